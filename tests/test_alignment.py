import numpy as np
import pytest

from tests.attitude.gen import MAG_NED_UT, make
from tpos_cli import alignment as al
from tpos_cli.errors import ProcessingError
from tpos_cli.frames.rotation import euler_to_dcm

ATOL_RAD = 1e-12  # closed form on exact vectors: rounding only


def test_level_and_magnetic_yaw_invert_exact_projections():
    rng = np.random.default_rng(0)
    r = rng.uniform(-1.2, 1.2, 50)
    p = rng.uniform(-1.2, 1.2, 50)
    y = rng.uniform(-np.pi, np.pi, 50)
    C = euler_to_dcm(r, p, y)
    f = np.einsum("nji,j->ni", C, [0.0, 0.0, -9.8])  # Eq. 5
    m = np.einsum("nji,j->ni", C, MAG_NED_UT)
    rr, pp = al.level_rad(f)
    decl = np.arctan2(MAG_NED_UT[1], MAG_NED_UT[0])
    yy = al.magnetic_yaw_rad(m, rr, pp, decl)
    np.testing.assert_allclose(rr, r, rtol=0, atol=ATOL_RAD)
    np.testing.assert_allclose(pp, p, rtol=0, atol=ATOL_RAD)
    np.testing.assert_allclose(np.angle(np.exp(1j * (yy - y))), 0.0, rtol=0, atol=1e-9)


def _rpy(t):
    s = max(0.0, t - 5.0)
    return np.radians([3 * np.sin(0.5 * s), 10 * np.sin(0.4 * s), 40 + 20 * np.sin(0.3 * s)])


def test_static_window_found_and_alignment_within_its_sigma():
    g = make(_rpy, duration_s=15.0)
    w = al.detect_static_window(g.t, g.gyro, g.acc, g.mag)
    assert w.i0 == 0 and w.end_reason == "motion"
    assert 4.0 <= g.t[w.i1 - 1] <= 5.0 + 1e-9  # motion starts at 5 s; never include it
    decl = np.arctan2(MAG_NED_UT[1], MAG_NED_UT[0])
    A = al.coarse_alignment(g.t, g.gyro, g.acc, g.mag, w, declination_rad=decl, lat_rad=np.radians(45.5),
                            acc_noise_mps2=0.0098, mag_noise_ut=0.3)
    err = np.array([A.roll_rad, A.pitch_rad, A.yaw_rad]) - _rpy(0.0)
    assert np.all(np.abs(err) < 4 * A.sigma_rpy_rad)  # 4 sigma: one seeded draw
    np.testing.assert_allclose(A.gyro_bias_rps, g.bias, rtol=0, atol=4 * 1e-4 / np.sqrt(w.i1))


def test_window_stops_at_a_magnetic_disturbance():
    g = make(_rpy, duration_s=15.0, mag_dist_ut=lambda t: np.where(t[:, None] >= 3.0, [20.0, 0, 0], 0.0))
    w = al.detect_static_window(g.t, g.gyro, g.acc, g.mag)
    assert w.end_reason == "magnetic"
    assert 2.7 <= g.t[w.i1 - 1] < 3.0  # the 0.2 s smoothing may stop it slightly early


def test_no_static_window_is_a_clear_error():
    g = make(lambda t: np.radians([0, 0, 30 * t]), duration_s=5.0)
    with pytest.raises(ProcessingError, match="stationary"):
        al.detect_static_window(g.t, g.gyro, g.acc, g.mag)


@pytest.mark.parametrize("n", [3, 4, 5, 50, 2001])
@pytest.mark.parametrize("shape", [(1,), (2,), (7,), (1000,), (1000, 3)])
def test_moving_mean_equals_the_windowed_sums_it_defines(n, shape):
    """_moving reads the clipped window ends as slices of a padded cumulative sum; it must give the
    gathered form c[hi] - c[lo] exactly (same sums, same order), edges with their partial windows."""
    x = np.random.default_rng(3).normal(size=shape)
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    i = np.arange(x.shape[0])
    lo = np.clip(i - n // 2, 0, x.shape[0])
    hi = np.clip(i - n // 2 + n, 0, x.shape[0])
    want = (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))
    got = al._moving(x, n)
    assert got.shape == want.shape
    assert np.array_equal(got, want)
    # and it is the mean over the window: a plain loop (rounding level)
    loop = np.array([x[a:b].mean(axis=0) for a, b in zip(lo, hi)])
    np.testing.assert_allclose(got, loop, rtol=1e-9, atol=1e-12)


def _swaying(t):
    # a hand holding the device "still" at 20 deg roll sways 0.5 deg with a 7 s period
    return np.radians([20.0 + 0.5 * np.sin(2 * np.pi * t / 7.0), 0.0, 30.0])


def test_a_swaying_hold_is_levelled_at_its_edge_sample_not_at_its_mean_attitude():
    g = make(_swaying, duration_s=12.0)
    w = al.StaticWindow(0, int(np.searchsorted(g.t, 10.0)), "motion")
    decl = np.arctan2(MAG_NED_UT[1], MAG_NED_UT[0])
    kw = dict(declination_rad=decl, lat_rad=np.radians(45.5), acc_noise_mps2=0.0098, mag_noise_ut=0.3)
    plain = al.coarse_alignment(g.t, g.gyro, g.acc, g.mag, w, **kw)
    held = al.coarse_alignment(g.t, g.gyro, g.acc, g.mag, w, ref=0, gyro_noise_rps=1e-4, **kw)
    # the window's mean roll is 0.106 deg above the first sample's (0.5 sin over 10/7 periods)
    assert np.degrees(plain.roll_rad) - 20.0 > 0.08
    err = np.array([held.roll_rad, held.pitch_rad, held.yaw_rad]) - _swaying(0.0)
    assert abs(np.degrees(err[0])) < 0.01  # the acc noise's 4/n variance at the window's edge: ~0.004 deg SD
    assert abs(np.angle(np.exp(1j * err[2]))) < 4 * held.sigma_rpy_rad[2]
    # the window-mean rate holds the sway's net turn (0.2 deg / 10 s about x); the turned levelling removes it
    assert abs(held.gyro_bias_rps[0] - g.bias[0]) < 0.1 * abs(plain.gyro_bias_rps[0] - g.bias[0])


def test_a_hold_without_turn_keeps_the_window_means():
    # a still device (gyro free of noise): the turn is the accelerometer noise's slope only, inside what that
    # noise explains, so the referenced means are the plain ones
    g = make(lambda t: np.radians([3.0, -8.0, 40.0]), duration_s=6.0, gyro_sd=0.0)
    w = al.StaticWindow(0, g.t.size, "end_of_log")
    plain = al.coarse_alignment(g.t, g.gyro, g.acc, g.mag, w)
    for ref in (0, g.t.size - 1):
        held = al.coarse_alignment(g.t, g.gyro, g.acc, g.mag, w, ref=ref, acc_noise_mps2=0.0098)
        np.testing.assert_allclose([held.roll_rad, held.pitch_rad, held.yaw_rad],
                                   [plain.roll_rad, plain.pitch_rad, plain.yaw_rad], rtol=0, atol=1e-9)
