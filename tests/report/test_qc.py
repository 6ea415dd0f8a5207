"""Quality figures without truth, against hand-made series: estimated bounds, separation,
magnetic disturbance windows, and the drawing helpers that must not lose information."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from tpos_cli.report import layout as L
from tpos_cli.report import qc
from tpos_cli.report.sections import Section, compose


def _traj(solution, t, north_m, sigma=(1.0, 2.0, 3.0), cov_ne=None):
    from tpos_cli.frames.geodetic import ned_to_lla

    lla = ned_to_lla(np.column_stack([north_m, 0 * t, 0 * t]), np.array([45.0, -73.0, 10.0]))
    d = pd.DataFrame(
        {
            "t": t,
            "lat": lla[:, 0],
            "lon": lla[:, 1],
            "h": lla[:, 2],
            "roll": 0.0,
            "pitch": 0.0,
            "yaw": 0.0,
            "solution": solution,
            "sigma_n": sigma[0],
            "sigma_e": sigma[1],
            "sigma_d": sigma[2],
            "sigma_yaw": 0.5,
        }
    )
    if cov_ne is not None:
        d["cov_ne_m2"] = cov_ne
    return d


def test_estimated_bounds_are_the_stated_95_percent_quantities():
    t = np.arange(10.0)
    s = qc.solution_series(_traj("forward", t, t))
    est = qc.estimated_accuracy(s, ["forward"]).to_pandas().iloc[0]
    k2 = np.sqrt(stats.chi2.ppf(0.95, 2))
    assert est.h95_median_m == pytest.approx(k2 * 2.0, rel=1e-9)  # the larger axis of a diagonal covariance
    assert est.v95_median_m == pytest.approx(stats.norm.ppf(0.975) * 3.0, rel=1e-9)
    assert est.yaw95_median_deg == pytest.approx(stats.norm.ppf(0.975) * 0.5, rel=1e-9)
    # a north-east correlation of 0.9 stretches the ellipse: semi-major from the covariance's eigenvalues
    c = 0.9 * 1.0 * 2.0
    s = qc.solution_series(_traj("forward", t, t, cov_ne=c))
    lam = np.linalg.eigvalsh([[1.0, c], [c, 4.0]]).max()
    assert qc.horizontal_95_m(s["forward"])[0] == pytest.approx(k2 * np.sqrt(lam), rel=1e-9)


def test_separation_of_two_runs_and_its_bound():
    t = np.arange(0.0, 10.0, 0.5)
    s = qc.solution_series(pd.concat([_traj("forward", t, t + 3.0), _traj("backward", t[::2], t[::2])]))
    sep = qc.separation(s["forward"], s["backward"])
    inside = np.isfinite(sep.dist_h_m)
    np.testing.assert_allclose(sep.dist_h_m[inside], 3.0, atol=1e-6)  # backward interpolated between its epochs
    assert not inside[-1]  # no extrapolation past backward's last epoch
    # summed covariance diag(2, 8): the 99 % bound is sqrt(chi2_2(0.99) * 8)
    np.testing.assert_allclose(sep.bound99_h_m[inside], np.sqrt(stats.chi2.ppf(0.99, 2) * 8.0), rtol=1e-9)
    np.testing.assert_allclose(sep.nees3[inside], 9.0 / 2.0, rtol=1e-6)


def test_magnetic_disturbance_windows():
    rate = 50.0
    t = np.arange(0.0, 60.0, 1 / rate)
    rng = np.random.default_rng(4)
    b = np.column_stack([20.0 + 0 * t, 0 * t, 45.0 + 0 * t]) + rng.normal(0, 0.3, (t.size, 3))
    b[(t >= 20.0) & (t < 30.0), 0] += 15.0  # a magnet for 10 s
    s = SimpleNamespace(
        imu=SimpleNamespace(t_s=t, mag_b_ut=b), t0_s=100.0, meta=SimpleNamespace(imu_noise=SimpleNamespace(mag_noise_ut=0.3))
    )
    m = qc.magnetic_field(s, reference_ut=float(np.hypot(20.0, 45.0)))
    assert m.threshold_ut == 3.0  # max(3 uT, 5 x 0.3 uT)
    (w,) = m.disturbed
    assert w[0] == pytest.approx(120.0, abs=0.6) and w[1] == pytest.approx(130.0, abs=0.6)  # logger clock, 1 s bins


def test_decimate_keeps_extremes_and_breaks():
    y = np.sin(np.linspace(0, 20, 100_000))
    y[50_000] = 5.0  # a one-sample spike
    y[70_000:70_010] = np.nan  # a gap
    i = L.decimate(y)
    assert i.size <= L.MAX_POINTS + 20 and 50_000 in i
    assert np.isnan(y[i]).any()  # the gap stays a gap
    assert np.nanmin(y[i]) == pytest.approx(np.nanmin(y)) and np.nanmax(y[i]) == 5.0


def test_compose_fills_pages_in_order_and_floats_tables_into_free_room():
    drawn = []

    def sec(name, h, floating=False, new_page=False):
        return Section(name, name, h, lambda fig, top, bottom, n=name: drawn.append((n, top, bottom)), floating=floating, new_page=new_page)

    pages = compose([sec("summary", 0.9, new_page=True), sec("a", 0.6), sec("b", 0.6), sec("table", 0.1, floating=True)])
    names = [n for n, _ in pages]
    assert names == ["summary", "a+table", "b"] or names == ["summary", "a", "b+table"]
    assert len(pages) == 3
    for _, top, bottom in drawn:
        assert 0.0 < bottom < top < 1.0


def test_solution_series_of_interleaved_and_grouped_rows():
    # load_run groups the rows by solution (slices of one array); any other order is split as well
    t = np.arange(6.0)
    a, b = _traj("a", t, 10.0 * t), _traj("b", t, -t, sigma=(4.0, 5.0, 6.0))
    grouped = qc.solution_series(pd.concat([a, b], ignore_index=True))
    inter = pd.concat([a, b]).sort_values("t", kind="stable").reset_index(drop=True)
    inter["flag"] = inter["solution"] == "b"
    mixed = qc.solution_series(inter)
    for s in (grouped, mixed):
        assert list(s) == ["a", "b"]
        np.testing.assert_array_equal(s["a"].t, t)
        np.testing.assert_allclose(s["b"].sigma_neu_m, np.tile([4.0, 5.0, 6.0], (6, 1)))
        np.testing.assert_allclose(s["a"].lla, a[["lat", "lon", "h"]].to_numpy())
    assert mixed["b"].flag.all() and not mixed["a"].flag.any()
    assert not grouped["a"].flag.any() and not grouped["a"].outage.any()


def test_track_points_keep_the_extremes_of_both_axes_and_the_ends():
    from tpos_cli.report.planview import track_points

    n = 100_000
    lat = np.linspace(45.0, 45.1, n)  # straight north, with one eastward spike of a single epoch
    lon = np.full(n, -73.0)
    lon[54_321] = -72.9
    lla = np.column_stack([lat, lon, np.zeros(n)])
    i = track_points(lla)
    assert i.size <= 2 * L.MAX_POINTS + 2
    assert {0, n - 1, 54_321} <= set(i.tolist())


def test_decade_labels_are_plain_text():
    assert [L.decade_label(v) for v in (1e-5, 0.01, 1.0, 10.0, 1000.0, 1e4)] == ["1e-5", "0.01", "1", "10", "1000", "1e4"]
    assert L.decade_label(2.0) == "2" and L.decade_label(0.0) == "" and L.decade_label(np.nan) == ""
