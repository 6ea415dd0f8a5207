"""Rotations: DCM, Euler angles, rotation vectors, quaternions, sensor-axes letters.

Conventions: `C_nb` maps body (FRD) vectors to navigation (NED) vectors; Euler angles are
roll, pitch, yaw in radians with `C_nb = Rz(yaw) @ Ry(pitch) @ Rx(roll)`. Quaternions are
scalar-first `[w, x, y, z]`. The numpy API accepts single values or stacks with a leading axis.
"""

from __future__ import annotations

import numpy as np

_AXIS_LETTERS = {
    "F": (1.0, 0.0, 0.0),
    "B": (-1.0, 0.0, 0.0),
    "R": (0.0, 1.0, 0.0),
    "L": (0.0, -1.0, 0.0),
    "D": (0.0, 0.0, 1.0),
    "U": (0.0, 0.0, -1.0),
}


def skew(v):
    """Cross-product matrix [v x], shape (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def euler_to_dcm(roll_rad, pitch_rad, yaw_rad):
    """C_nb from roll, pitch, yaw (rad): Rz(yaw) Ry(pitch) Rx(roll); shape (..., 3, 3)."""
    r, p, y = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (roll_rad, pitch_rad, yaw_rad)))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    out = np.empty(r.shape + (3, 3))
    out[..., 0, 0] = cp * cy
    out[..., 0, 1] = -cr * sy + sr * sp * cy
    out[..., 0, 2] = sr * sy + cr * sp * cy
    out[..., 1, 0] = cp * sy
    out[..., 1, 1] = cr * cy + sr * sp * sy
    out[..., 1, 2] = -sr * cy + cr * sp * sy
    out[..., 2, 0] = -sp
    out[..., 2, 1] = sr * cp
    out[..., 2, 2] = cr * cp
    return out


def dcm_to_euler(C_nb):
    """(roll, pitch, yaw) in rad from C_nb, each shape (...); yaw in (-pi, pi]."""
    C = np.asarray(C_nb, dtype=float)
    roll = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    pitch = -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0))
    return roll, pitch, _yaw(C)


def _yaw(C):
    """dcm_to_euler's yaw of C_nb (..., 3, 3) alone."""
    return np.arctan2(C[..., 1, 0], C[..., 0, 0])


def euler_error_map(C_nb):
    """M (..., 3, 3) with phi = M @ d(roll, pitch, yaw) for a NED attitude error phi (small angles).

    phi = d_roll C_nb e_x + d_pitch Rz(yaw) e_y + d_yaw e_z (C_nb = Rz Ry Rx: each Euler rate
    turns about its own intermediate axis); the sign convention of phi does not matter for
    covariances.
    """
    C = np.asarray(C_nb, dtype=float)
    yaw = _yaw(C)
    M = np.zeros(C.shape)
    M[..., :, 0] = C[..., :, 0]
    M[..., 0, 1] = -np.sin(yaw)
    M[..., 1, 1] = np.cos(yaw)
    M[..., 2, 2] = 1.0
    return M


def euler_sigmas_deg(C_nb, P_att_rad2):
    """SDs (..., 3) of roll, pitch, yaw in degrees from NED attitude-error covariances (..., 3, 3) rad^2.

    The one conversion every solution table uses: Cov(d_euler) = M^-1 P_att M^-T (`euler_error_map`).
    Singular at pitch = +-90 deg, where Euler angles are.
    """
    C = np.asarray(C_nb, dtype=float)
    P = np.asarray(P_att_rad2, dtype=float)
    # M = [[A, 0], [b^T, 1]] with A = M[:2, :2], b = M[2, :2] (b[1] = 0): M^-1 = [[A^-1, 0],
    # [-b^T A^-1, 1]], A^-1 = [[a11, -a01], [-a10, a00]] / det A, only the diagonal of M^-1 P M^-T
    # (rows r_i of M^-1: r_i P r_i^T), elementwise over the stack (np.linalg.inv and two stacked
    # matmuls cost 16 ms per hour of 10 Hz rows)
    # (`euler_error_map`'s entries, without building M)
    yaw = _yaw(C)
    a00, a01, a10, a11, b0 = C[..., 0, 0], -np.sin(yaw), C[..., 1, 0], np.cos(yaw), C[..., 2, 0]
    det = a00 * a11 - a01 * a10
    r0 = (a11 / det, -a01 / det)
    r1 = (-a10 / det, a00 / det)
    r2 = (-b0 * r0[0], -b0 * r0[1])
    p00, p01, p10, p11 = P[..., 0, 0], P[..., 0, 1], P[..., 1, 0], P[..., 1, 1]

    def quad2(r):  # r P[:2, :2] r^T
        return r[0] * (r[0] * p00 + r[1] * p01) + r[1] * (r[0] * p10 + r[1] * p11)

    var = np.stack([quad2(r0), quad2(r1),
                    quad2(r2) + r2[0] * (P[..., 0, 2] + P[..., 2, 0]) + r2[1] * (P[..., 1, 2] + P[..., 2, 1]) + P[..., 2, 2]],
                   axis=-1)
    return np.degrees(np.sqrt(np.clip(var, 0.0, None)))


def attitude_cov_from_euler_sigmas(C_nb, sigma_rpy_deg):
    """NED attitude-error covariances (..., 3, 3) rad^2 for independent Euler-angle SDs (..., 3) deg:
    the inverse of `euler_sigmas_deg`, P_att = M diag(sigma^2) M^T."""
    M = euler_error_map(C_nb)
    s = np.radians(np.broadcast_to(np.asarray(sigma_rpy_deg, dtype=float), M.shape[:-1]))
    return M @ (s[..., :, None] ** 2 * np.eye(3)) @ np.swapaxes(M, -1, -2)


def rotvec_to_dcm(rotvec):
    """DCM of a rotation vector (axis times angle, rad), shape (..., 3, 3)."""
    from scipy.spatial.transform import (
        Rotation,  # lazy: 0.2 s of start-up for every command otherwise
    )

    rv = np.asarray(rotvec, dtype=float)
    return Rotation.from_rotvec(rv.reshape(-1, 3)).as_matrix().reshape(rv.shape[:-1] + (3, 3))


def dcm_to_rotvec(C):
    """Rotation vector (rad) of a DCM, shape (..., 3)."""
    from scipy.spatial.transform import (
        Rotation,  # lazy: 0.2 s of start-up for every command otherwise
    )

    C = np.asarray(C, dtype=float)
    return Rotation.from_matrix(C.reshape(-1, 3, 3)).as_rotvec().reshape(C.shape[:-2] + (3,))


def quat_to_dcm(q):
    """DCM from scalar-first unit quaternions, shape (..., 3, 3)."""
    from scipy.spatial.transform import (
        Rotation,  # lazy: 0.2 s of start-up for every command otherwise
    )

    q = np.asarray(q, dtype=float)
    xyzw = np.concatenate([q[..., 1:], q[..., :1]], axis=-1).reshape(-1, 4)
    return Rotation.from_quat(xyzw).as_matrix().reshape(q.shape[:-1] + (3, 3))


def dcm_to_quat(C):
    """Scalar-first unit quaternions (w >= 0) from DCMs, shape (..., 4)."""
    from scipy.spatial.transform import (
        Rotation,  # lazy: 0.2 s of start-up for every command otherwise
    )

    C = np.asarray(C, dtype=float)
    xyzw = Rotation.from_matrix(C.reshape(-1, 3, 3)).as_quat(canonical=True)
    return np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=-1).reshape(C.shape[:-2] + (4,))


def axes_to_dcm(axes: str):
    """C_bs: maps a vector logged in the sensor axes named by `axes` to body FRD.

    `axes` is three letters from F, B, R, L, U, D giving where the sensor's x, y, z point
    (the contract's `[imu] axes`). Raises ValueError unless the letters name a right-handed frame.
    """
    if not isinstance(axes, str) or len(axes) != 3 or any(c not in _AXIS_LETTERS for c in axes.upper()):
        raise ValueError(f"axes must be three letters from F, B, R, L, U, D, got {axes!r}")
    C = np.array([_AXIS_LETTERS[c] for c in axes.upper()]).T
    if not np.isclose(np.linalg.det(C), 1.0):
        raise ValueError(
            f"axes {axes!r} do not form a right-handed frame (repeated or opposite axes, or a mirror)"
        )
    return C


def wrap_angle_rad(a):
    """Wrap angles to (-pi, pi]."""
    return -((-np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi)


def wrap_angle_deg(a):
    """Wrap angles to (-180, 180]."""
    return -((-np.asarray(a, dtype=float) + 180.0) % 360.0 - 180.0)
