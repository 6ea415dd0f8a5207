"""Target geolocation from an observer, a laser range and the beam attitude, with covariance.

Paper 000 Eq. 1-2: the beam is the body forward axis, so the target offset in the navigation
frame is p_n = d C_nb e_x = d (cos(pitch) cos(yaw), cos(pitch) sin(yaw), -sin(pitch)) in NED
(Eq. 2 in the package's frames). Eq. 3-4 and 29 (paper 001 Eq. 11-14) carry the offset into ECEF
at the observer and add it to the observer's ECEF position; done here through pymap3d
(`frames.geodetic.ned_to_lla`). Covariance: with C = exp(phi) C_hat, dp = -[p x] phi + e_beam dd,
so Cov(p) = [p x] P_att [p x]^T + sigma_d^2 e e^T (+ the observer's position covariance).

Paper 001 Eq. 31-38: with a shot on a reference point of known position, the pitch/heading
offsets (d_theta, d_psi) follow by least squares from Delta p = A [d_theta, d_psi]; A is the
Jacobian of Eq. 2 (paper 001's own Eq. 9 mixes conventions, so the Jacobian is derived from
paper 000 Eq. 2 instead), solved in NED (equivalent to their ECEF form since C_t^e is a
rotation) and iterated to convergence. Paper 001 Eq. 15-16: slant range and height difference
between targets (heights are exact ellipsoidal heights from pymap3d, not Eq. 16's approximation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from tpos_cli.errors import ProcessingError
from tpos_cli.frames import geodetic
from tpos_cli.frames.rotation import attitude_cov_from_euler_sigmas, euler_to_dcm, skew


@dataclass(frozen=True)
class TargetFix:
    """lla (N,3) target position; ned_m (N,3) offset from the observer; cov_ned_m2 (N,3,3)."""

    lla: np.ndarray
    ned_m: np.ndarray
    cov_ned_m2: np.ndarray

    @property
    def sigma_neu_m(self):
        """(N,3) SD north, east, up, m."""
        return np.sqrt(np.clip(np.diagonal(self.cov_ned_m2, axis1=1, axis2=2), 0.0, None))


def _rows(a, n, shape):
    a = np.asarray(a, dtype=float)
    return np.broadcast_to(a, (n,) + shape).copy() if a.shape != (n,) + shape else a


def beam_second_order_var(P_att_rad2, u, range_m):
    """(N,) m^2: second moment of the along-beam error that an attitude error leaves at range d.

    A beam turned by a small angle theta (the part of the attitude error phi across the beam, covariance
    S = Q P Q with Q = I - u u^T) ends d (cos theta - 1) = -d theta^T theta / 2 along it, which the
    linear term d [phi x] u does not hold. With theta ~ N(0, S): E[(theta^T theta)^2] / 4
    = ((tr S)^2 + 2 tr(S^2)) / 4. It matters when d sigma_theta^2 / 2 reaches the range noise (a degree
    at 12 m: 2 mm, beside 0.2 mm of averaged range noise)."""
    P = np.asarray(P_att_rad2, dtype=float)
    u = np.asarray(u, dtype=float)
    Q = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    S = Q @ P @ Q
    tr = np.trace(S, axis1=1, axis2=2)
    tr2 = np.einsum("nij,nji->n", S, S)
    return np.asarray(range_m, dtype=float) ** 2 * (tr**2 + 2.0 * tr2) / 4.0


def geolocate(observer_lla, C_nb, range_m, *, P_att_rad2=None, sigma_range_m=0.0,
              P_obs_ned_m2=None, lever_b_m=None) -> TargetFix:
    """Target positions from observers (N,3), attitudes C_nb (N,3,3) FRD->NED, ranges (N,) m.

    P_att_rad2 (N,3,3): NED attitude-error covariance (C_true = exp(phi) C_hat); sigma_range_m
    scalar or (N,); P_obs_ned_m2 (N,3,3) observer position covariance; lever_b_m (3,) FRD offset
    of LR1's origin from the point `observer_lla` refers to. Works for static or moving observers.
    """
    C = np.asarray(C_nb, dtype=float)
    if C.ndim == 2:
        C = C[None]
    n = C.shape[0]
    obs = _rows(observer_lla, n, (3,))
    d = _rows(range_m, n, ())
    e = C[:, :, 0]  # Eq. 1: p_b = (d, 0, 0) along the beam
    p = d[:, None] * e
    if lever_b_m is not None:
        p = p + np.einsum("nij,j->ni", C, np.asarray(lever_b_m, dtype=float))
    lla = geodetic.ned_to_lla(p, obs[0]) if np.all(obs == obs[0]) else np.stack(
        [geodetic.ned_to_lla(p[i], obs[i]) for i in range(n)])
    cov = np.zeros((n, 3, 3))
    if P_att_rad2 is not None:
        Pa = _rows(P_att_rad2, n, (3, 3))
        Px = skew(p)
        cov += Px @ Pa @ np.swapaxes(Px, 1, 2)
        cov += beam_second_order_var(Pa, e, d)[:, None, None] * (e[:, :, None] * e[:, None, :])
    s = _rows(sigma_range_m, n, ())
    cov += (s**2)[:, None, None] * (e[:, :, None] * e[:, None, :])
    if P_obs_ned_m2 is not None:
        cov += _rows(P_obs_ned_m2, n, (3, 3))
    return TargetFix(lla=np.asarray(lla).reshape(n, 3), ned_m=p, cov_ned_m2=cov)


def geolocate_rpy(observer_lla, roll_deg, pitch_deg, yaw_deg, range_m, *, sigma_rpy_deg=None,
                  sigma_range_m=0.0, P_obs_ned_m2=None) -> TargetFix:
    """`geolocate` with Euler angles (deg) and optional independent Euler SDs (N,3) deg."""
    r, p, y = (np.radians(np.atleast_1d(np.asarray(a, dtype=float))) for a in (roll_deg, pitch_deg, yaw_deg))
    C = euler_to_dcm(r, p, y)
    P = None
    if sigma_rpy_deg is not None:
        P = attitude_cov_from_euler_sigmas(C, np.broadcast_to(np.asarray(sigma_rpy_deg, dtype=float), (C.shape[0], 3)))
    return geolocate(observer_lla, C, range_m, P_att_rad2=P, sigma_range_m=sigma_range_m, P_obs_ned_m2=P_obs_ned_m2)


def beam_ned_jacobian(pitch_rad, yaw_rad, range_m):
    """(N,3,2) d p_ned / d(pitch, yaw) of Eq. 2 (the A of paper 001 Eq. 36-37, in NED)."""
    th, ps, d = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (pitch_rad, yaw_rad, range_m))
    A = np.zeros((th.size, 3, 2))
    A[:, 0, 0] = -d * np.sin(th) * np.cos(ps)
    A[:, 1, 0] = -d * np.sin(th) * np.sin(ps)
    A[:, 2, 0] = -d * np.cos(th)
    A[:, 0, 1] = -d * np.cos(th) * np.sin(ps)
    A[:, 1, 1] = d * np.cos(th) * np.cos(ps)
    return A


@dataclass(frozen=True)
class Calibration:
    """Pitch and heading offsets (rad): true = measured - offset (paper 001 Eq. 35); residual RMS m;
    cov_rad2 (2,2) covariance of (dpitch, dyaw) from the reference shots' position covariances
    (zeros when none were given)."""

    dpitch_rad: float
    dyaw_rad: float
    residual_rms_m: float
    n_shots: int
    cov_rad2: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))


def calibrate_offsets(observer_lla, pitch_rad, yaw_rad, range_m, reference_lla, iterations=5,
                      cov_ned_m2=None) -> Calibration:
    """Least-squares pitch/heading offsets from shots on reference points (paper 001 Eq. 31-38).

    Arrays (R,) or (R,3) over R reference shots. Delta p = p_measured - p_reference (Eq. 34)
    = A (d_theta, d_psi) (Eq. 36-37); solved by Eq. 38 and iterated (Gauss-Newton) because
    Eq. 36 is the linearization of the transcendental Eq. 34. `cov_ned_m2` (R,3,3): covariance of
    each measured point; the offsets' covariance is then (A^T W A)^-1 A^T W Cov W A (A^T W A)^-1 with
    the Eq. 38 weights W = I (the paper's unweighted solution), i.e. the measured points' errors
    propagated through the least-squares solution.
    """
    obs = np.atleast_2d(np.asarray(observer_lla, dtype=float))
    ref = np.atleast_2d(np.asarray(reference_lla, dtype=float))
    th, ps, d = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (pitch_rad, yaw_rad, range_m))
    R = th.size
    if R < 1:
        raise ProcessingError("calibration needs at least one shot on a reference point")
    obs = np.broadcast_to(obs, (R, 3))
    ref = np.broadcast_to(ref, (R, 3))
    p_ref = np.stack([geodetic.lla_to_ned(ref[i], obs[i]) for i in range(R)])
    x = np.zeros(2)
    for _ in range(iterations):
        tc, pc = th - x[0], ps - x[1]
        p_c = d[:, None] * np.stack([np.cos(tc) * np.cos(pc), np.cos(tc) * np.sin(pc), -np.sin(tc)], axis=-1)
        J = -beam_ned_jacobian(tc, pc, d).reshape(-1, 2)  # d p / d(offset) = -d p / d(angle)
        r = (p_ref - p_c).reshape(-1)  # Eq. 34 residual at the current offsets
        dx, *_ = np.linalg.lstsq(J, r, rcond=None)  # Eq. 38: (A^T A)^-1 A^T Delta p
        x = x + dx
        if np.max(np.abs(dx)) < 1e-12:
            break
    tc, pc = th - x[0], ps - x[1]
    p_c = d[:, None] * np.stack([np.cos(tc) * np.cos(pc), np.cos(tc) * np.sin(pc), -np.sin(tc)], axis=-1)
    res = float(np.sqrt(np.mean(np.sum((p_c - p_ref) ** 2, axis=1))))
    cov = np.zeros((2, 2))
    if cov_ned_m2 is not None:
        J = beam_ned_jacobian(tc, pc, d).reshape(-1, 2)
        G = np.linalg.pinv(J)  # (A^T A)^-1 A^T
        Cp = np.zeros((3 * R, 3 * R))
        for i in range(R):
            Cp[3 * i:3 * i + 3, 3 * i:3 * i + 3] = np.asarray(cov_ned_m2[i], dtype=float)
        cov = G @ Cp @ G.T
    return Calibration(dpitch_rad=float(x[0]), dyaw_rad=float(x[1]), residual_rms_m=res, n_shots=int(R), cov_rad2=cov)


def target_pairs(ids, lla, solution: str, cov_ned_m2=None) -> pd.DataFrame:
    """Slant range (paper 001 Eq. 15), height difference (Eq. 16) and horizontal distance per pair.

    dh_m = h2 - h1 (signed; Eq. 16 is its absolute value). With covariances (T,3,3) the SDs of
    slant range and height difference are propagated assuming independent targets.
    """
    lla = np.asarray(lla, dtype=float)
    ecef = geodetic.lla_to_ecef(lla)
    T = len(ids)
    if T < 2:
        return pd.DataFrame([])
    cols: dict = {"id_1": [], "id_2": [], "solution": [], "slant_range_m": [], "dh_m": [], "horizontal_m": []}
    if cov_ned_m2 is not None:
        cols.update({"sigma_slant_m": [], "sigma_dh_m": []})
    for i in range(T - 1):
        # the NED offsets of every later target from target i in one call (element by element the same numbers
        # as one call per pair; an hour's 336 shots make 56k pairs per solution: 1.0 -> 0.3 s)
        ned = geodetic.lla_to_ned(np.ascontiguousarray(lla[i + 1:]), lla[i])
        for jj, j in enumerate(range(i + 1, T)):
            dv = ecef[j] - ecef[i]
            slant = float(np.linalg.norm(dv))
            n = ned[jj]
            cols["id_1"].append(ids[i])
            cols["id_2"].append(ids[j])
            cols["solution"].append(solution)
            cols["slant_range_m"].append(slant)
            cols["dh_m"].append(float(lla[j, 2] - lla[i, 2]))
            cols["horizontal_m"].append(float(np.hypot(n[0], n[1])))
            if cov_ned_m2 is not None:
                S = np.asarray(cov_ned_m2[i]) + np.asarray(cov_ned_m2[j])
                u = n / max(slant, 1e-12)
                cols["sigma_slant_m"].append(float(np.sqrt(u @ S @ u)))
                cols["sigma_dh_m"].append(float(np.sqrt(S[2, 2])))
    return pd.DataFrame(cols)
