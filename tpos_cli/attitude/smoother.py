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
The gyro's constant scale/misalignment (`AttitudeSolution.S_gm`, a consider sensitivity) is not scaled, and
the fused solution holds its share as `master.fuse` computes it for the fused weights. The runs' drifts from
it have opposite signs (each accumulates it from its own end), so their difference shows it in full: the
heading test counts it as modelled (`heading_split`: the difference's covariance is s o + lam times the
drift's), the tilt test leaves it out (`master.difference_cov(gyro_scale=False)`, unchanged: `fb_scale`).
And since the difference shows that drift, the fused solution's share of it is predicted from the difference
and removed, its covariance kept for what is left (`drift_given_difference`); only where the difference exceeds
what the runs' own parts explain (`DRIFT_TEST_MIN`): else the test and the solution are those without the split.
Each run also carries its error's sensitivity to the accelerometer bias (`AttitudeSolution.S_ba`);
the fused sensitivity is the runs' weighted sum (`master.fuse`). (The test's `diff_cov` is the
caller's: the sensitivity-based difference (S_f - S_b) (..)^T var(b_a) - Q_f - Q_b is the exact one,
but it moves the scale and with it the fusion weights; not adopted yet, see the chain.)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import minimize
from scipy.stats import chi2

from tpos_cli.attitude import master
from tpos_cli.attitude.local import AttitudeSolution, FilterSetup, run_full
from tpos_cli.frames.rotation import dcm_to_rotvec, rotvec_to_dcm


def own_difference_cov(fwd: AttitudeSolution, bwd: AttitudeSolution) -> np.ndarray:
    """(N,3,3) covariance of the runs' difference from their own parts, the gyro's scale/misalignment left out
    (`master.difference_cov(gyro_scale=False)`): what `fb_scale`, `heading_split` and `smooth_full` test the
    difference against. Formed on full arrays, so a caller that needs it more than once forms it once and
    passes it (`own`)."""
    return master.difference_cov(fwd, bwd, gyro_scale=False)


def fb_scale(fwd: AttitudeSolution, bwd: AttitudeSolution, stride: int = 10, diff_cov=None,
             own: np.ndarray | None = None) -> tuple[float, float]:
    """(tilt, heading) mean of d^T (P_f + P_b + D)^-1 d per dof over the samples (every `stride`-th);
    D (3,3) the covariance of a difference the runs' own covariances leave out by design (a consider
    term, e.g. the two ends' different levelling errors from one accelerometer bias), default none.
    `own`: `own_difference_cov(fwd, bwd)` if the caller has it (else formed here)."""
    sl = slice(None, None, max(1, stride))
    d = dcm_to_rotvec(fwd.C_nb[sl] @ np.swapaxes(bwd.C_nb[sl], 1, 2))
    S = (own_difference_cov(fwd, bwd) if own is None else own)[sl]
    if diff_cov is not None:
        S = S + np.asarray(diff_cov, dtype=float)[None]
    St = S[:, 0:2, 0:2]
    dt = d[:, 0:2]
    tilt = np.einsum("ni,ni->n", dt, np.linalg.solve(St, dt[..., None])[..., 0]) / 2.0
    head = d[:, 2] ** 2 / S[:, 2, 2]
    return float(np.mean(tilt)), float(np.mean(head))


#: most the realized dM drift in the forward/backward difference may exceed the variance its prior gives
#: (`heading_split`'s lam): one draw of it is chi2_1 about that variance, above this 95 % point in 5 % of gyros
#: (chosen after seeing BROAD with lam unbounded: notes marg13.md)
DRIFT_DRAW_MAX = float(chi2.ppf(0.95, 1))
#: the runs' heading difference shows something beyond their own parts only where its mean NEES against them
#: (`fb_scale`'s heading) exceeds this: chi2_1's 95 % point, the difference taken as one draw (nearly constant
#: where the field is refused). Below it the own parts explain the difference and no drift is split from it
#: (`heading_split`): on simulated paper-grade gyros (no scale error) the own parts explain it (mean NEES
#: .27-2.9 on benchmarks/target_nees.py's 8 seeds; tactical, 100 ppm: .13-3.0; mems, 1000 ppm: 4 of 8 above)
#: but the drift's variance profile has their shape there, and the split alone credited .5-.75 of the prior
#: to it (the statistic chosen after seeing two of those sims and BROAD, its level fixed before: notes marg213.md)
DRIFT_TEST_MIN = float(chi2.ppf(0.95, 1))


def heading_split(fwd: AttitudeSolution, bwd: AttitudeSolution, stride: int = 10, diff_cov=None,
                  own: np.ndarray | None = None) -> tuple[float, float]:
    """(s, lam): the forward/backward heading test with the difference's whole modelled covariance. d, the runs'
    heading difference over the samples (every `stride`-th), is taken as N(0, s o + lam g), o its own covariance
    (`fb_scale`'s, the part s multiplies: what the model leaves out scales the noises it has) and
    g = var_gm |(S_f - S_b)_D|^2 the drift the gyro's constant scale/misalignment dM ~ N(0, var_gm I9) puts in it
    (`AttitudeSolution.S_gm`; `master.difference_cov`); s and lam by maximum likelihood, lam in (0, DRIFT_DRAW_MAX).
    The runs accumulate that drift through the same turns from opposite ends (forward from the start, backward from
    the end): their errors from it have opposite signs, the difference shows it in full and the fused solution only
    the weighted sum's (`master.fuse`, `drift_given_difference`). `fb_scale` leaves it out of the test, so the own
    parts were scaled up by it and fused as independent (simulated dM at the prior's SD, tests/attitude/
    test_smoother.py: smoothed heading NEES 0.21). lam is the drift's size against its prior: ONE draw of dM (the
    difference is nearly constant where the field is refused) whose realized size may exceed its prior SD, and a
    gyro whose dM is far smaller than the prior's (a sim without it) shows none (lam -> 0). Without the
    sensitivity, or where the own parts explain the difference (`fb_scale`'s heading scale s0 <= DRIFT_TEST_MIN):
    (s0, 0), the test of main. `own`: as `fb_scale`'s."""
    sl = slice(None, None, max(1, stride))
    d2 = dcm_to_rotvec(fwd.C_nb[sl] @ np.swapaxes(bwd.C_nb[sl], 1, 2))[:, 2] ** 2
    o = (own_difference_cov(fwd, bwd) if own is None else own)[sl][:, 2, 2]
    if diff_cov is not None:
        o = o + float(np.asarray(diff_cov, dtype=float)[2, 2])
    s0 = float(np.mean(d2 / o))
    if fwd.S_gm is None or bwd.S_gm is None or max(fwd.var_gm, bwd.var_gm) <= 0.0 or s0 <= DRIFT_TEST_MIN:
        return s0, 0.0
    g = max(fwd.var_gm, bwd.var_gm) * np.sum((fwd.S_gm[sl] - bwd.S_gm[sl])[:, 2, :] ** 2, axis=1)

    def lam_of(x1):
        return DRIFT_DRAW_MAX / (1.0 + np.exp(-x1))

    def nll(x):  # mean negative log-likelihood per sample, s = exp(x0)
        v = np.exp(x[0]) * o + lam_of(x[1]) * g
        return float(np.mean(np.log(v) + d2 / v))

    x0 = np.log(max(float(np.mean(d2 / (o + g))), 1e-6))
    r = minimize(nll, [x0, 0.0], method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-12, "maxiter": 4000})
    return float(np.exp(r.x[0])), float(lam_of(r.x[1]))


def heading_scale(fwd: AttitudeSolution, bwd: AttitudeSolution, stride: int = 10, diff_cov=None) -> float:
    """The own parts' heading scale s of `heading_split`."""
    return heading_split(fwd, bwd, stride, diff_cov)[0]


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


def drift_given_difference(C_nb, S_g, var_gm: float, A_D, d_D, o_D, lam: float):
    """(C_nb, S_g', P_add) of a fused solution given its runs' heading difference d_D (N,) rad. The fused error
    holds the gyro's constant scale/misalignment as S_g m, m = vec(dM) (`master.fuse`); the difference holds it
    as A_D m, A_D = (S_f - S_b)_D (N,9), beside the runs' own parts of variance o_D (N,) (the scaled own heading
    covariance of the difference, `heading_split`). The two runs accumulate that drift from opposite ends
    through the same turns, so the difference shows it and the fused error's share of it is predictable from
    it: per sample, from that sample's difference alone (the samples' differences are not independent), with
    m ~ N(0, lam var_gm I9) (`heading_split`'s lam: the drift's size the log shows), the Gaussian prediction
    h d_D, h = c / V, c = lam var_gm S_g A_D^T, V = o_D + lam var_gm |A_D|^2, is removed from the attitude
    (C <- exp(-h d_D) C). What is left, (S_g - h A_D) m - h n, is scored under m ~ N(0, max(lam, 1) var_gm I9)
    (never less than the prior): S_g' = sqrt(max(lam, 1)) (S_g - h A_D) (the shared share var_gm S_g' S_g'^T) and
    P_add = o_D h h^T (the own noise the prediction carries in). lam -> 0 (no drift in the difference): no
    change but the prior's share. On BROAD 33/28/02 the prediction correlates 0.95/0.88/0.74 with the
    smoothed heading error (notes marg13.md)."""
    var_c = lam * var_gm
    a2 = np.sum(A_D * A_D, axis=1)
    V = o_D + var_c * a2
    ok = V > 0.0
    h = np.where(ok[:, None], var_c * np.einsum("nij,nj->ni", S_g, A_D) / np.where(ok, V, 1.0)[:, None], 0.0)
    S_post = h[:, :, None] * A_D[:, None, :]
    np.subtract(S_g, S_post, out=S_post)
    S_post *= np.sqrt(max(lam, 1.0))
    P_add = o_D[:, None, None] * h[:, :, None] * h[:, None, :]
    return rotvec_to_dcm(-h * d_D[:, None]) @ C_nb, S_post, P_add


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
    run with `setup`. `nis` are the forward run's, `nis_backward` the backward run's; `mag_ok` is True where
    both runs accepted the field.
    `diff_cov`: see `fb_scale`."""
    fwd = forward if forward is not None else run_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, setup, use,
                                                        still=still)
    bwd = run_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, backward_setup, use, backward=True, still=still)
    s = master.fuse(name, [fwd, bwd])
    own = own_difference_cov(fwd, bwd)  # once per solution: the tests and the drift's split read it
    lt, _ = fb_scale(fwd, bwd, diff_cov=diff_cov, own=own)
    lh, lam = heading_split(fwd, bwd, diff_cov=diff_cov, own=own)
    drift = None  # the runs' heading difference where it shows the gyro's scale/misalignment drift (lam > 0)
    if lam > 0.0 and s.S_gm is not None and s.var_gm > 0.0:
        o_D = own[:, 2, 2].copy()
        if diff_cov is not None:
            o_D = o_D + float(np.asarray(diff_cov, dtype=float)[2, 2])
        drift = (fwd.S_gm[:, 2, :] - bwd.S_gm[:, 2, :], dcm_to_rotvec(fwd.C_nb @ np.swapaxes(bwd.C_nb, 1, 2))[:, 2], o_D)
    vb = np.concatenate([fwd.var_bias, bwd.var_bias], axis=1)
    bg, vg = _fuse_diag(fwd.bias_rps, vb[:, 0:3], bwd.bias_rps, vb[:, 6:9])
    ba, va = _fuse_diag(fwd.acc_bias_mps2, vb[:, 3:6], bwd.acc_bias_mps2, vb[:, 9:12])
    mag_ok = None if fwd.mag_ok is None else (fwd.mag_ok & bwd.mag_ok)
    mag_any = None if fwd.mag_ok is None else (fwd.mag_ok | bwd.mag_ok)
    nis_backward = bwd.nis
    del bwd, vb, own  # the backward run is freed before the covariance's temporaries (memory: ~0.2 GB an hour at 100 Hz)
    ft, fh = excess_factor(lt), heading_excess_factor(lh)
    # the excess scales the noises the model left out; the gyro's scale/misalignment share is a prior that the
    # difference does not show where the runs share it (`master.fuse`): added once, as fused
    G = master.gyro_scale_cov(s)
    P = scale_covariance(s.P_att - G, ft, fh)
    C, S_gm = s.C_nb, s.S_gm
    if drift is not None:  # `drift_given_difference`
        A_D, d_D, o_D = drift
        C, S_gm, P_add = drift_given_difference(C, s.S_gm, s.var_gm, A_D, d_D, fh * o_D, lam)
        P = P + P_add
    P = P + (G if S_gm is s.S_gm else s.var_gm * (S_gm @ np.swapaxes(S_gm, 1, 2)))
    Q = None if s.Q_ba is None else scale_covariance(s.Q_ba, ft, fh)
    return replace(fwd, C_nb=C, P_att=P, bias_rps=bg, acc_bias_mps2=ba, var_bias=np.concatenate([vg, va], axis=1),
                   mag_ok=mag_ok, mag_any=mag_any, gyro_M=None, fb_scale=(lt, lh), S_ba=s.S_ba, Q_ba=Q, s_al=s.s_al, var_al=s.var_al,
                   S_gm=S_gm, var_gm=s.var_gm, nis_backward=nis_backward)
