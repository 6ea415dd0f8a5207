"""Range and position measurement models with their Jacobians (paper 002, Eq. 19-24, 11-12).

Positions are NED metres in the local frame of the session's `[local]` origin, where the anchors
are given (`Session.anchors.ned_m`). The INS position (lat, lon, h) is brought into that frame
through ECEF (`lla_to_local_ned`), exactly: a range is rotation invariant, and the local frame's
axes differ from the vehicle's NED axes by (distance / Earth radius) ~ 1e-5 rad over a building,
which is negligible in the Jacobian rows.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.frames.earth import A_M, E2


@njit(cache=True)
def lla_rad_to_ecef(lat, lon, h):
    """ECEF position (m) of geodetic lat, lon (rad), h (m) (Groves Eq. 2.112)."""
    sl = np.sin(lat)
    re = A_M / np.sqrt(1.0 - E2 * sl * sl)
    out = np.empty(3)
    out[0] = (re + h) * np.cos(lat) * np.cos(lon)
    out[1] = (re + h) * np.cos(lat) * np.sin(lon)
    out[2] = (re * (1.0 - E2) + h) * sl
    return out


@njit(cache=True)
def lla_to_local_ned(lat, lon, h, r0_e, C_ne0):
    """NED position (m) relative to the origin with ECEF position r0_e and ECEF->NED DCM C_ne0."""
    return C_ne0 @ (lla_rad_to_ecef(lat, lon, h) - r0_e)


@njit(cache=True)
def range_residual(p_ned, anchor_ned, range_m, bias_m):
    """nu = rho_W - (|p - a| + eps_d): measured minus predicted range (Eq. 19, 21-22), m."""
    d = p_ned - anchor_ned
    return range_m - (np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) + bias_m)


@njit(cache=True)
def range_jacobian(p_ned, anchor_ned):
    """d rho / d p_ned = (p - a) / rho, the unit line of sight (Eq. 23), shape (3,)."""
    d = p_ned - anchor_ned
    return d / np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
