"""WGS-84 Earth model: radii of curvature, normal gravity, Earth and transport rates.

Numpy API over scalars or arrays; the numba twins used inside kernels are in `_kernels.py`
and are tested against these. References: Groves, *Principles of GNSS, Inertial, and
Multisensor Integrated Navigation Systems*, 2nd ed., Eq. 2.105-2.106 (radii), 2.134 and
2.139 (Somigliana gravity with height correction), 5.44 (transport rate).
"""

from __future__ import annotations

import numpy as np

A_M = 6378137.0  # semi-major axis
F = 1.0 / 298.257223563  # flattening
B_M = A_M * (1.0 - F)
E2 = F * (2.0 - F)  # first eccentricity squared
OMEGA_IE_RPS = 7.292115e-5  # Earth rotation rate
G0_MPS2 = 9.80665  # standard gravity (CGPM 1901): the unit g of accelerometer data sheets, mg, and the `g` unit
GM_M3PS2 = 3.986004418e14
GAMMA_E_MPS2 = 9.7803253359  # normal gravity at the equator
GAMMA_P_MPS2 = 9.8321849378  # normal gravity at the poles
SOMIGLIANA_K = (B_M * GAMMA_P_MPS2) / (A_M * GAMMA_E_MPS2) - 1.0
M_RATIO = OMEGA_IE_RPS**2 * A_M**2 * B_M / GM_M3PS2


def meridian_radius_m(lat_rad):
    """Meridian (north-south) radius of curvature R_N, m (Groves Eq. 2.105)."""
    s2 = np.sin(lat_rad) ** 2
    return A_M * (1.0 - E2) / (1.0 - E2 * s2) ** 1.5


def transverse_radius_m(lat_rad):
    """Transverse (prime vertical, east-west) radius of curvature R_E, m (Groves Eq. 2.106)."""
    s2 = np.sin(lat_rad) ** 2
    return A_M / np.sqrt(1.0 - E2 * s2)


def normal_gravity_mps2(lat_rad, h_m):
    """Magnitude of normal gravity (gravitation plus centrifugal) at height h, m/s^2.

    Somigliana on the ellipsoid (Groves Eq. 2.134) with the second-order height
    correction (Groves Eq. 2.139).
    """
    s2 = np.sin(lat_rad) ** 2
    g0 = GAMMA_E_MPS2 * (1.0 + SOMIGLIANA_K * s2) / np.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 / A_M * (1.0 + F + M_RATIO - 2.0 * F * s2) * h_m + 3.0 * h_m**2 / A_M**2)


def gravity_ned_mps2(lat_rad, h_m):
    """Normal gravity vector in NED, m/s^2, shape (..., 3); along +down (deflection ignored)."""
    g = np.asarray(normal_gravity_mps2(lat_rad, h_m), dtype=float)
    out = np.zeros(g.shape + (3,))
    out[..., 2] = g
    return out


def earth_rate_ned_rps(lat_rad):
    """Earth rotation rate resolved in NED, rad/s, shape (..., 3)."""
    lat = np.asarray(lat_rad, dtype=float)
    out = np.zeros(lat.shape + (3,))
    out[..., 0] = OMEGA_IE_RPS * np.cos(lat)
    out[..., 2] = -OMEGA_IE_RPS * np.sin(lat)
    return out


def transport_rate_ned_rps(lat_rad, h_m, vel_ned_mps):
    """Rate of the NED frame w.r.t. the Earth, rad/s, shape (..., 3) (Groves Eq. 5.44)."""
    v = np.asarray(vel_ned_mps, dtype=float)
    rn = meridian_radius_m(lat_rad) + h_m
    re = transverse_radius_m(lat_rad) + h_m
    out = np.empty(v.shape)
    out[..., 0] = v[..., 1] / re
    out[..., 1] = -v[..., 0] / rn
    out[..., 2] = -v[..., 1] * np.tan(lat_rad) / re
    return out


def ned_rate_to_lla_rate(lat_rad, h_m, vel_ned_mps):
    """Geodetic rates (dlat/dt, dlon/dt in rad/s, dh/dt in m/s) from NED velocity (Groves Eq. 2.111)."""
    v = np.asarray(vel_ned_mps, dtype=float)
    rn = meridian_radius_m(lat_rad) + h_m
    re = transverse_radius_m(lat_rad) + h_m
    out = np.empty(v.shape)
    out[..., 0] = v[..., 0] / rn
    out[..., 1] = v[..., 1] / (re * np.cos(lat_rad))
    out[..., 2] = -v[..., 2]
    return out
