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

# error_model="numpy" on every kernel: a float division is not checked for a zero divisor (numba's default
# raises ZeroDivisionError from a test and branch at every division, which also keeps loops from vectorizing);
# the same numbers for every nonzero divisor, and a zero one gives inf/NaN, which the filters' divergence
# checks report. The drive hour's error-state kernel runs 13 % faster. The filter modules' kernels
# (frames, ins, fusion, smoothing) are compiled alike.


@njit(cache=True, error_model="numpy")
def matmul_into(A, B, out):
    """out (m, p) = A B for A (m, n), B (n, p); `out` must not alias A or B. Loop order i, k, j:
    the innermost loop runs along rows of B and out (contiguous, so it vectorizes without
    reassociating the sums; each sum still adds k = 0, 1, ... in order). Zero elements of A are
    skipped (the filters' transition and measurement matrices are mostly zeros; adding their
    zero products would not change a sum)."""
    m, n = A.shape
    p = B.shape[1]
    for i in range(m):
        for j in range(p):
            out[i, j] = 0.0
        for k in range(n):
            a = A[i, k]
            if a != 0.0:
                for j in range(p):
                    out[i, j] += a * B[k, j]


@njit(cache=True, error_model="numpy")
def _a_bt_at_into(A, B, W):
    """W (m, m) = A B^T A^T for A (m, n), B (n, n): T = A B, then W = A T^T. Both products have A
    on the left, whose zeros `matmul_into` skips (a transition matrix is mostly zeros)."""
    m, n = A.shape
    T = np.empty((m, n))
    matmul_into(A, B, T)
    Tt = np.empty((n, m))
    for i in range(m):
        for k in range(n):
            Tt[k, i] = T[i, k]
    matmul_into(A, Tt, W)


@njit(cache=True, error_model="numpy")
def sandwich_into(A, B, out):
    """out (m, m) = A B A^T for A (m, n), B (n, n) (the transpose of A B^T A^T); `out` must not
    alias A or B."""
    m = A.shape[0]
    W = np.empty((m, m))
    _a_bt_at_into(A, B, W)
    for i in range(m):
        for j in range(m):
            out[i, j] = W[j, i]


@njit(cache=True, error_model="numpy")
def _symmetric_sandwich_into(A, B, out):
    """out (m, m) = A B A^T for a symmetric B (n, n), its upper triangle mirrored (exactly
    symmetric); `out` must not alias A or B."""
    _a_bt_at_into(A, B, out)
    for i in range(out.shape[0]):
        for j in range(i):
            out[i, j] = out[j, i]


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def symmetrize(P):
    """P <- (P + P^T) / 2 in place."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def forward_substitute(L, b, w):
    """w = L^-1 b for lower-triangular L (m, m), b and w (m,)."""
    for i in range(L.shape[0]):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * w[k]
        w[i] = s / L[i, i]


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def cho_solve_matrix_into(L, B, X):
    """X (m, p) = S^-1 B for S = L L^T (L lower-triangular (m, m), from `cholesky_into`) and B
    (m, p): forward then back substitution on whole rows, so the inner loops run along the rows of
    B and X (contiguous; the p right-hand sides at once instead of p calls of `cho_solve_into`).
    `X` must not alias L; it may alias B."""
    m = L.shape[0]
    p = B.shape[1]
    for i in range(m):  # L Y = B, Y in X
        for j in range(p):
            X[i, j] = B[i, j]
        for k in range(i):
            a = L[i, k]
            for j in range(p):
                X[i, j] -= a * X[k, j]
        d = L[i, i]
        for j in range(p):
            X[i, j] /= d
    for i in range(m - 1, -1, -1):  # L^T X = Y
        for k in range(i + 1, m):
            a = L[k, i]
            for j in range(p):
                X[i, j] -= a * X[k, j]
        d = L[i, i]
        for j in range(p):
            X[i, j] /= d


@njit(cache=True, error_model="numpy")
def transition_into(F, dt, Phi):
    """Phi = I + F dt + (F dt)^2 / 2 (Eq. 14 to second order), written in place (`discretize`'s)."""
    n = F.shape[0]
    matmul_into(F, F, Phi)
    for i in range(n):
        for j in range(n):
            Phi[i, j] = F[i, j] * dt + 0.5 * (dt * dt) * Phi[i, j]
        Phi[i, i] += 1.0


@njit(cache=True, error_model="numpy")
def discretize(F, Qc, dt, Phi, Qd):
    """Phi = I + F dt + (F dt)^2 / 2 (Eq. 14 to second order), Qd = (Phi Qc Phi^T + Qc) dt / 2.

    `Phi`, `Qd` (n, n) are written in place. Trapezoidal Qd: exact to O(dt^2) for the
    short covariance steps (<= 1 s) used with MEMS IMUs. A diagonal Qc (white noises on single
    states, as the filters' are) makes Phi Qc a column scaling (the same numbers as the product).
    """
    n = F.shape[0]
    transition_into(F, dt, Phi)
    diagonal = True
    for i in range(n):
        for j in range(n):
            if i != j and Qc[i, j] != 0.0:
                diagonal = False
    if diagonal:
        QPt = np.empty((n, n))  # (Phi Qc)^T
        for k in range(n):
            for i in range(n):
                QPt[k, i] = Phi[i, k] * Qc[k, k]
        matmul_into(Phi, QPt, Qd)
        for i in range(n):
            for j in range(i):
                Qd[i, j] = Qd[j, i]
    else:
        sandwich_into(Phi, Qc, Qd)
    for i in range(n):
        for j in range(n):
            Qd[i, j] = 0.5 * dt * (Qd[i, j] + Qc[i, j])


@njit(cache=True, error_model="numpy")
def predict(x, P, Phi, Qd):
    """x <- Phi x ; P <- Phi P Phi^T + Qd, symmetrized (Eq. 1-2); in place. The product is taken
    of P's symmetric part (`_symmetric_sandwich_into`: Phi's zeros skipped)."""
    n = x.shape[0]
    x0 = x.copy()
    for i in range(n):
        s = 0.0
        for k in range(n):
            s += Phi[i, k] * x0[k]
        x[i] = s
    Ps = P.copy()
    symmetrize(Ps)
    _symmetric_sandwich_into(Phi, Ps, P)
    for i in range(n):
        for j in range(n):
            P[i, j] += Qd[i, j]
    symmetrize(P)


@njit(cache=True, error_model="numpy")
def predict_trapezoid(x, P, Phi, Qc, dt, T, Tt):
    """`predict` with `discretize`'s trapezoidal Qd = (Phi Qc Phi^T + Qc) dt / 2, regrouped as
    P <- Phi (P + Qc dt / 2) Phi^T + Qc dt / 2 (the same equations; one product with Phi instead of
    two), and x <- Phi x; in place, without allocating: T, Tt (n, n) are scratch. P and Qc exactly
    symmetric; P comes out exactly symmetric (the upper triangle of the product, mirrored)."""
    n = x.shape[0]
    zero = True  # a closed-loop filter predicts x = 0: Phi 0 is +0.0 in every element (the sums start at +0.0)
    for i in range(n):
        T[0, i] = x[i]
        if x[i] != 0.0:
            zero = False
    for i in range(n):
        if zero:
            x[i] = 0.0
            continue
        s = 0.0
        for k in range(n):
            s += Phi[i, k] * T[0, k]
        x[i] = s
    h = 0.5 * dt
    for i in range(n):
        for j in range(n):
            P[i, j] += h * Qc[i, j]
    matmul_into(Phi, P, T)
    for i in range(n):
        for k in range(n):
            Tt[k, i] = T[i, k]
    matmul_into(Phi, Tt, P)
    for i in range(n):
        for j in range(i + 1, n):
            v = P[i, j] + h * Qc[i, j]
            P[i, j] = v
            P[j, i] = v
        P[i, i] += h * Qc[i, i]


@njit(cache=True, error_model="numpy")
def innovation_into(x, P, z, H, R, nu, HP, S):
    """nu = z - H x (m,), H P (m, n) (= (P H^T)^T: P symmetric), S = H P H^T + R symmetrized
    (m, m), written into nu, HP, S. Zero elements of H are skipped (a measurement row touches a
    few states)."""
    m, n = H.shape
    for i in range(m):
        s = z[i]
        for k in range(n):
            if H[i, k] != 0.0:
                s -= H[i, k] * x[k]
        nu[i] = s
    matmul_into(H, P, HP)
    for i in range(m):
        for j in range(m):
            s = R[i, j]
            for k in range(n):
                if H[i, k] != 0.0:
                    s += H[i, k] * HP[j, k]
            S[i, j] = s
    symmetrize(S)


@njit(cache=True, error_model="numpy")
def nis_into(nu, S, L, w):
    """nu^T S^-1 nu, as the squared norm of the whitened innovation w = L^-1 nu (S = L L^T; L and
    w (m,) written); -1 if S is not positive definite."""
    m = nu.shape[0]
    if not cholesky_into(S, L):
        return -1.0
    forward_substitute(L, nu, w)
    nis = 0.0
    for i in range(m):
        nis += w[i] * w[i]
    return nis


@njit(cache=True, error_model="numpy")
def _scalar_statistics(x, P, z, H, R):
    """(nu, h^T P h, S = h^T P h + R) of a scalar measurement (H (1, n)) without allocating;
    the sums run in the order of `innovation_into`'s, skipping zeros of h."""
    n = H.shape[1]
    nu = z[0]
    hph = 0.0
    S = R[0, 0]
    for k in range(n):
        hk = H[0, k]
        if hk != 0.0:
            nu -= hk * x[k]
            pk = 0.0  # (P h)_k
            for j in range(n):
                if H[0, j] != 0.0:
                    pk += H[0, j] * P[k, j]
            hph += hk * pk
            S += hk * pk
    return nu, hph, S


@njit(cache=True, error_model="numpy")
def _update_scalar_into(x, P, z, h, r, p, g, held):
    """One scalar measurement z = h^T x + noise of variance r (h (n,)), in place, in O(n^2):
    p = P h, s = h^T p + r, k = p / s, x <- x + k nu, and the Joseph form
    (I - k h^T) P (I - k h^T)^T + k r k^T expanded exactly (for any gain k) as
    P - k p^T - p k^T + s k k^T. Returns nu^2 / s, or -1 (nothing changed) if s <= 0.
    p, g (n,) are its scratch (P h and the gain); held >= 0: that state's gain is zero (it is not
    corrected; the expanded Joseph form holds for that gain too)."""
    n = h.shape[0]
    for i in range(n):
        p[i] = 0.0
    nu = z
    for k in range(n):
        hk = h[k]
        if hk != 0.0:
            nu -= hk * x[k]
            for i in range(n):
                p[i] += hk * P[k, i]  # P symmetric: row k of P is its column k
    s = r
    for k in range(n):
        if h[k] != 0.0:
            s += h[k] * p[k]
    if not s > 0.0:
        return -1.0
    sq = np.sqrt(s)
    w = nu / sq
    for i in range(n):  # g: the gain k, as a Cholesky solve with S = s computes it
        g[i] = (p[i] / sq) / sq if i != held else 0.0
        x[i] += g[i] * nu
    for i in range(n):
        for j in range(i, n):
            v = P[i, j] - g[i] * p[j] - p[i] * g[j] + s * g[i] * g[j]
            P[i, j] = v
            P[j, i] = v
    return w * w


@njit(cache=True, error_model="numpy")
def update(x, P, z, H, R):
    """Joseph-form update (Eq. 3-5) in place; returns NIS = nu^T S^-1 nu, or -1 (x and P
    unchanged) if S is not PD. See `update_holding`."""
    return update_holding(x, P, z, H, R, -1)


@njit(cache=True, error_model="numpy")
def update_holding(x, P, z, H, R, held):
    """Joseph-form update (Eq. 3-5) in place whose gain is zero for state `held` (-1: none, the
    optimal gain); returns NIS = nu^T S^-1 nu, or -1 (x and P unchanged) if S is not PD.

    z (m,), H (m, n), R (m, m) symmetric PSD, P symmetric. The innovation is nu = z - H x,
    S = H P H^T + R. Joseph form (I - K H) P (I - K H)^T + K R K^T keeps P symmetric PD even for
    a gated or suboptimal gain. The rows are processed one at a time (`_update_scalar_into`, O(n^2)
    each instead of the O(n^3) products with I - K H), after decorrelating them by R = L D L^T
    (L unit lower-triangular, D diagonal: z' = L^-1 z, H' = L^-1 H, R' = D; a diagonal R is
    left as it is): rows with independent noise give, one after the other, the joint update's
    x, P and NIS (the sum of the rows' nu'^2 / s'). With a held state each row's gain has that
    entry zeroed: P is the Joseph form's for the gain used (the held state's variance unchanged).
    """
    m, n = H.shape
    if m == 1:
        return _update_scalar_into(x, P, z[0], H[0], R[0, 0], np.empty(n), np.empty(n), held)
    # one allocation for the scratch (L, D, zd, Hd, the state before, the rows' p and g): the NHC
    # rows (m = 2) come at every fifth of a second of a drive
    buf = np.empty(m * m + 2 * m + m * n + n + n * n + 2 * n)
    o = 0
    L = buf[o:o + m * m].reshape((m, m))
    o += m * m
    D = buf[o:o + m]
    o += m
    zd = buf[o:o + m]
    o += m
    Hd = buf[o:o + m * n].reshape((m, n))
    o += m * n
    x0 = buf[o:o + n]
    o += n
    P0 = buf[o:o + n * n].reshape((n, n))
    o += n * n
    p = buf[o:o + n]
    g = buf[o + n:o + 2 * n]
    for i in range(m):
        for j in range(m):
            L[i, j] = 0.0
    for j in range(m):  # R = L D L^T; a zero pivot (PSD R) leaves its column of L at zero
        d = R[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k] * D[k]
        D[j] = d
        L[j, j] = 1.0
        for i in range(j + 1, m):
            v = R[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k] * D[k]
            L[i, j] = v / d if d > 0.0 else 0.0
    for i in range(m):  # unit lower-triangular forward substitution
        s = z[i]
        for j in range(i):
            s -= L[i, j] * zd[j]
        zd[i] = s
        for k in range(n):
            s = H[i, k]
            for j in range(i):
                s -= L[i, j] * Hd[j, k]
            Hd[i, k] = s
    for k in range(n):
        x0[k] = x[k]
        for j in range(n):
            P0[k, j] = P[k, j]
    nis = 0.0
    for i in range(m):
        v = _update_scalar_into(x, P, zd[i], Hd[i], D[i], p, g, held)
        if v < 0.0:  # S not PD: leave the state as it was
            for k in range(n):
                x[k] = x0[k]
                for j in range(n):
                    P[k, j] = P0[k, j]
            return -1.0
        nis += v
    return nis


@njit(cache=True, error_model="numpy")
def innovation_statistics(x, P, z, H, R, pvar):
    """A candidate update's statistics, without applying it, from one S = H P H^T + R and its
    Cholesky factor: returns (NIS nu^T S^-1 nu, log det S) and writes pvar[:m] = diag(H P H^T)
    (the predicted variance of each residual component, for covariance matching). NIS -1 and
    log det NaN if S is not PD (`update` then reports it). P symmetric."""
    m, n = H.shape
    if m == 1:
        nu, hph, s = _scalar_statistics(x, P, z, H, R)
        pvar[0] = hph
        if not s > 0.0:
            return -1.0, np.nan
        sq = np.sqrt(s)
        w = nu / sq
        return w * w, 2.0 * np.log(sq)
    buf = np.empty(m + m * n + 2 * m * m + m)  # nu, HP, S, L, w: one allocation
    nu = buf[:m]
    HP = buf[m:m + m * n].reshape((m, n))
    S = buf[m + m * n:m + m * n + m * m].reshape((m, m))
    L = buf[m + m * n + m * m:m + m * n + 2 * m * m].reshape((m, m))
    innovation_into(x, P, z, H, R, nu, HP, S)
    for i in range(m):
        s = 0.0
        for k in range(n):
            if H[i, k] != 0.0:
                s += H[i, k] * HP[i, k]
        pvar[i] = s
    nis = nis_into(nu, S, L, buf[m + m * n + 2 * m * m:])
    if nis < 0.0:
        return nis, np.nan
    logdet = 0.0
    for i in range(m):
        logdet += 2.0 * np.log(L[i, i])
    return nis, logdet


@njit(cache=True, error_model="numpy")
def nis_of(x, P, z, H, R):
    """Normalized innovation squared nu^T S^-1 nu of a candidate update, without applying it;
    -1 if S is not PD (`update` then reports it)."""
    return innovation_statistics(x, P, z, H, R, np.empty(H.shape[0]))[0]
