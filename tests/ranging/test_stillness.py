"""Stationary intervals: the Theil-Sen line against scipy.stats.theilslopes; the intervals of a still
node against a moving one, whatever the order of the ranges."""

import numpy as np
import pytest
from scipy.stats import theilslopes

from tpos_cli.ranging.stillness import stationary_intervals, theil_sen


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_theil_sen_matches_scipy(seed):
    rng = np.random.default_rng(seed)
    n = 40 + 30 * seed
    x = np.sort(rng.uniform(0.0, 5.0, n))
    y = 0.03 * x + rng.normal(0.0, 0.05, n)
    y[rng.random(n) < 0.1] += 0.8  # one-sided spikes (NLOS)
    if seed == 2:  # ties in both coordinates
        x = np.round(x, 1)
        y = np.round(y, 2)
    ref = theilslopes(y, x, alpha=0.997)
    got = theil_sen(x, y, 0.997)
    np.testing.assert_allclose(got, (ref.slope, ref.low_slope, ref.high_slope), rtol=1e-12, atol=1e-15)


def test_theil_sen_all_x_equal():
    assert np.all(np.isnan(theil_sen(np.ones(5), np.arange(5.0), 0.95)))


def _scene(seed: int = 0):
    """100 Hz IMU (level, body = NED axes), 3 anchors ranged at 10 Hz: 60 s at rest, 0.5 m/s^2 north
    for 1 s, then 19 s at 0.5 m/s (the IMU as still as at rest: uniform motion)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 80.0, 0.01)
    gyro = rng.normal(0.0, 0.002, (t.size, 3))
    acc = np.array([0.0, 0.0, -9.81]) + rng.normal(0.0, 0.01, (t.size, 3))
    acc[(t > 60.0) & (t <= 61.0), 0] += 0.5
    anchors = np.array([[10.0, 0.0, -2.0], [0.0, 10.0, -2.0], [-10.0, -5.0, -2.0]])
    tr = np.repeat(np.arange(0.0, 80.0, 0.1), 3)
    a = np.tile(np.arange(3), tr.size // 3)
    north = np.where(tr > 61.0, 0.25 + 0.5 * (tr - 61.0), np.where(tr > 60.0, 0.25 * (tr - 60.0) ** 2, 0.0))
    pos = np.column_stack([north, np.zeros_like(tr), np.zeros_like(tr)])
    r = np.linalg.norm(pos - anchors[a], axis=1) + rng.normal(0.0, 0.02, tr.size)
    return t, gyro, acc, tr, a, r


def test_stationary_intervals_find_the_rest_not_the_uniform_motion():
    t, gyro, acc, tr, a, r = _scene()
    iv = stationary_intervals(t, gyro, acc, tr, a, r)
    assert len(iv) == 1
    t0, t1 = iv[0]
    assert t0 < 1.0 and 58.0 < t1 <= 60.0  # the rest, not the moving stretch the IMU cannot tell from it


def test_stationary_intervals_do_not_depend_on_the_order_of_the_ranges():
    # 600 ranges per anchor at rest: thinned for Theil-Sen (_MAX_POINTS), in time order whatever the input order
    t, gyro, acc, tr, a, r = _scene(1)
    perm = np.random.default_rng(2).permutation(tr.size)
    assert stationary_intervals(t, gyro, acc, tr[perm], a[perm], r[perm]) == stationary_intervals(t, gyro, acc, tr, a, r)
