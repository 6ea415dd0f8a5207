"""The contract's GPS fix codes named for a log: 0 none, 1 autonomous, 2 differential.

The spec (docs/log-format.md) names 2 SBAS/WAAS differential, but the importers map DGPS and RTK
(fixed and float) there too (`importers.nmea`, `importers.rtklib_pos`) and a session declares nothing
more: the horizontal SDs the receiver states for those fixes tell which it is.
"""

from __future__ import annotations

import numpy as np


def differential_name(fix, sigma_h_m) -> str:
    """What fix = 2 is in this log, from the stated horizontal SDs (m) of those fixes: a centimetre floor
    (`fusion.rtk_float.rtk_floor`, the test the GPS model uses) is RTK, not SBAS (a metre class); a larger
    one SBAS/WAAS as the spec says; no stated SD: not known."""
    from tpos_cli.fusion.rtk_float import rtk_floor

    rtk = None if sigma_h_m is None else rtk_floor(np.asarray(sigma_h_m, dtype=float)[np.asarray(fix) == 2])
    return "differential" if rtk is None else "RTK" if rtk else "SBAS/WAAS"


def fix_names(fix, sigma_h_m) -> dict[int, str]:
    """Names of the fix codes 0, 1, 2 in this log (`differential_name` for 2)."""
    return {0: "none", 1: "autonomous", 2: differential_name(fix, sigma_h_m)}
