"""Trajectory exports: epochs at a rate, solution choice."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tpos_cli.errors import InvalidInputError
from tpos_cli.export.trajectory import epochs_at_rate, trajectory_table
from tpos_cli.report.solutions import choose_solution, rank_solutions


def test_epochs_at_rate_keeps_real_epochs_nearest_each_tick():
    t = np.arange(0.0, 10.0001, 0.1) + 0.03  # 10 Hz, offset from whole seconds
    i = epochs_at_rate(t, 1.0)
    assert i[0] == 0 and i[-1] == t.size - 1
    # ticks at 1..10 s pick 1.03..10.03; the first and last epochs are always kept
    np.testing.assert_allclose(t[i], np.r_[0.0, np.arange(1.0, 10.01)] + 0.03, atol=1e-9)
    assert np.array_equal(epochs_at_rate(t, 100.0), np.arange(t.size))  # above the native rate: all
    assert np.array_equal(epochs_at_rate(t, None), np.arange(t.size))
    with pytest.raises(InvalidInputError):
        epochs_at_rate(t, 0.0)


def test_epochs_at_rate_far_above_the_epochs_builds_no_grid(monkeypatch):
    # `tpos export --rate 1e308` was an internal error (exit 1: a tick grid of span x rate); 1e9 on an
    # hour at 100 Hz would be 3.6e12 ticks. Every epoch is the nearest to some tick there.
    t = 408639.749 + np.arange(360_000) / 100.0
    for rate in (1e9, 1e308):
        assert np.array_equal(epochs_at_rate(t, rate), np.arange(t.size))
    # the cell rule used above MAX_TICKS_PER_EPOCH picks the grid's epochs (irregular epochs: no
    # tick lies exactly half-way between two of them)
    from tpos_cli.export import trajectory as tr

    rng = np.random.default_rng(5)
    for rate in (0.5, 1.0, 3.7, 10.0):
        t = 1000.0 + np.cumsum(rng.uniform(0.02, 0.18, 500))
        grid = epochs_at_rate(t, rate)
        monkeypatch.setattr(tr, "MAX_TICKS_PER_EPOCH", 0)
        assert np.array_equal(epochs_at_rate(t, rate), grid), rate
        monkeypatch.setattr(tr, "MAX_TICKS_PER_EPOCH", 4)


def test_best_solution_order_and_unknown_names():
    assert rank_solutions(["forward", "backward", "smoothed"])[0] == "smoothed"
    assert rank_solutions(["gyro", "lf1", "lf2", "fkf", "fkf_raw", "fkf_cal"])[0] == "fkf_cal"
    assert rank_solutions(["lc", "tc", "fatci", "smoothed"])[:2] == ["smoothed", "fatci"]
    assert rank_solutions(["mine", "forward"]) == ["forward", "mine"]
    with pytest.raises(InvalidInputError, match="the run has: forward"):
        choose_solution(["forward"], "smoothed", "x")


def test_trajectory_table_sigma_u_from_sigma_d_and_yaw_range():
    df = pd.DataFrame(
        {
            "t": [0.0, 1.0],
            "lat": [45.0, 45.0001],
            "lon": [-73.0, -73.0],
            "h": [10.0, 10.0],
            "roll": 0.0,
            "pitch": 0.0,
            "yaw": [-10.0, 350.0],
            "solution": "forward",
            "sigma_n": 1.0,
            "sigma_e": 1.0,
            "sigma_d": 2.0,
        }
    )
    tab, zone = trajectory_table(df, "forward")
    assert list(tab["sigma_u"]) == [2.0, 2.0] and list(tab["yaw"]) == [350.0, 350.0]
    assert zone.label == "18N" and np.all(np.isfinite(tab["utm_e_m"]))
