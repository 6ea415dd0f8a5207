"""Wild GPS fixes left out before the filter (issue 18: one fix 11 km off, or at 0, 0, 0, even the first)."""

import numpy as np

from tpos_cli.fusion.screening import wild_fixes


def _track(n=400, dt=0.25):
    """A car at 15 m/s turning and braking, fixes every 0.25 s (deg, deg, m)."""
    t = np.arange(n) * dt
    yaw = 0.3 * np.sin(t / 20.0)
    sp = 15.0 - 5.0 * np.sin(t / 30.0)
    north = np.cumsum(sp * np.cos(yaw)) * dt
    east = np.cumsum(sp * np.sin(yaw)) * dt
    lat = 48.0 + np.degrees(north / 6378137.0)
    lon = 11.0 + np.degrees(east / (6378137.0 * np.cos(np.radians(48.0))))
    return t, np.column_stack([lat, lon, np.full(n, 500.0)])


def test_a_clean_track_keeps_every_fix():
    rng = np.random.default_rng(0)
    for _ in range(5):  # 1 m noise: a 5-sigma + 10 m threshold is never reached by chance
        t, lla = _track()
        lla[:, :2] += np.degrees(rng.normal(0.0, 1.0, (t.size, 2)) / 6378137.0)
        assert not wild_fixes(t, lla, np.full(t.size, 1.0)).any()


def test_wild_first_middle_and_zero_fixes_go():
    t, lla = _track()
    lla[0, 0] += 0.1  # 11 km north, the first fix
    lla[200] = 0.0  # (0, 0, 0)
    lla[300, 1] += 0.001  # 75 m east
    bad = wild_fixes(t, lla, np.full(t.size, 0.02))
    assert np.flatnonzero(bad).tolist() == [0, 200, 300]


def test_impossible_coordinates_are_wild():
    t, lla = _track(20)
    lla[5, 0] = 95.5
    lla[7, 1] = np.nan
    assert np.flatnonzero(wild_fixes(t, lla)).tolist() == [5, 7]
