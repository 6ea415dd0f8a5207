"""Forward-backward attitude smoothing of a local filter (tpos is a post-processor).

Two independent runs of the same kernel (`local.run_full`): forward from the alignment at the start
of the log, and backward in time from the backward setup, which the caller aligns at the END of the
log on its own (its own still window, its own gyro bias): nothing of the forward run enters it, so
the two estimates are independent given the common prior and are fused on SO(3) with their
covariances (two-filter smoother, Fraser-Potter form), which is the information fusion of Eq. 27
applied to the two runs (`master.fuse`; the forward run's sensitivity to the start alignment's heading,
`AttitudeSolution.s_al`, is carried through the fusion and the forward/backward test). Their biases are
fused the same way (diagonal covariances).

The two runs also measure how honest their covariances are: their difference d has covariance
P_f + P_b when both are consistent. `fb_scale` is the mean of d^T (P_f + P_b)^-1 d per degree of
freedom, separately for tilt (2 dof) and heading (1 dof): a covariance-matching estimate of the
scale of the noise the model left out (room fields, unmodelled sensor errors). Scaling every noise
of a Kalman filter by a factor leaves its gains and estimates unchanged and scales its covariance
by that factor; the smoothed tilt covariance is multiplied by 1 + 2 max(scale - 1, 0), the excess being
fused as of unknown correlation between the runs (`excess_factor`), the heading covariance by max(scale, 1),
its excess being a drift each run accumulates from its own end (`heading_excess_factor`).
The gyro's constant scale/misalignment (`AttitudeSolution.S_gm`, a consider sensitivity) is not scaled: the
test leaves it out (`master.difference_cov(gyro_scale=False)`), and the fused solution holds its share as
`master.fuse` computes it for the fused weights (the part of it both runs share, which their difference
cannot show).
Each run also carries its error's sensitivity to the accelerometer bias (`AttitudeSolution.S_ba`);
the fused sensitivity is the runs' weighted sum (`master.fuse`). (The test's `diff_cov` is the
caller's: the sensitivity-based difference (S_f - S_b) (..)^T var(b_a) - Q_f - Q_b is the exact one,
but it moves the scale and with it the fusion weights; not adopted yet, see the chain.)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tpos_cli.attitude import master
from tpos_cli.attitude.local import AttitudeSolution, FilterSetup, run_full
from tpos_cli.frames.rotation import dcm_to_rotvec


def fb_scale(fwd: AttitudeSolution, bwd: AttitudeSolution, stride: int = 10, diff_cov=None) -> tuple[float, float]:
    """(tilt, heading) mean of d^T (P_f + P_b + D)^-1 d per dof over the samples (every `stride`-th);
    D (3,3) the covariance of a difference the runs' own covariances leave out by design (a consider
    term, e.g. the two ends' different levelling errors from one accelerometer bias), default none."""
    sl = slice(None, None, max(1, stride))
    d = dcm_to_rotvec(fwd.C_nb[sl] @ np.swapaxes(bwd.C_nb[sl], 1, 2))
    S = master.difference_cov(fwd, bwd, gyro_scale=False)[sl]
    if diff_cov is not None:
        S = S + np.asarray(diff_cov, dtype=float)[None]
    St = S[:, 0:2, 0:2]
    dt = d[:, 0:2]
    tilt = np.einsum("ni,ni->n", dt, np.linalg.solve(St, dt[..., None])[..., 0]) / 2.0
    head = d[:, 2] ** 2 / S[:, 2, 2]
    return float(np.mean(tilt)), float(np.mean(head))


def scale_covariance(P_att: np.ndarray, tilt: float, heading: float) -> np.ndarray:
    """P_att (N,3,3) with its tilt block scaled by `tilt` and heading by `heading` (D P D)."""
    D = np.sqrt(np.array([tilt, tilt, heading]))
    return P_att * D[None, :, None] * D[None, None, :]


def excess_factor(scale: float) -> float:
    """Factor of the smoothed covariance for a forward/backward `scale` (`fb_scale`): the modelled parts
    of the two runs are independent and fuse as such (P_s); the excess (scale - 1) P_f, (scale - 1) P_b
    the model leaves out need not be: what it leaves out (a sustained acceleration, a field that moves
    with the device) pushes both runs alike near each instant, and for W_f u_f + W_b u_b any correlation
    gives at most 2 (scale - 1) (W_f P_f W_f^T + W_b P_b W_b^T) = 2 (scale - 1) P_s (the covariance-
    intersection bound). So 1 + 2 max(scale - 1, 0); 1 for a consistent pair."""
    return 1.0 + 2.0 * max(float(scale) - 1.0, 0.0)


def heading_excess_factor(scale: float) -> float:
    """Factor of the smoothed heading covariance for a forward/backward heading `scale`: max(scale, 1), the
    excess fused as independent between the runs. What the model leaves out of a heading is a drift each run
    accumulates from its own fix (its alignment, its last accepted field sample), through the gyro's errors
    over the turns since then: the forward run's from the past, the backward run's from the future, so they
    are not positively correlated (on BROAD 02/11/26/28/33 the two runs' heading errors correlate -0.48 to
    -0.75: notes marg7.md, rho.py), and a random-walk drift fuses to exactly scale P_s (a ramp through the
    same turns to less: the weights cancel most of it). The covariance-intersection bound of `excess_factor`,
    1 + 2 (scale - 1), assumes the worst positive correlation and made the heading 3-10x too cautious."""
    return max(float(scale), 1.0)


def _fuse_diag(a, va, b, vb):
    """Inverse-variance mean of two independent estimates per element; a state that neither run
    estimates (both variances zero) keeps the forward value."""
    s = va + vb
    ok = s > 0.0
    w = np.where(ok, vb / np.where(ok, s, 1.0), 1.0)  # weight of a
    return w * a + (1.0 - w) * b, np.where(ok, va * vb / np.where(ok, s, 1.0), 0.0)


def smooth_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, setup: FilterSetup, use: int,
                backward_setup: FilterSetup, still=None, forward: AttitudeSolution | None = None,
                diff_cov=None) -> AttitudeSolution:
    """Smoothed `run_full` solution (module docstring). `backward_setup` holds the backward run's own
    initial state at the last sample (C0, bias0_rps, P0); `forward` may pass an already computed forward
    run with `setup`. `nis` are the forward run's; `mag_ok` is True where both runs accepted the field.
    `diff_cov`: see `fb_scale`."""
    fwd = forward if forward is not None else run_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, setup, use,
                                                        still=still)
    bwd = run_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, backward_setup, use, backward=True, still=still)
    s = master.fuse(name, [fwd, bwd])
    lt, lh = fb_scale(fwd, bwd, diff_cov=diff_cov)
    vb = np.concatenate([fwd.var_bias, bwd.var_bias], axis=1)
    bg, vg = _fuse_diag(fwd.bias_rps, vb[:, 0:3], bwd.bias_rps, vb[:, 6:9])
    ba, va = _fuse_diag(fwd.acc_bias_mps2, vb[:, 3:6], bwd.acc_bias_mps2, vb[:, 9:12])
    mag_ok = None if fwd.mag_ok is None else (fwd.mag_ok & bwd.mag_ok)
    mag_any = None if fwd.mag_ok is None else (fwd.mag_ok | bwd.mag_ok)
    del bwd, vb  # the backward run is freed before the covariance's temporaries (memory: ~0.2 GB an hour at 100 Hz)
    ft, fh = excess_factor(lt), heading_excess_factor(lh)
    # the excess scales the noises the model left out; the gyro's scale/misalignment share is a prior that the
    # difference does not show where the runs share it (`master.fuse`): added once, as fused
    G = master.gyro_scale_cov(s)
    P = scale_covariance(s.P_att - G, ft, fh) + G
    Q = None if s.Q_ba is None else scale_covariance(s.Q_ba, ft, fh)
    return replace(fwd, C_nb=s.C_nb, P_att=P, bias_rps=bg, acc_bias_mps2=ba, var_bias=np.concatenate([vg, va], axis=1),
                   mag_ok=mag_ok, mag_any=mag_any, gyro_M=None, fb_scale=(lt, lh), S_ba=s.S_ba, Q_ba=Q, s_al=s.s_al, var_al=s.var_al,
                   S_gm=s.S_gm, var_gm=s.var_gm)
