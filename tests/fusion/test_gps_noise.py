"""GPS noise by covariance matching (`fusion.gps_noise`) and IMU decimation (`ins.decimate_imu`)."""

import dataclasses

import numpy as np
import pytest

from tpos_cli.chains.drive_smooth import process_drive
from tpos_cli.config import DriveSmoothParams
from tpos_cli.fusion.gps_noise import bracketed, last_secant, normalized_square, rows_within, scaled_fixes, solve_scale
from tpos_cli.fusion.insgps import GpsFixes
from tpos_cli.ins.mechanization import decimate_imu, integrate
from tpos_cli.session import load_session
from tpos_cli.sim.drive import simulate_drive


def test_decimate_imu_keeps_the_increments():
    """Decimated rows are interval means: their increments sum to the original ones exactly."""
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.009, 0.011, 1001))  # jittered 100 Hz
    g, a = rng.standard_normal((1001, 3)), rng.standard_normal((1001, 3))
    td, gd, ad = decimate_imu(t, g, a, 4)
    assert td[0] == t[0] and td[-1] == t[-1] and td.size == 251
    for full, dec in ((g, gd), (a, ad)):
        inc = np.concatenate([[np.zeros(3)], np.cumsum(full[1:] * np.diff(t)[:, None], axis=0)])
        inc_d = np.concatenate([[np.zeros(3)], np.cumsum(dec[1:] * np.diff(td)[:, None], axis=0)])
        np.testing.assert_allclose(inc_d, inc[::4], atol=1e-12)  # sums of 1000 O(1e-2) terms
    # a tail shorter than the factor ends at the last sample
    td, gd, _ = decimate_imu(t[:1000], g[:1000], a[:1000], 4)
    assert td[-1] == t[999]
    np.testing.assert_allclose(gd[-1], np.average(g[997:1000], axis=0, weights=np.diff(t[996:1000])))


def test_decimated_noise_free_drive_stays_on_the_truth():
    """Noise-free simulated IMU decimated 100 Hz -> 25 Hz integrates onto the truth over 60 s."""
    sim = simulate_drive(75.0, seed=2, noise_free=True, outages=())
    tr = sim.truth
    i0 = int(np.searchsorted(tr.t_s, 15.0))  # after the static start
    td, gd, ad = decimate_imu(sim.imu.t_s[i0:], sim.imu.gyro_b_rps[i0:], sim.imu.acc_b_mps2[i0:], 4)
    ins = integrate(td, gd, ad, tr.lla[i0], tr.vel_ned_mps[i0], np.degrees(tr.rpy_rad[i0]))
    from tpos_cli.frames.geodetic import lla_to_ned
    e = lla_to_ned(ins.lla, tr.lla[i0]) - lla_to_ned(tr.lla[i0::4][: td.size], tr.lla[i0])
    # 25 Hz drops the coning/sculling of the 100 Hz intervals: about a millimetre over a minute
    # of driving (measured 1.2 mm; 100 Hz: 0.3 mm); a bound 8x that still catches any misweighting
    assert np.abs(e).max() < 0.01


def test_normalized_square_and_scale_on_gaussian_innovations():
    rng = np.random.default_rng(1)
    n = 4000
    hph = rng.uniform(0.01, 0.2, n)
    var_true = 0.25
    nu = rng.standard_normal(n) * np.sqrt(hph + var_true)
    m, used = normalized_square(nu, hph, np.full(n, var_true))
    # mean of 4000 chi-square(1): SD sqrt(2/4000) = 0.022; 4 SD
    assert abs(m - 1.0) < 0.09 and used >= n - 5
    s2 = solve_scale(nu, hph, np.full(n, 1.0))
    assert s2 == pytest.approx(var_true, rel=0.1)
    # hph alone larger than the innovations: no positive root
    assert np.isnan(solve_scale(nu * 0.1, hph + 1.0, np.full(n, 1.0)))


def test_bracketed_keeps_the_root_search_inside_what_the_passes_found():
    """m falls as s grows: passes with m > 1 (log m > 0) and m < 1 bracket the root; a step out of
    the bracket goes to its midpoint, one inside stays, and with one side missing nothing changes."""
    hist = [(0.0, np.log(0.3)), (-2.5, np.log(0.64)), (-3.1, np.log(1.40)), (-2.8, np.log(1.34))]
    # the root lies in (-2.8, -2.5): the largest log s with m > 1, the smallest with m < 1
    assert bracketed(-0.9, hist) == pytest.approx(-2.65)  # a secant through two nearly equal m
    assert bracketed(-3.5, hist) == pytest.approx(-2.65)
    assert bracketed(-2.7, hist) == -2.7
    assert bracketed(5.0, hist[:1]) == 5.0  # only m < 1 seen: no bracket yet
    # noisy passes that do not order (m > 1 above m < 1): no bracket to enforce
    assert bracketed(1.0, [(0.0, np.log(1.2)), (-1.0, np.log(0.8))]) == 1.0


def test_last_secant_steps_from_the_latest_pass_at_another_scale():
    """After the loop: a group that stopped inside its band while other groups moved on has its
    last passes at one scale (the walk log's vertical position: s 1 -> m 3.49, then twice s 3.035
    -> m 1.44, 1.35); its last step is the secant through s 1 and the latest pass, at most x 1.2."""
    lo, hi = np.log(0.02), np.log(50.0)
    hist = [(0.0, np.log(3.493)), (np.log(3.035), np.log(1.435)), (np.log(3.035), np.log(1.352))]
    # secant through (0, log 3.493) and (log 3.035, log 1.352): a step of +0.35 in log s, clipped to log 1.2
    assert np.exp(last_secant(hist, lo, hi)) == pytest.approx(3.035 * 1.2)
    # two passes at two scales: the plain secant between them, within the factor 1.2
    two = [(0.0, np.log(1.3)), (np.log(1.1), np.log(1.1))]
    s1 = -np.log(1.1) * np.log(1.1) / (np.log(1.1) - np.log(1.3))
    assert last_secant(two, lo, hi) == pytest.approx(np.log(1.1) + s1)
    # a group that never moved keeps its SDs (no scale but 1); an increasing m gives no step
    assert last_secant([(0.0, np.log(1.2)), (0.0, np.log(1.25))], lo, hi) is None
    assert last_secant([], lo, hi) is None
    assert last_secant([(0.0, np.log(0.8)), (np.log(2.0), np.log(0.9))], lo, hi) is None


def test_scaled_fixes_scales_each_group():
    f = GpsFixes(np.arange(3.0), np.zeros((3, 3)), np.zeros((3, 3)), np.ones((3, 3)), np.ones((3, 3)))
    g = scaled_fixes(f, [2.0, 3.0, 0.5, 0.25])
    np.testing.assert_array_equal(g.sigma_pos_ned_m[0], [2.0, 2.0, 3.0])
    np.testing.assert_array_equal(g.sigma_vel_mps[0], [0.5, 0.5, 0.25])


@pytest.fixture(scope="module")
def quiet_gps(tmp_path_factory):
    """A drive whose receiver is 3x better than the defaults the pipeline assumes (no SD columns)."""
    sim = simulate_drive(420.0, seed=5, outages=((200.0, 20.0),), gps_sigma_h_m=0.5, gps_sigma_v_m=0.8,
                         gps_sigma_vel_mps=0.05)
    session = load_session(sim.write(tmp_path_factory.mktemp("quiet") / "s"))
    gps = dataclasses.replace(session.gps, sigma_neu_m=np.full_like(session.gps.sigma_neu_m, np.nan))
    return sim, dataclasses.replace(session, gps=gps)


def test_estimated_sigmas_recover_the_simulated_receiver(quiet_gps):
    sim, session = quiet_gps
    res = process_drive(session, DriveSmoothParams(), None, names=("forward", "smoothed"))
    g = res.info["gps_noise"]
    # ~700 horizontal / 350 vertical components: the variance to 5-8% (1 SD), the stopping rule
    # |m - 1| < max(0.1, 3 sqrt(2/n)) to ~10-16%: SDs within 15% / 20%
    assert g["sigma_pos_h_m"] == pytest.approx(0.5, rel=0.15)
    assert g["sigma_pos_v_m"] == pytest.approx(0.8, rel=0.2)
    assert g["sigma_vel_h_mps"] == pytest.approx(0.05, rel=0.15)
    # and the main forward run's NIS lands in the band of a mean of M chi-square(3) values
    gi = res.innovations()
    a = gi.nis[gi.accepted[:, 0], 0]
    assert abs(np.mean(a) - 3.0) < 3 * np.sqrt(6.0 / a.size) + 0.3  # 3 SD plus the 10% stopping rule


def test_given_noise_is_kept(quiet_gps):
    _, session = quiet_gps
    res = process_drive(session, DriveSmoothParams(gps_noise="given"), None, names=("forward",))
    g = res.info["gps_noise"]
    assert g["sigma_pos_h_m"] == 1.5 and g["sigma_pos_v_m"] == 2.5
    # the 3x too large SDs make the NIS about 9x too small: the problem the estimate solves
    gi = res.innovations()
    a = gi.nis[gi.accepted[:, 0], 0]
    assert np.mean(a) < 1.0


def test_consistent_log_keeps_its_sds(tmp_path):
    """The simulator writes its true SDs: the estimate must leave the position scales at 1."""
    sim = simulate_drive(300.0, seed=9, outages=())
    session = load_session(sim.write(tmp_path / "s"))
    res = process_drive(session, DriveSmoothParams(gps_sigma_vel_mps=0.05), None, names=("forward",))
    sc = res.info["gps_noise"]["scale"]
    assert sc["pos_h"] == 1.0 and sc["pos_v"] == 1.0
    # the velocity SDs are the pipeline's (the simulator writes none): kept while m is within 1.96 SDs
    # of 1 (`DEFAULT_SD_Z`); set to the simulated 0.05 m/s, they are consistent and kept as given
    assert sc["vel_h"] == 1.0 and sc["vel_v"] == 1.0


def test_rows_within_keeps_the_rows_a_pass_can_process():
    """The rows up to the pass's last sample (inclusive, as `run_filter` places them), in their order;
    the same object when all fit, None stays None."""
    from tpos_cli.fusion.engine import Measurements
    from tpos_cli.fusion.measurements import Kind

    t = np.array([0.5, 3.0, 1.0, 2.0, 2.5])
    rows = Measurements.rows(t, Kind.ZUPT, np.zeros((5, 3)), np.tile(np.eye(3), (5, 1, 1)), dim=3, gated=False)
    cut = rows_within(rows, 2.0)
    np.testing.assert_array_equal(cut.t_s, [0.5, 1.0, 2.0])
    assert rows_within(rows, 3.0) is rows and rows_within(None, 1.0) is None


def test_fixes_at_stops_are_matched_apart_from_the_moving_ones(tmp_path):
    """A receiver whose fixes scatter 4x less standing than moving (as part 1 of the 0708 drive: NIS 0.47
    at its stops under one R, 2.9 moving): the matching per regime brings the rows at stops to their
    d.o.f.; with one R (the old matching) their mean NIS is ~1/16 of it."""
    sim = simulate_drive(300.0, seed=11, outages=(), gps_sigma_h_m=0.5, gps_sigma_v_m=0.8, gps_sigma_vel_mps=0.05)
    session = load_session(sim.write(tmp_path / "s"))
    g = session.gps
    k = np.searchsorted(sim.gps.t_s, g.t_s - g.t_s[0] + sim.gps.t_s[0] - 1e-6)  # the written rows, in order
    assert k.size == sim.gps.t_s.size
    standing = np.linalg.norm(sim.gps.vel_true_ned_mps[k], axis=1) < 0.01
    lla, vel = g.lla.copy(), g.vel_ned_mps.copy()
    lla[standing] = sim.gps.lla_true[k][standing] + (lla[standing] - sim.gps.lla_true[k][standing]) / 4.0
    vel[standing] = sim.gps.vel_true_ned_mps[k][standing] + (vel[standing] - sim.gps.vel_true_ned_mps[k][standing]) / 4.0
    # no SD columns: the scales are free (the receiver's own SDs would only be raised, `raise_only`)
    gps = dataclasses.replace(g, lla=lla, vel_ned_mps=vel, sigma_neu_m=np.full_like(g.sigma_neu_m, np.nan))
    res = process_drive(dataclasses.replace(session, gps=gps), DriveSmoothParams(), None, names=("forward",))
    rest = res.info["gps_noise"]["at_rest"]
    assert rest["n_used"]["pos_h"] >= 20  # the start's 15 s standing at least
    gi = res.innovations()
    at_stop = np.zeros(res.fixes.t_s.size, dtype=bool)
    for a, b in res.stop_intervals_s:
        at_stop |= (res.fixes.t_s >= a) & (res.fixes.t_s <= b)
    a = gi.nis[gi.accepted[:, 0] & at_stop, 0]
    assert a.size >= 10
    assert abs(np.mean(a) - 3.0) < 3 * np.sqrt(6.0 / a.size) + 0.3  # 3 SD plus the 10% stopping rule
