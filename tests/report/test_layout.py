"""Drawing primitives of the report (`tpos_cli.report.layout`): axis limits that a filter's start-up
does not set, the log-axis minor grid drawn without tick objects."""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from tpos_cli.report import layout as L


def _axes():
    return Figure().add_axes([0.1, 0.1, 0.8, 0.8])


def _notes(ax):
    return [t.get_text() for t in ax.texts if "beyond this axis" in t.get_text()]


def test_startup_transient_does_not_set_the_limits_but_a_later_excursion_does():
    x = np.arange(0.0, 300.0, 0.1)
    y = np.full(x.size, 0.05)
    y[:7] = 19.0  # the first 0.7 s: the forward run's initial covariance
    ax = _axes()
    ax.plot(x, y)
    L.ylim_past_startup(ax, [(x, y)], 10.0)
    assert ax.get_ylim() == (0.0, 0.05 * 1.05)
    assert _notes(ax) == ["7 samples beyond this axis (max 19)"]

    y[1500:1600] = 3.0  # a GPS outage in the middle: its excursion is data, shown whole
    ax = _axes()
    ax.plot(x, y)
    L.ylim_past_startup(ax, [(x, y), (x, -y)], 10.0, symmetric=True)
    assert ax.get_ylim() == (-3.0 * 1.05, 3.0 * 1.05) and _notes(ax) == ["14 samples beyond this axis (max 19)"]

    backward = np.full(x.size, 0.05)
    backward[-4:] = 12.0  # a backward run starts at the end
    ax = _axes()
    L.ylim_past_startup(ax, [(x, backward)], 10.0)
    assert ax.get_ylim()[1] == 0.05 * 1.05


def test_no_limits_without_a_transient():
    x = np.arange(0.0, 100.0, 0.1)
    ax = _axes()
    ax.plot(x, np.sin(x))
    before = ax.get_ylim()
    L.ylim_past_startup(ax, [(x, np.sin(x))], 10.0, symmetric=True)
    assert ax.get_ylim() == before and not _notes(ax)


def test_log_minor_grid_is_one_collection_per_axis_without_minor_ticks():
    ax = _axes()
    ax.loglog([0.01, 500.0], [3.0, 800.0])
    ax.set_xlim(0.01, 500.0)
    ax.set_ylim(3.0, 800.0)
    L.log_minor_grid(ax, "xy")
    assert ax.xaxis.get_minorticklocs().size == 0 and ax.yaxis.get_minorticklocs().size == 0
    cols = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(cols) == 2
    xs = sorted(seg[0, 0] for seg in cols[0].get_segments())
    ys = sorted(seg[0, 1] for seg in cols[1].get_segments())
    np.testing.assert_allclose(xs[:3], [0.02, 0.03, 0.04])  # 2..9 x 10^k inside the limits, decades excluded
    assert len(xs) == 8 * 4 + 3 and min(ys) == 4.0 and max(ys) == 700.0 and 100.0 not in ys
    assert ax.get_xlim() == (0.01, 500.0)


def _bar_start(ax):
    (bar,) = [ln for ln in ax.lines if ln.get_linewidth() == 2.5]  # the black bar (its white half is thinner)
    return bar.get_xdata()[0], bar.get_ydata()[0]


def test_scale_bar_goes_to_the_corner_it_covers_least():
    def axes_with(points):
        ax = Figure(figsize=(5, 5)).add_axes([0.1, 0.1, 0.8, 0.8])
        ax.set_xlim(0.0, 100.0)
        ax.set_ylim(0.0, 100.0)
        ax.set_aspect("equal")
        L.scale_bar(ax, np.asarray(points, dtype=float))
        return _bar_start(ax)

    road = [(x, 5.0) for x in np.linspace(0.0, 100.0, 200)]  # a road along the whole bottom edge
    start = [(10.0, 8.0)] * 50  # a long stop in the lower left
    assert axes_with([(50.0, 50.0)]) == (5.0, 5.0)  # nothing near: lower left
    assert axes_with(start)[0] > 50.0  # lower right
    assert axes_with(road) == (5.0, 90.0)  # both lower corners on the road: upper left
    # the car log's case: a lower-left corner full of a long stop's points, a road under the
    # lower-right bar; the upper left is free
    assert axes_with(start + [(x, 6.0) for x in np.linspace(60.0, 100.0, 80)]) == (5.0, 90.0)


def test_north_arrow_leaves_the_upper_right_only_for_data_and_never_takes_the_bars_corner():
    # navego (session 7 audit): the track's end lies in the upper right, under the arrow
    def arrow_with(points, taken=None):
        ax = Figure(figsize=(5, 5)).add_axes([0.1, 0.1, 0.8, 0.8])
        ax.set_xlim(0.0, 100.0)
        ax.set_ylim(0.0, 100.0)
        return L.north_arrow(ax, np.asarray(points, dtype=float), taken=taken)

    assert arrow_with([(50.0, 50.0)]) == "upper right"  # nothing under it: where readers look for it
    end = [(94.0, 90.0)] * 5
    assert arrow_with(end) == "upper left"
    assert arrow_with(end, taken="upper left") == "lower right"  # the scale bar holds the upper left
    one_each = [(94.0, 90.0), (6.0, 85.0), (94.0, 15.0)]  # one point under each free corner
    assert arrow_with(one_each, taken="lower left") == "upper right"  # covered alike: the first of equals


def test_binned_range_is_each_bins_min_median_max_over_round_bins():
    """An hour at 1 Hz: 240 bins at most -> 15 s bins; each bin's figures are those of its own samples."""
    t = np.arange(3600.0) + 100.0
    y = np.where(np.arange(3600) % 2 == 0, 8.0, 9.0)
    y[30] = 12.0  # bin 2 (30-44 s)
    y[31] = np.nan
    b = L.binned_range(t, y)
    assert b is not None and b.bin_s == 15.0 and b.t0_s.size == 240
    assert np.array_equal(b.t0_s, 100.0 + 15.0 * np.arange(240))
    assert (b.lo == 8.0).all() and b.hi[2] == 12.0 and (np.delete(b.hi, 2) == 9.0).all()
    ref = [np.nanmedian(y[i:i + 15]) for i in range(0, 3600, 15)]
    assert np.array_equal(b.med, ref)
    assert L.bin_label(b.bin_s) == "per 15 s" and L.bin_label(60.0) == "per minute" and L.bin_label(300.0) == "per 5 min"


def test_binned_range_leaves_short_series_to_be_drawn_as_they_are():
    assert L.binned_range(np.arange(480.0), np.ones(480)) is None  # at most 2 x 240 samples: drawn one by one
    b = L.binned_range(np.arange(481.0), np.ones(481))
    assert b is not None and b.bin_s == 5.0 and b.t0_s.size == 97  # 480 s: 2 s bins would be 241 with the last sample
