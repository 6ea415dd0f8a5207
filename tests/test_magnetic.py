from datetime import UTC, datetime

import numpy as np
import pytest

from tpos_cli import magnetic
from tpos_cli.errors import InvalidInputError


def test_igrf_declination_montreal_2015():
    # NOAA's calculator gives about -14.6 deg at ETS Montreal in June 2015 (paper 000's site);
    # 0.3 deg covers model differences (IGRF vs WMM) and crustal fields are not modelled by either
    d = magnetic.declination_deg([45.4946, -73.5622, 40.0], datetime(2015, 6, 11, tzinfo=UTC))
    assert abs(d - (-14.6)) < 0.3


def test_field_magnitude_and_dip_plausible_berlin():
    b = magnetic.field_ned_ut([52.5125, 13.3269, 50.0], datetime(2021, 1, 1))
    # IGRF-13/14 at Berlin: ~49.9 uT total, ~68 deg inclination; 1 uT / 1 deg for model epochs
    assert abs(np.linalg.norm(b) - 49.9) < 1.0
    assert abs(np.degrees(np.arctan2(b[2], np.hypot(b[0], b[1]))) - 68.0) < 1.0


def test_resolve_prefers_session_and_names_what_is_missing():
    assert magnetic.resolve_declination_deg(-3.0, None, None) == (-3.0, "session.toml")
    with pytest.raises(InvalidInputError, match="start_utc"):
        magnetic.resolve_declination_deg(None, np.array([45.0, 0.0, 0.0]), None)
