"""GPS error states (`fusion.gps_error`, 18-state `insgps_kernel`) against exact simulated truth."""

import tempfile
from pathlib import Path

import numpy as np
import pytest

from tpos_cli.chains.drive_smooth import process_drive
from tpos_cli.config import DriveSmoothParams
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.fusion.engine import epoch_of
from tpos_cli.fusion.layout import Block
from tpos_cli.session import load_session
from tpos_cli.sim.drive import simulate_drive

OUTAGE = (300.0, 30.0)


def _gps_error_ned(sim):
    ref = sim.gps.lla_true[0]
    return lla_to_ned(sim.gps.lla, ref) - lla_to_ned(sim.gps.lla_true, ref)


def test_simulated_correlated_error_is_first_order_gauss_markov():
    """b_k - a b_(k-1) is white with SD sqrt(1 - a^2) sigma (the exact AR(1) the simulator draws)."""
    sim = simulate_drive(600.0, seed=4, outages=(), gps_sigma_h_m=0.0, gps_sigma_v_m=0.0,
                         gps_correlated_sigma_neu_m=(1.0, 1.0, 2.0), gps_correlated_tau_s=30.0)
    b = _gps_error_ned(sim)
    b[:, 2] *= -1.0  # down -> up, as drawn
    a = np.exp(-1.0 / 30.0)
    w = (b[1:] - a * b[:-1]) / (np.sqrt(1 - a * a) * np.array([1.0, 1.0, 2.0]))
    # 600 samples per axis: the SD of a unit normal sample is known to 1/sqrt(1200) ~ 3%; 5 SEs
    np.testing.assert_allclose(w.std(axis=0), 1.0, atol=0.15)
    # whiteness: lag-1 correlation of the innovations within 4 / sqrt(600)
    for i in range(3):
        assert abs(np.corrcoef(w[:-1, i], w[1:, i])[0, 1]) < 4.0 / np.sqrt(600)


def test_white_simulated_gps_keeps_the_15_state_filter():
    """White fixes: the likelihood-ratio test rejects the error states, the filter stays 15-state."""
    with tempfile.TemporaryDirectory() as tmp:
        sim = simulate_drive(600.0, seed=1, outages=(OUTAGE,))
        ses = load_session(sim.write(Path(tmp) / "s"))
    p = DriveSmoothParams(gps_sigma_vel_mps=0.05, gps_error_model="gauss_markov")
    res = process_drive(ses, p, None, names=("forward", "backward", "smoothed"))
    ge = res.info["gps_error_states"]
    assert ge["sigma_h_m"] == 0.0 and ge["sigma_v_m"] == 0.0
    assert res.forward.layout.offset(Block.GPS_ERROR) == -1


def _stats(sim, sol, inside):
    tr = sim.truth
    e = tr.navigation_errors(sol.idx, sol.nav, sol.C_nb)[:, :3]
    t = tr.t_s[sol.idx]
    m = (t >= OUTAGE[0]) & (t < OUTAGE[0] + OUTAGE[1]) if inside else (t > 30.0) & ~((t >= OUTAGE[0]) & (t < sum(OUTAGE)))
    z = e[m, :2] / np.sqrt(np.diagonal(sol.P9[m, :2, :2], axis1=1, axis2=2))
    return np.mean(np.hypot(e[m, 0], e[m, 1]) ** 2), np.mean(np.abs(z) < 2.0)


@pytest.fixture(scope="module")
def correlated_runs():
    """Three drives with a 1 m / 1.5 m Gauss-Markov GPS error (tau 60 s) over 0.3 m white noise,
    processed with the error states (default) and with the white model."""
    out = []
    for seed in (1, 2, 3):
        with tempfile.TemporaryDirectory() as tmp:
            sim = simulate_drive(600.0, seed=seed, outages=(OUTAGE,), gps_sigma_h_m=0.3, gps_sigma_v_m=0.5,
                                 gps_correlated_sigma_neu_m=(1.0, 1.0, 1.5), gps_correlated_tau_s=60.0)
            ses = load_session(sim.write(Path(tmp) / "s"))
        runs = {m: process_drive(ses, DriveSmoothParams(gps_sigma_vel_mps=0.05, gps_error_model=m), None,
                                 names=("forward", "backward", "smoothed", "two_filter"))
                for m in ("gauss_markov", "white")}
        out.append((sim, runs))
    return out


def test_error_states_are_fitted_on_correlated_gps(correlated_runs):
    for _sim, runs in correlated_runs:
        ge = runs["gauss_markov"].info["gps_error_states"]
        # ML over ten correlation times of one drive: the SD is known to a factor of about 2 (the
        # innovations pin the drift rate sigma^2 / tau better than sigma or tau alone)
        assert 0.5 <= ge["sigma_h_m"] <= 2.0
        assert runs["gauss_markov"].forward.layout.offset(Block.GPS_ERROR) >= 0


def test_error_states_are_consistent_forward_and_backward(correlated_runs):
    """The estimated fix error (the GPS_ERROR block) of both runs against the exact simulated error, in
    units of its own SD: the mean square per horizontal axis is about 1 (0.5-3.0 per run, 1.35 over
    the six; a wrong sign in the backward run would give about 4 sigma_gm^2 / P ~ 8)."""
    z2 = []
    for sim, runs in correlated_runs:
        r = runs["gauss_markov"]
        b_true = _gps_error_ned(sim)
        t = sim.gps.t_s
        k = np.searchsorted(sim.truth.t_s, t)
        # after each run's first minute (heading search, convergence): forward from the start,
        # backward from the end of the log
        for run, m in ((r.forward, t > 60.0), (r.backward, t < sim.truth.t_s[-1] - 60.0)):
            e = epoch_of(run, k[m])  # the covariance of the nearest epoch on the data side
            o = run.layout.offset(Block.GPS_ERROR)
            sd = np.sqrt(np.diagonal(run.ep_P[e][:, o:o + 2, o:o + 2], axis1=1, axis2=2))
            z = (run.extra(Block.GPS_ERROR, k[m])[:, :2] - b_true[m, :2]) / sd
            assert np.mean(np.abs(z) < 2.0) > 0.6  # one run is ~10 correlation times: a loose floor
            z2.append(np.mean(z**2))
    # six runs of ~10 effective samples per axis: the mean of z^2 is 1 to about +-0.4 (2 SD)
    assert 0.5 < np.mean(z2) < 2.0


def test_error_states_make_the_sigmas_cover_correlated_gps(correlated_runs):
    """Outside the outage the white model's sigmas cover the errors on 7-28% of the epochs (it
    believes the 0.3 m fix-to-fix scatter); with the error states on 86-100%; the smoothed errors
    are also smaller, outside and, over the three drives, inside the outage."""
    acc = {m: {"in": [], "out": []} for m in ("gauss_markov", "white")}
    for sim, runs in correlated_runs:
        for m, res in runs.items():
            ms_in, _ = _stats(sim, res.solutions["smoothed"], True)
            ms_out, cover = _stats(sim, res.solutions["smoothed"], False)
            _, cover_tf = _stats(sim, res.solutions["two_filter"], False)
            acc[m]["in"].append(ms_in)
            acc[m]["out"].append(ms_out)
            if m == "gauss_markov":
                # |e| < 2 sigma on >= 95% of the epochs of a consistent filter; 570 s of one draw of
                # a 60-s correlated error is about 10 independent samples: allow 0.85
                assert cover >= 0.85
                assert cover_tf >= 0.8  # the two-filter blend over 18 states (0.86-0.90 measured)
            else:
                assert cover < 0.5
    for key in ("in", "out"):
        rms = {m: np.sqrt(np.mean(acc[m][key])) for m in acc}
        assert rms["gauss_markov"] < rms["white"], (key, rms)


def test_unmodelled_error_is_what_the_stated_accuracy_leaves():
    """sigma_c^2 = stated^2 - white^2 - gm^2, and never negative (`unmodelled_error_sd_m`)."""
    from tpos_cli.fusion.gps_error import unmodelled_error_sd_m

    sd = unmodelled_error_sd_m([1.5, 2.5], [0.3, 0.4], [0.4, 0.0])
    np.testing.assert_allclose(sd, [np.sqrt(1.5**2 - 0.3**2 - 0.4**2), np.sqrt(2.5**2 - 0.4**2)], rtol=1e-12)
    np.testing.assert_array_equal(unmodelled_error_sd_m([1.0, 1.0], [1.2, 1.0]), [0.0, 0.0])


def _line_fit_p9(n: int, dt: float, r: float, at_end: bool) -> np.ndarray:
    """P9 of a least-squares line (position, velocity) through n fixes of variance r every dt s,
    at the last fix or at the centre, the same on each NED axis."""
    t = np.arange(n) * dt
    t = t - (t[-1] if at_end else t.mean())
    H = np.column_stack([np.ones(n), t])
    C = np.linalg.inv(H.T @ H) * r
    P9 = np.zeros((1, 9, 9))
    for i in range(3):
        P9[0, i, i], P9[0, 3 + i, 3 + i] = C[0, 0], C[1, 1]
        P9[0, i, 3 + i] = P9[0, 3 + i, i] = C[0, 1]
    return P9


def test_velocity_span_is_the_line_fits_span():
    """`velocity_span_s` on the exact covariance of a least-squares line through n fixes: at the
    centre sqrt(12) sigma_p / sigma_v = dt sqrt(n^2 - 1) exactly; at the end it tends to n dt."""
    from tpos_cli.fusion.gps_error import velocity_span_s

    n, dt = 201, 0.5
    centre = velocity_span_s(_line_fit_p9(n, dt, 0.04, at_end=False), two_sided=True)
    np.testing.assert_allclose(centre, dt * np.sqrt(n * n - 1.0), rtol=1e-9)
    end = velocity_span_s(_line_fit_p9(n, dt, 0.04, at_end=True), two_sided=False)
    np.testing.assert_allclose(end, dt * np.sqrt((n * n - 1.0) * (1.0 + 3.0 * (n - 1.0) / (n + 1.0)) / 4.0), rtol=1e-9)
    np.testing.assert_allclose(end, n * dt, rtol=0.01)


def test_unmodelled_velocity_var_is_the_gauss_markov_slope():
    """Analytic: 2 sigma^2 (1 - exp(-T / tau)) / T^2, the variance of (b(t + T) - b(t)) / T for a
    first-order Gauss-Markov b (checked on exact AR(1) draws); tau from `matched_tau_bound_s` makes
    the change over the matched span equal the white variance, and is the worst case."""
    from tpos_cli.fusion.gps_error import matched_tau_bound_s, unmodelled_velocity_var

    sigma, tau, T = 1.0, 300.0, 30.0
    np.testing.assert_allclose(unmodelled_velocity_var(sigma, tau, T), 2.0 * (1.0 - np.exp(-T / tau)) / T**2, rtol=1e-12)
    rng = np.random.default_rng(0)
    b0 = rng.standard_normal(40000) * sigma  # stationary start, then the exact AR(1) step over T
    a = np.exp(-T / tau)
    bT = a * b0 + np.sqrt(1.0 - a * a) * sigma * rng.standard_normal(b0.size)
    mc = np.var((bT - b0) / T)
    assert abs(mc / unmodelled_velocity_var(sigma, tau, T) - 1.0) < 0.05  # 40000 draws: SE of a variance 0.7 %

    white, span_m = 0.25, 10.0
    tau_min = matched_tau_bound_s([sigma, 0.0, 0.1], [white, white, white], [span_m] * 3)
    np.testing.assert_allclose(2.0 * sigma**2 * (1.0 - np.exp(-span_m / tau_min[0])), white**2, rtol=1e-12)
    np.testing.assert_array_equal(tau_min[1:], [0.0, 0.0])  # no unmodelled error; white^2 >= 2 sigma^2: no bound
    var = unmodelled_velocity_var([sigma, 0.0, 0.1], tau_min, T)
    assert var[1] == 0.0
    np.testing.assert_allclose(var[2], 2.0 * 0.1**2 / T**2, rtol=1e-12)  # tau 0: the whole error from fix to fix
    assert var[0] > unmodelled_velocity_var(sigma, 2.0 * tau_min[0], T)  # slower wander: a smaller slope
    # at the matched span itself the slope variance is the white variance over the span squared
    np.testing.assert_allclose(unmodelled_velocity_var(sigma, tau_min[0], span_m), white**2 / span_m**2, rtol=1e-12)


def test_stated_split_recovers_the_white_and_correlated_parts_at_rest():
    """Fixes at rest with a 4 mm white and a 9 mm Gauss-Markov error (tau 100 s, 1 Hz) whose receiver
    states the total (9.85 mm): the split finds the white SD from the fix-to-fix scatter and leaves the
    rest of the stated variance to the error states; a white receiver at its stated SD is not split."""
    from tpos_cli.fusion.gps_error import stated_split, white_sds

    rng = np.random.default_rng(0)
    t = np.arange(400.0)
    a = np.exp(-1.0 / 100.0)
    b = np.zeros((t.size, 3))
    b[0] = rng.standard_normal(3) * 0.009
    for k in range(1, t.size):
        b[k] = a * b[k - 1] + np.sqrt(1 - a * a) * 0.009 * rng.standard_normal(3)
    ned = b + 0.004 * rng.standard_normal((t.size, 3))
    stated = np.full((t.size, 3), np.hypot(0.004, 0.009))
    stops = np.array([[0.0, 60.0], [150.0, 200.0], [300.0, 340.0]])  # 150 fixes at rest
    s = stated_split(t, ned, stated, stops, np.array([True, True]))
    # the white SD from ~300 horizontal differences: to about 6 % (1 / sqrt(2 n_eff)); 20 % allows
    # the Gauss-Markov term's share of the differences and the draw
    np.testing.assert_allclose(s.white_m, 0.004, rtol=0.2)
    np.testing.assert_allclose(s.white_m ** 2 + s.gm_m ** 2, stated[0, [0, 2]] ** 2)  # the budget is kept
    np.testing.assert_allclose(white_sds(stated, s)[:, 0], s.white_m[0])
    # a white receiver at its stated SD (no correlated part): the scatter is consistent, nothing is split
    w = stated_split(t, 0.01 * rng.standard_normal((t.size, 3)), np.full((t.size, 3), 0.01), stops, np.array([True, True]))
    assert np.all(w.gm_m == 0.0)
    # SDs the receiver did not state (pipeline defaults) are no accuracy to split
    d = stated_split(t, ned, stated, stops, np.array([False, False]))
    assert np.all(d.gm_m == 0.0)
