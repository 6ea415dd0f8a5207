"""The forward/backward smoother's heading sigma (`smoother.heading_scale`, `smooth_full`).

The first tests take the heading test alone on constructed runs: the gyro's constant scale/misalignment drift,
which the two runs accumulate from opposite ends, is not their own parts' excess.

The others take the smoothed heading's sigma against its error where the heading is carried by the gyro
(simulated truth).

A device turned by hand one way (6 deg/s about the vertical, with roll and pitch sway) for 60 s; a room
magnet far beyond the gate from 10 s to 50 s, so the gated LF1 refuses the field there and each run carries
its heading through those 40 s on the gyro alone, from its own end: the situation of the BROAD trials whose
forward and backward runs drift apart (notes marg12.md section 3). Each run starts from its own end's
alignment and gyro bias, drawn around the truth from their priors (as the target chain aligns each run in its
own still window: no estimate, and no prior error, is shared by the two runs).

The heading NEES (1 dof) of the smoothed solution is taken once per trial, at 30 s (the middle of the refused
stretch, 20 s from either fix: where the fusion leans on both runs equally), so the trials' values are
independent draws and the mean of `SEEDS` of them has a chi-square band.
"""

from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from scipy.stats import chi2

from tests.attitude.gen import make
from tests.attitude.test_local import _setup
from tpos_cli.attitude import _kernels as K
from tpos_cli.attitude.local import AttitudeSolution
from tpos_cli.attitude.smoother import fb_scale, heading_scale, heading_split, smooth_full
from tpos_cli.frames.rotation import dcm_to_rotvec, euler_to_dcm, rotvec_to_dcm

N = 20000
SD_OWN = 1e-3  # rad, each run's own heading SD (the model's)
VAR_GM = 1e-6  # the runs' prior variance of each dM element (1000 ppm)


def _runs(d_rad, gm_f, gm_b):
    """(forward, backward) solutions whose heading difference is `d_rad` (N,), heading sensitivities to dM[0]
    `gm_f`, `gm_b` (N,), own heading SD `_own_sd` each."""
    t = np.arange(N) * 0.01
    P = np.eye(3) * _own_sd()[:, None, None] ** 2

    def sol(C, g):
        S = np.zeros((N, 3, 9))
        S[:, 2, 0] = g
        return AttitudeSolution("lf1", t, C, P + VAR_GM * (S @ np.swapaxes(S, 1, 2)), S_gm=S, var_gm=VAR_GM)

    C_b = rotvec_to_dcm(np.column_stack([np.zeros(N), np.zeros(N), -d_rad]))  # C_f C_b^T = exp(d e_D)
    return sol(np.tile(np.eye(3), (N, 1, 1)), gm_f), sol(C_b, gm_b)


def _own_sd():
    """(N,) each run's own heading SD: it varies along the log (as between field updates)."""
    return SD_OWN * (1.0 + 3.0 * np.abs(np.sin(np.linspace(0.0, 6.0 * np.pi, N))))


def _ramps():
    u = np.linspace(0.0, 1.0, N)
    # rad per unit dM (~3 turns): the drift through the same turns from each run's own end, opposite signs
    return 20.0 * u, -20.0 * (1.0 - u)


# One fit's s scatters widely where the drift fills the difference (the drift a single constant draw beside own parts
# of their modelled size: the ML fit's sandwich SE of s is 0.12 at one prior SD of drift, 0.21 at 1.8), so a single
# seed's 0.8-1.25 would be ~2 and ~1.2 SE and pass by the seed; the tests take the mean over a fixed range of
# independent draws of the own errors instead, whose SE is that over sqrt(SEEDS_SPLIT).
SEEDS_SPLIT = 32


def _mean_heading_scale(drift_prior_sds: float) -> float:
    """Mean `heading_scale` over SEEDS_SPLIT pairs of runs: the drift of a dM of `drift_prior_sds` prior SDs and own errors
    as modelled (a new draw per seed)."""
    gf, gb = _ramps()
    scales = []
    for seed in range(SEEDS_SPLIT):
        rng = np.random.default_rng(seed)
        d = (gf - gb) * drift_prior_sds * np.sqrt(VAR_GM) + rng.normal(0.0, np.sqrt(2.0) * _own_sd())
        scales.append(heading_scale(*_runs(d, gf, gb), stride=1))
    return float(np.mean(scales))


def test_gyro_scale_drift_in_the_difference_is_not_taken_as_own_excess():
    # the drift of a dM of one prior SD (what the model expects): the mean's SE 0.12 / sqrt(32) = 0.022, so 0.8-1.25
    # is more than 8 SE from 1 either side (the ML estimate runs a little low: 0.98 over seeds 1000-1039)
    assert 0.8 < _mean_heading_scale(1.0) < 1.25
    rng = np.random.default_rng(0)
    gf, gb = _ramps()
    d = (gf - gb) * np.sqrt(VAR_GM) + rng.normal(0.0, np.sqrt(2.0) * _own_sd())
    assert fb_scale(*_runs(d, gf, gb), stride=1)[1] > 20.0  # the test without it: all of d taken as the own parts' excess


def test_a_large_draw_of_the_drift_is_not_taken_as_own_excess():
    # the drift of a dM of 1.8 prior SDs (a chi2_1 draw of 3.2, inside its 95 % range: one dM per gyro): the mean's SE
    # 0.21 / sqrt(32) = 0.037, so 0.8 is ~4.6 SE under 0.97 (the mean over seeds 1000-1039) and 1.25 ~7.6 SE over it
    assert 0.8 < _mean_heading_scale(1.8) < 1.25


def test_own_excess_is_measured_beside_the_drift():
    rng = np.random.default_rng(1)
    gf, gb = _ramps()
    d = (gf - gb) * np.sqrt(VAR_GM) + rng.normal(0.0, np.sqrt(2.0 * 40.0) * _own_sd())  # own parts 40x their variance
    f, b = _runs(d, gf, gb)
    # +-15 % is ~6.5 SE of s: the ML fit's sandwich SE here (the drift one constant draw, the own parts white over the
    # N samples; var(d^2) = 4 c^2 s o + 2 s^2 o^2) is 2.2 % of s (2.4 % over seeds 100-139; notes marg14.md)
    assert 40.0 * 0.85 < heading_scale(f, b, stride=1) < 40.0 * 1.15


def test_no_drift_is_split_from_a_difference_its_own_parts_explain():
    rng = np.random.default_rng(3)
    # own errors as modelled and no drift; the drift's variance profile has the own parts' shape (as on the
    # simulated paper-grade target sessions, notes marg213.md), so s o + lam g cannot tell them apart: the own
    # parts explaining the difference (mean NEES <= chi2_1's 95 % point), nothing is split off as drift
    gf = np.sqrt(2.0) * _own_sd() / np.sqrt(VAR_GM)
    d = rng.normal(0.0, np.sqrt(2.0) * _own_sd())
    f, b = _runs(d, gf, np.zeros(N))
    assert heading_split(f, b, stride=1) == (fb_scale(f, b, stride=1)[1], 0.0)


SEEDS = 60
DURATION_S, REFUSED_S, AT_S = 60.0, (10.0, 50.0), 30.0


def _rpy(t):
    return np.radians([8 * np.sin(0.3 * t), 15 * np.sin(2 * np.pi * t / 20), 30 + 6.0 * t])


def _room_magnet(t):
    m = np.zeros((t.size, 3))
    m[(t > REFUSED_S[0]) & (t < REFUSED_S[1])] = [30.0, -20.0, 10.0]
    return m


def _own_end(g, rng, st, i):
    """`st` started at sample `i` from its own alignment and gyro bias, each an error drawn from P0."""
    sd = np.sqrt(np.diag(st.P0))
    C0 = euler_to_dcm(*(np.array(_rpy(g.t[i])) + rng.normal(0, sd[0:3])))
    return replace(st, C0=C0, bias0_rps=g.bias + rng.normal(0, sd[3:6]))


@cache
def _heading_nees(gyro_scale_sd: float, modelled: bool = True) -> np.ndarray:
    """(SEEDS,) smoothed heading NEES at `AT_S`; the gyro reads (I + dM) its rate, dM ~ N(0, gyro_scale_sd^2 I9),
    and the filters model exactly that (`FilterNoise.gyro_scale_const_sd`; 0: a gyro without it) or, not
    `modelled`, nothing of it."""
    out = []
    for seed in range(SEEDS):
        rng = np.random.default_rng(300 + seed)
        g = make(_rpy, duration_s=DURATION_S, seed=seed, bias_rps=rng.normal(0, 3e-5, 3), mag_dist_ut=_room_magnet)
        dM = rng.normal(0.0, gyro_scale_sd, (3, 3))
        gyro = g.gyro + g.gyro @ dM.T
        st = _setup(g, rng)
        st = replace(st, noise=replace(st.noise, gyro_scale_const_sd=gyro_scale_sd if modelled else 0.0))
        fwd, bwd = _own_end(g, rng, st, 0), _own_end(g, rng, st, -1)
        s = smooth_full("lf1", g.t, gyro, g.acc, g.mag, None, fwd, K.USE_ACC | K.USE_MAG, bwd)
        k = int(np.searchsorted(g.t, AT_S))
        e = dcm_to_rotvec(s.C_nb[k] @ g.C[k].T)[2]
        out.append(e**2 / s.P_att[k, 2, 2])
    return np.asarray(out)


def test_smoothed_heading_sigma_covers_its_error_where_each_run_carries_the_heading_on_the_gyro():
    nees = _heading_nees(0.0)
    lo, hi = chi2.ppf([0.025, 0.975], SEEDS) / SEEDS  # two-sided 95 % band of the mean of SEEDS chi2(1)
    assert lo < nees.mean() < hi, (nees.mean(), lo, hi)
    assert np.mean(nees < chi2.ppf(0.95, 1)) >= 0.90


def test_smoothed_heading_sigma_covers_its_error_with_the_gyros_scale_error_as_modelled():
    # a constant scale/misalignment dM the filters model (consider sensitivity `S_gm`, each run honest alone):
    # the runs drift from opposite ends through the same turns, their difference shows that drift in full
    # and the fused solution holds only the weighted sum of it (`master.fuse`)
    nees = _heading_nees(3e-3)
    lo, hi = chi2.ppf([0.025, 0.975], SEEDS) / SEEDS
    assert lo < nees.mean() < hi, (nees.mean(), lo, hi)


@pytest.mark.xfail(strict=True, reason=(
    "known gap (issue 13): a gyro scale/misalignment the filters do not model (0.3 %, no prior) turns both runs "
    "through the same turns; they drift apart from opposite ends (each run bold alone), the forward/backward "
    "test reads their difference as independent excess and scales the fused heading by it, while the fusion "
    "cancels much of that drift: smoothed heading NEES 0.57 (band 0.67-1.39; with a z-axis scale error alone "
    "0.04, sigma ~5x its error), the caution seen on BROAD 02/26/28/33. The difference alone cannot tell such a "
    "drift from an offset one run holds (notes marg12.md, marg13.md)"))
def test_smoothed_heading_sigma_with_a_drift_the_filters_do_not_model():
    nees = _heading_nees(3e-3, modelled=False)
    lo, hi = chi2.ppf([0.025, 0.975], SEEDS) / SEEDS
    assert lo < nees.mean() < hi, (nees.mean(), lo, hi)


def test_the_runs_difference_covariance_is_formed_once_per_smoothed_solution(monkeypatch):
    # fb_scale, heading_split and the drift's split (where the gate opens: a modelled dM) all read the runs'
    # own difference covariance; on full arrays it is formed once (memory and time of an hour at 100 Hz)
    from tpos_cli.attitude import master

    calls = []
    real = master.difference_cov

    def counted(a, b, gyro_scale=True):
        calls.append(gyro_scale)
        return real(a, b, gyro_scale)

    monkeypatch.setattr(master, "difference_cov", counted)
    rng = np.random.default_rng(7)
    g = make(_rpy, duration_s=DURATION_S, seed=7, bias_rps=rng.normal(0, 3e-5, 3), mag_dist_ut=_room_magnet)
    st = _setup(g, rng)
    st = replace(st, noise=replace(st.noise, gyro_scale_const_sd=3e-3))
    gyro = g.gyro + g.gyro @ rng.normal(0.0, 3e-3, (3, 3)).T
    s = smooth_full("lf1", g.t, gyro, g.acc, g.mag, None, _own_end(g, rng, st, 0), K.USE_ACC | K.USE_MAG,
                    _own_end(g, rng, st, -1))
    assert s.fb_scale is not None
    assert calls.count(False) == 1, calls


def test_the_smoothed_solution_keeps_each_runs_nis():
    # the verdict checks each run's innovations (`quality.nis_findings`): the backward run's are kept beside the
    # forward run's (before: only the forward run's, the backward run's dropped with it)
    from tpos_cli.attitude.local import run_full

    rng = np.random.default_rng(8)
    g = make(_rpy, duration_s=20.0, seed=8, bias_rps=rng.normal(0, 3e-5, 3))
    st = _setup(g, rng)
    fwd, bwd = _own_end(g, rng, st, 0), _own_end(g, rng, st, -1)
    use = K.USE_ACC | K.USE_MAG
    s = smooth_full("lf1", g.t, g.gyro, g.acc, g.mag, None, fwd, use, bwd)
    back = run_full("lf1", g.t, g.gyro, g.acc, g.mag, None, bwd, use, backward=True)
    assert s.nis_backward is not None and set(s.nis_backward) == set(back.nis)
    for k, v in back.nis.items():
        np.testing.assert_array_equal(s.nis_backward[k], v)  # the same run, the same samples: identical
    assert np.isfinite(s.nis_backward["mag"]).sum() > 0.9 * g.t.size
