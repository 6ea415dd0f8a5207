"""The plan view's ellipse enlargement (`tpos_cli.report.planview`)."""

from __future__ import annotations

import numpy as np

from tpos_cli.report.planview import MAX_ELLIPSE_FRAC, MIN_ELLIPSE_FRAC, _enlargement


def test_small_ellipses_are_enlarged_by_a_1_2_5_factor_to_be_seen():
    f = _enlargement(np.full(12, 0.02), 800.0)
    assert f == 500.0 and 0.02 * f >= MIN_ELLIPSE_FRAC * 800.0
    assert _enlargement(np.full(12, 50.0), 800.0) == 1.0  # big enough: drawn as they are


def test_one_outage_ellipse_is_not_drawn_across_the_map():
    # rtklibexplorer_drive_0708_part1 with 30 s of GPS withheld: eleven 2 cm ellipses and one of
    # 1.2 m; the median's factor (500) would draw a 600 m semi-axis on an 800 m map
    major = np.array([0.02] * 11 + [1.2])
    f = _enlargement(major, 800.0)
    assert f == 20.0 and 1.2 * f <= MAX_ELLIPSE_FRAC * 800.0
    assert _enlargement(np.array([0.02] * 11 + [400.0]), 800.0) == 1.0  # never drawn smaller than it is
