"""Geodetic conversions on (N, 3) arrays, through pymap3d (WGS-84).

`lla` arrays hold latitude and longitude in degrees and ellipsoidal height in metres.
"""

from __future__ import annotations

import numpy as np
import pymap3d


def _cols(a):
    a = np.asarray(a, dtype=float)
    return a[..., 0], a[..., 1], a[..., 2]


def lla_to_ecef(lla):
    """ECEF position, m, shape (..., 3)."""
    return np.stack(pymap3d.geodetic2ecef(*_cols(lla)), axis=-1)


def ecef_to_lla(r_e):
    """Geodetic lat/lon (deg), h (m), shape (..., 3)."""
    return np.stack(pymap3d.ecef2geodetic(*_cols(r_e)), axis=-1)


def lla_to_ned(lla, origin_lla):
    """North/east/down, m, of `lla` in the local-level frame at `origin_lla`."""
    o = np.asarray(origin_lla, dtype=float)
    return np.stack(pymap3d.geodetic2ned(*_cols(lla), o[0], o[1], o[2]), axis=-1)


def ned_to_lla(ned_m, origin_lla):
    """Geodetic position of north/east/down offsets (m) from `origin_lla` (3,), or from one origin
    per row (..., 3)."""
    o = np.asarray(origin_lla, dtype=float)
    return np.stack(pymap3d.ned2geodetic(*_cols(ned_m), o[..., 0], o[..., 1], o[..., 2]), axis=-1)


def lla_to_enu(lla, origin_lla):
    """East/north/up, m, of `lla` in the local-level frame at `origin_lla`."""
    o = np.asarray(origin_lla, dtype=float)
    return np.stack(pymap3d.geodetic2enu(*_cols(lla), o[0], o[1], o[2]), axis=-1)


def enu_to_lla(enu_m, origin_lla):
    """Geodetic position of east/north/up offsets (m) from `origin_lla`."""
    o = np.asarray(origin_lla, dtype=float)
    return np.stack(pymap3d.enu2geodetic(*_cols(enu_m), o[0], o[1], o[2]), axis=-1)


def ecef_to_ned_dcm(lat_deg, lon_deg):
    """C_ne: rotates ECEF vectors into NED at (lat, lon), shape (..., 3, 3)."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    out = np.empty(lat.shape + (3, 3))
    out[..., 0, :] = np.stack([-sl * co, -sl * so, cl], axis=-1)
    out[..., 1, :] = np.stack([-so, co, np.zeros_like(lat)], axis=-1)
    out[..., 2, :] = np.stack([-cl * co, -cl * so, -sl], axis=-1)
    return out
