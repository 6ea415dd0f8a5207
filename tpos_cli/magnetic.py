"""Geomagnetic field and declination from the IGRF (package `ppigrf`, IGRF-14, valid to 2030).

Paper 000 Eq. 8 needs the declination D at the observer. Order of preference (the chain's):
`[magnetic] declination_deg` in session.toml, else IGRF at the observer position and the
session's `[session] start_utc`, else an error naming what is missing.
"""

from __future__ import annotations

from datetime import datetime

import numpy as np

from tpos_cli.errors import InvalidInputError


def field_ned_ut(lla, when: datetime) -> np.ndarray:
    """IGRF main field (north, east, down) in uT at geodetic `lla` (3,) and UTC `when`."""
    import ppigrf  # imported here: only sessions without a declination need it

    lat, lon, h = (float(v) for v in np.asarray(lla, dtype=float))
    when = when.replace(tzinfo=None) if when.tzinfo is not None else when
    be, bn, bu = ppigrf.igrf(lon, lat, h / 1000.0, when)  # nT, geodetic east/north/up
    return np.array([float(np.ravel(bn)[0]), float(np.ravel(be)[0]), -float(np.ravel(bu)[0])]) / 1000.0


def declination_deg(lla, when: datetime) -> float:
    """Magnetic declination (deg, east positive) from the IGRF."""
    b = field_ned_ut(lla, when)
    return float(np.degrees(np.arctan2(b[1], b[0])))


def resolve_declination_deg(declination_deg_cfg: float | None, observer_lla, start_utc: datetime | None):
    """(declination deg, source) with source "session.toml" or "IGRF"; InvalidInputError if neither."""
    if declination_deg_cfg is not None:
        return float(declination_deg_cfg), "session.toml"
    missing = []
    if observer_lla is None:
        missing.append("an observer position ([observer] or GPS)")
    if start_utc is None:
        missing.append("[session] start_utc")
    if missing:
        raise InvalidInputError(
            "session.toml: [magnetic] declination_deg is absent and the magnetic model needs "
            + " and ".join(missing)
        )
    return declination_deg(observer_lla, start_utc), "IGRF"
