"""numba twins of the Earth-model and rotation functions, for use inside compiled kernels.

Scalars and small fixed-size float64 arrays only; tested against `earth.py` and
`rotation.py`, which document the equations. The 3x3 products (`mat_vec3`, ...) are element
loops rather than `@`: numba compiles each `@` through its BLAS dispatch, once per memory layout
of the operands (a transpose is another layout), for a 3x3 that costs more than it computes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.frames.earth import (
    A_M,
    E2,
    GAMMA_E_MPS2,
    M_RATIO,
    OMEGA_IE_RPS,
    SOMIGLIANA_K,
    F,
)

# error_model="numpy" on every kernel: no zero-divisor test at each division (`tpos_cli.filters.kalman`).


@njit(cache=True, error_model="numpy")
def radii_m(lat):
    """(R_N meridian, R_E transverse) radii of curvature, m."""
    s2 = np.sin(lat) ** 2
    d = 1.0 - E2 * s2
    sd = np.sqrt(d)
    return A_M * (1.0 - E2) / (d * sd), A_M / sd  # d * sqrt(d), not d**1.5: the pow was 7 % of a strapdown step


@njit(cache=True, error_model="numpy")
def normal_gravity(lat, h):
    """Normal gravity magnitude, m/s^2 (see earth.normal_gravity_mps2)."""
    s2 = np.sin(lat) ** 2
    g0 = GAMMA_E_MPS2 * (1.0 + SOMIGLIANA_K * s2) / np.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 / A_M * (1.0 + F + M_RATIO - 2.0 * F * s2) * h + 3.0 * h * h / (A_M * A_M))


@njit(cache=True, error_model="numpy")
def earth_rate_ned(lat):
    """Earth rate in NED, rad/s."""
    out = np.zeros(3)
    out[0] = OMEGA_IE_RPS * np.cos(lat)
    out[2] = -OMEGA_IE_RPS * np.sin(lat)
    return out


@njit(cache=True, error_model="numpy")
def transport_rate_ned(lat, h, v):
    """Transport rate in NED, rad/s, from NED velocity v."""
    rn, re = radii_m(lat)
    out = np.empty(3)
    out[0] = v[1] / (re + h)
    out[1] = -v[0] / (rn + h)
    out[2] = -v[1] * np.tan(lat) / (re + h)
    return out


@njit(cache=True, error_model="numpy")
def skew(v):
    """Cross-product matrix of a 3-vector."""
    out = np.zeros((3, 3))
    out[0, 1] = -v[2]
    out[0, 2] = v[1]
    out[1, 0] = v[2]
    out[1, 2] = -v[0]
    out[2, 0] = -v[1]
    out[2, 1] = v[0]
    return out


@njit(cache=True, error_model="numpy")
def rotvec_to_dcm_into(x, y, z, R):
    """Rodrigues DCM of rotation vector (x, y, z) written into R (3, 3), without allocating
    (for per-sample loops). Below 0.01 rad (an IMU sample's rotation, a filter's correction) the
    coefficients sin(a)/a and (1 - cos a)/a^2 are their Taylor series to a^6: the next terms,
    a^8/9! and a^8/10!, are below 3e-22, and 1 - cos(a) would lose 4 of its digits to cancellation;
    no sqrt, sin or cos (6 % of a strapdown step)."""
    a2 = x * x + y * y + z * z
    if a2 < 1e-4:
        s = 1.0 - a2 / 6.0 * (1.0 - a2 / 20.0 * (1.0 - a2 / 42.0))
        c = 0.5 - a2 / 24.0 * (1.0 - a2 / 30.0 * (1.0 - a2 / 56.0))
    else:
        a = np.sqrt(a2)
        s = np.sin(a) / a
        c = (1.0 - np.cos(a)) / a2
    R[0, 0] = 1.0 - c * (y * y + z * z)
    R[1, 1] = 1.0 - c * (x * x + z * z)
    R[2, 2] = 1.0 - c * (x * x + y * y)
    R[0, 1] = -s * z + c * x * y
    R[1, 0] = s * z + c * x * y
    R[0, 2] = s * y + c * x * z
    R[2, 0] = -s * y + c * x * z
    R[1, 2] = -s * x + c * y * z
    R[2, 1] = s * x + c * y * z


@njit(cache=True, error_model="numpy")
def rotvec_to_dcm(rv):
    """Rodrigues' formula, with a series expansion near zero angle."""
    R = np.empty((3, 3))
    rotvec_to_dcm_into(rv[0], rv[1], rv[2], R)
    return R


@njit(cache=True, error_model="numpy")
def dcm_to_rotvec(C):
    """Rotation vector of a DCM (angle below pi)."""
    cos_a = min(1.0, max(-1.0, 0.5 * (C[0, 0] + C[1, 1] + C[2, 2] - 1.0)))
    a = np.arccos(cos_a)
    w = np.empty(3)
    w[0] = C[2, 1] - C[1, 2]
    w[1] = C[0, 2] - C[2, 0]
    w[2] = C[1, 0] - C[0, 1]
    if a < 1e-6:
        return 0.5 * w
    return w * (a / (2.0 * np.sin(a)))


@njit(cache=True, error_model="numpy")
def euler_to_dcm(roll, pitch, yaw):
    """C_nb = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    C = np.empty((3, 3))
    C[0, 0] = cp * cy
    C[0, 1] = -cr * sy + sr * sp * cy
    C[0, 2] = sr * sy + cr * sp * cy
    C[1, 0] = cp * sy
    C[1, 1] = cr * cy + sr * sp * sy
    C[1, 2] = -sr * cy + cr * sp * sy
    C[2, 0] = -sp
    C[2, 1] = sr * cp
    C[2, 2] = cr * cp
    return C


@njit(cache=True, error_model="numpy")
def dcm_to_euler(C):
    """(roll, pitch, yaw) in rad from C_nb."""
    roll = np.arctan2(C[2, 1], C[2, 2])
    pitch = -np.arcsin(min(1.0, max(-1.0, C[2, 0])))
    yaw = np.arctan2(C[1, 0], C[0, 0])
    return roll, pitch, yaw


@njit(cache=True, error_model="numpy")
def orthonormalize(C):
    """Nearest-rotation correction of a DCM that drifted from orthonormality (first-order)."""
    return 1.5 * C - 0.5 * (C @ C.T @ C)


@njit(cache=True, error_model="numpy")
def mat_vec3(A, v):
    """A v for A (3, 3) and v (3,), as a new array."""
    out = np.empty(3)
    for i in range(3):
        out[i] = A[i, 0] * v[0] + A[i, 1] * v[1] + A[i, 2] * v[2]
    return out


@njit(cache=True, error_model="numpy")
def matT_vec3(A, v):
    """A^T v for A (3, 3) and v (3,), as a new array."""
    out = np.empty(3)
    for i in range(3):
        out[i] = A[0, i] * v[0] + A[1, i] * v[1] + A[2, i] * v[2]
    return out


@njit(cache=True, error_model="numpy")
def mat_mat3(A, B):
    """A B for A, B (3, 3), as a new array."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return out


@njit(cache=True, error_model="numpy")
def mat_matT3(A, B):
    """A B^T for A, B (3, 3), as a new array."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[j, 0] + A[i, 1] * B[j, 1] + A[i, 2] * B[j, 2]
    return out
