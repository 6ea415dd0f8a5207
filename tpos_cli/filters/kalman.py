"""Kalman predict and update kernels (paper 003 Eq. 1-5, 13-14), in place over float64 arrays.

Every kernel works for any state dimension n and measurement dimension m, so the 15-state
INS/GPS filter and a ranging filter with extra anchor-bias states share them. They modify
`x` and `P` in place (no allocation of the n x n result in the caller's loop) and are usable
from another module's `@njit` loop as plain function calls.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def discretize(F, Qc, dt, Phi, Qd):
    """Phi = I + F dt + (F dt)^2 / 2 (Eq. 14 to second order), Qd = (Phi Qc Phi^T + Qc) dt / 2.

    `Phi`, `Qd` (n, n) are written in place. Trapezoidal Qd: exact to O(dt^2) for the
    short covariance steps (<= 1 s) used with MEMS IMUs.
    """
    n = F.shape[0]
    Fdt = F * dt
    Phi[:, :] = Fdt + 0.5 * (Fdt @ Fdt)
    for i in range(n):
        Phi[i, i] += 1.0
    Qd[:, :] = 0.5 * dt * (Phi @ Qc @ Phi.T + Qc)


@njit(cache=True)
def predict(x, P, Phi, Qd):
    """x <- Phi x ; P <- Phi P Phi^T + Qd, symmetrized (Eq. 1-2); in place."""
    x[:] = Phi @ x
    Pn = Phi @ P @ Phi.T + Qd
    P[:, :] = 0.5 * (Pn + Pn.T)


@njit(cache=True)
def update(x, P, z, H, R):
    """Joseph-form update (Eq. 3-5) in place; returns NIS = nu^T S^-1 nu, or -1 if S is not PD.

    z (m,), H (m, n), R (m, m). Joseph form keeps P symmetric PD even for a gated or
    suboptimal gain. The innovation is nu = z - H x.
    """
    n = x.shape[0]
    nu = z - H @ x
    PHt = P @ H.T
    S = H @ PHt + R
    S = 0.5 * (S + S.T)
    # Cholesky both tests positive definiteness and gives the whitened innovation
    for i in range(S.shape[0]):
        if not S[i, i] > 0.0:
            return -1.0
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, nu)
    nis = w @ w
    K = np.linalg.solve(S, PHt.T).T  # K = P H^T S^-1 without an explicit inverse
    x += K @ nu
    I_KH = np.eye(n) - K @ H
    Pn = I_KH @ P @ I_KH.T + K @ R @ K.T
    P[:, :] = 0.5 * (Pn + Pn.T)
    return nis


@njit(cache=True)
def nis_of(x, P, z, H, R):
    """Normalized innovation squared nu^T S^-1 nu of a candidate update, without applying it."""
    nu = z - H @ x
    S = H @ P @ H.T + R
    S = 0.5 * (S + S.T)
    return nu @ np.linalg.solve(S, nu)
