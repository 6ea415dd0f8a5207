"""Least-squares position fix from ranges to anchors (the WSN position of paper 002, Eq. 7-8).

Gauss-Newton on `rho_i = |p - a_i|` for the horizontal position (north, east) with the down
coordinate held at a given value: the anchors of a corridor lie near one plane, so the vertical is
not observable from ranges alone, and a vehicle on a floor knows its height. With that, three
anchors give a fix with one redundant range; the paper's loosely coupled filter needs
"more than three" ranges on a plane (Sec. 2.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Fix:
    """One epoch's fix: pos_ned_m (3,), cov_ne_m2 (2, 2), rms residual, success flag."""

    pos_ned_m: np.ndarray
    cov_ne_m2: np.ndarray
    residual_rms_m: float
    ok: bool


def ls_fix(
    anchors_ned_m: np.ndarray,
    range_m: np.ndarray,
    sigma_m: np.ndarray,
    guess_ned_m: np.ndarray,
    *,
    max_iter: int = 50,
    tol_m: float = 1e-6,
    max_pdop: float = 10.0,
) -> Fix:
    """Weighted Gauss-Newton horizontal fix; down stays at `guess_ned_m[2]`.

    anchors_ned_m : (k, 3); range_m, sigma_m : (k,); guess_ned_m : (3,) starting point.
    `ok` is False with fewer than 3 ranges, on non-convergence or when the geometry is poor
    (sqrt(trace(cov)) / sigma above max_pdop).
    """
    a = np.asarray(anchors_ned_m, dtype=float)
    r = np.asarray(range_m, dtype=float)
    s = np.asarray(sigma_m, dtype=float)
    p = np.array(guess_ned_m, dtype=float)
    nan_fix = Fix(np.full(3, np.nan), np.full((2, 2), np.nan), np.nan, False)
    if r.size < 3:
        return nan_fix
    w = 1.0 / s**2
    for _ in range(max_iter):
        diff = p[None, :] - a
        rho = np.linalg.norm(diff, axis=1)
        if np.any(rho < 1e-9):
            return nan_fix
        H = diff[:, :2] / rho[:, None]  # d rho / d (n, e), paper Eq. 23
        nu = r - rho
        N = H.T @ (w[:, None] * H)
        try:
            dx = np.linalg.solve(N, H.T @ (w * nu))
        except np.linalg.LinAlgError:
            return nan_fix
        p[:2] += dx
        if np.linalg.norm(dx) < tol_m:
            break
    else:
        return nan_fix
    rho = np.linalg.norm(p[None, :] - a, axis=1)
    diff = p[None, :] - a
    H = diff[:, :2] / rho[:, None]
    cov = np.linalg.inv(H.T @ (w[:, None] * H))
    res = r - rho
    pdop = np.sqrt(np.trace(cov)) / np.sqrt(np.mean(s**2))
    return Fix(p, cov, float(np.sqrt(np.mean(res**2))), bool(pdop <= max_pdop))
