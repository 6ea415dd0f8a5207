"""The contract's fix codes named for a log (`tpos_cli.report.fixes`)."""

from __future__ import annotations

import numpy as np

from tpos_cli.report.fixes import differential_name, fix_names


def test_fix_2_at_a_centimetre_floor_is_rtk_not_sbas():
    # audit (session 25): the rtklibexplorer logs (fix 2, stated SD ~1 cm) read "100 % SBAS/WAAS"
    fix = np.array([2, 2, 2, 1])
    assert differential_name(fix, np.array([0.014, 0.015, 0.02, 3.0])) == "RTK"
    assert differential_name(fix, np.array([1.5, 2.1, 1.8, 3.0])) == "SBAS/WAAS"  # the spec's metre class
    assert differential_name(fix, None) == "differential"  # no stated SD: the kind is not known
    assert differential_name(fix, np.full(4, np.nan)) == "differential"
    assert fix_names(fix, np.array([0.014, 0.015, 0.02, 3.0])) == {0: "none", 1: "autonomous", 2: "RTK"}
