"""Kalman predict and update kernels (paper 003 Eq. 1-5, 13-14), in place over float64 arrays.

Every kernel works for any state dimension n and measurement dimension m, so the 15-state
INS/GPS filter and a ranging filter with extra anchor-bias states share them. They modify
`x` and `P` in place (no allocation of the n x n result in the caller's loop) and are usable
from another module's `@njit` loop as plain function calls.

The algebra is written as element loops over the indices, not as `@`, `np.linalg.solve` or
array assignment: those cost numba far more to compile (BLAS dispatch per memory layout, LAPACK
wrappers, formatted shape-mismatch errors) than they save at n <= 25, and every kernel that calls
these pays that compile again (issue 15: 6 of the first run's 30 s of compiling were here).
Inverses are never formed: S = L L^T (Cholesky), then triangular substitutions.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def matmul_into(A, B, out):
    """out (m, p) = A B for A (m, n), B (n, p); `out` must not alias A or B. Loop order i, k, j:
    the innermost loop runs along rows of B and out (contiguous, so it vectorizes without
    reassociating the sums; each sum still adds k = 0, 1, ... in order)."""
    m, n = A.shape
    p = B.shape[1]
    for i in range(m):
        for j in range(p):
            out[i, j] = 0.0
        for k in range(n):
            a = A[i, k]
            for j in range(p):
                out[i, j] += a * B[k, j]


@njit(cache=True)
def sandwich_into(A, B, out):
    """out (m, m) = A B A^T for A (m, n), B (n, n); `out` must not alias A or B."""
    m, n = A.shape
    T = np.empty((m, n))
    matmul_into(A, B, T)
    At = np.empty((n, m))
    for i in range(m):
        for k in range(n):
            At[k, i] = A[i, k]
    matmul_into(T, At, out)


@njit(cache=True)
def quadratic_form(P, a, b):
    """a^T P b for P (n, n), a and b (n,)."""
    n = a.shape[0]
    v = 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += P[i, j] * b[j]
        v += a[i] * s
    return v


@njit(cache=True)
def symmetrize(P):
    """P <- (P + P^T) / 2 in place."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v


@njit(cache=True)
def cholesky_into(S, L):
    """Lower-triangular L with S = L L^T (S symmetric, m x m); False if S is not positive definite."""
    m = S.shape[0]
    for j in range(m):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, m):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
        for i in range(j):
            L[i, j] = 0.0
    return True


@njit(cache=True)
def forward_substitute(L, b, w):
    """w = L^-1 b for lower-triangular L (m, m), b and w (m,)."""
    for i in range(L.shape[0]):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * w[k]
        w[i] = s / L[i, i]


@njit(cache=True)
def cho_solve_into(L, b, out):
    """out = S^-1 b for S = L L^T (L lower-triangular (m, m), from `cholesky_into`), b and out (m,):
    forward then back substitution."""
    m = L.shape[0]
    forward_substitute(L, b, out)
    for j in range(m - 1, -1, -1):  # back substitution with L^T
        s = out[j]
        for k in range(j + 1, m):
            s -= L[k, j] * out[k]
        out[j] = s / L[j, j]


@njit(cache=True)
def discretize(F, Qc, dt, Phi, Qd):
    """Phi = I + F dt + (F dt)^2 / 2 (Eq. 14 to second order), Qd = (Phi Qc Phi^T + Qc) dt / 2.

    `Phi`, `Qd` (n, n) are written in place. Trapezoidal Qd: exact to O(dt^2) for the
    short covariance steps (<= 1 s) used with MEMS IMUs.
    """
    n = F.shape[0]
    matmul_into(F, F, Phi)
    for i in range(n):
        for j in range(n):
            Phi[i, j] = F[i, j] * dt + 0.5 * (dt * dt) * Phi[i, j]
        Phi[i, i] += 1.0
    sandwich_into(Phi, Qc, Qd)
    for i in range(n):
        for j in range(n):
            Qd[i, j] = 0.5 * dt * (Qd[i, j] + Qc[i, j])


@njit(cache=True)
def predict(x, P, Phi, Qd):
    """x <- Phi x ; P <- Phi P Phi^T + Qd, symmetrized (Eq. 1-2); in place."""
    n = x.shape[0]
    x0 = x.copy()
    for i in range(n):
        s = 0.0
        for k in range(n):
            s += Phi[i, k] * x0[k]
        x[i] = s
    sandwich_into(Phi, P.copy(), P)
    for i in range(n):
        for j in range(n):
            P[i, j] += Qd[i, j]
    symmetrize(P)


@njit(cache=True)
def _innovation(x, P, z, H, R):
    """(nu = z - H x (m,), P H^T (n, m), S = H P H^T + R symmetrized (m, m))."""
    m, n = H.shape
    nu = np.empty(m)
    PHt = np.empty((n, m))
    S = np.empty((m, m))
    for i in range(m):
        s = z[i]
        for k in range(n):
            s -= H[i, k] * x[k]
        nu[i] = s
    for i in range(n):
        for j in range(m):
            s = 0.0
            for k in range(n):
                s += P[i, k] * H[j, k]
            PHt[i, j] = s
    for i in range(m):
        for j in range(m):
            s = R[i, j]
            for k in range(n):
                s += H[i, k] * PHt[k, j]
            S[i, j] = s
    symmetrize(S)
    return nu, PHt, S


@njit(cache=True)
def _nis(nu, S, L):
    """nu^T S^-1 nu, as the squared norm of the whitened innovation L^-1 nu (S = L L^T, L written);
    -1 if S is not positive definite."""
    m = nu.shape[0]
    if not cholesky_into(S, L):
        return -1.0
    w = np.empty(m)
    forward_substitute(L, nu, w)
    nis = 0.0
    for i in range(m):
        nis += w[i] * w[i]
    return nis


@njit(cache=True)
def update(x, P, z, H, R):
    """Joseph-form update (Eq. 3-5) in place; returns NIS = nu^T S^-1 nu, or -1 if S is not PD.

    z (m,), H (m, n), R (m, m). Joseph form keeps P symmetric PD even for a gated or
    suboptimal gain. The innovation is nu = z - H x.
    """
    m, n = H.shape
    nu, PHt, S = _innovation(x, P, z, H, R)
    # Cholesky both tests positive definiteness and gives the whitened innovation
    L = np.empty((m, m))
    nis = _nis(nu, S, L)
    if nis < 0.0:
        return -1.0
    # K = P H^T S^-1 without an explicit inverse: row i of K solves S k = (P H^T)[i] (S symmetric)
    K = np.empty((n, m))
    for i in range(n):
        cho_solve_into(L, PHt[i], K[i])
    for i in range(n):
        s = 0.0
        for j in range(m):
            s += K[i, j] * nu[j]
        x[i] += s
    I_KH = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(m):
                s += K[i, k] * H[k, j]
            I_KH[i, j] = -s
        I_KH[i, i] += 1.0
    KRKt = np.empty((n, n))
    sandwich_into(K, R, KRKt)
    sandwich_into(I_KH, P.copy(), P)
    for i in range(n):
        for j in range(n):
            P[i, j] += KRKt[i, j]
    symmetrize(P)
    return nis


@njit(cache=True)
def innovation_statistics(x, P, z, H, R, pvar):
    """A candidate update's statistics, without applying it, from one S = H P H^T + R and its
    Cholesky factor: returns (NIS nu^T S^-1 nu, log det S) and writes pvar[:m] = diag(H P H^T)
    (the predicted variance of each residual component, for covariance matching). NIS -1 and
    log det NaN if S is not PD (`update` then reports it)."""
    m, n = H.shape
    nu, PHt, S = _innovation(x, P, z, H, R)
    for i in range(m):
        s = 0.0
        for k in range(n):
            s += H[i, k] * PHt[k, i]
        pvar[i] = s
    L = np.empty((m, m))
    nis = _nis(nu, S, L)
    if nis < 0.0:
        return nis, np.nan
    logdet = 0.0
    for i in range(m):
        logdet += 2.0 * np.log(L[i, i])
    return nis, logdet


@njit(cache=True)
def nis_of(x, P, z, H, R):
    """Normalized innovation squared nu^T S^-1 nu of a candidate update, without applying it;
    -1 if S is not PD (`update` then reports it)."""
    return innovation_statistics(x, P, z, H, R, np.empty(H.shape[0]))[0]
