"""Compiled loops of the ranging chain, over float64/int64 arrays; the documented wrappers are
`multilateration.ls_fix`, `multilateration.group_epochs`, `filter.fix_events` and `fuzzy.infer`.

- `gauss_newton_fix`: weighted Gauss-Newton position fix from ranges (paper 002 Eq. 7-8);
- `fix_epochs`: one fix per range epoch with the redundant-range chi-square cleaning and the
  fix's sensitivity to the floor-height and per-anchor calibration errors;
- `epoch_numbers`: epochs of time-sorted ranges;
- `mamdani_centroid`: the exact centroid of a SISO Mamdani system's aggregated output.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# fix status
FIX_OK = 0
FIX_FAILED = 1  # too few ranges, a range of zero, a singular normal matrix or no convergence
FIX_POOR_GEOMETRY = 2  # converged, but sqrt(trace(cov)) / sigma above max_pdop


@njit(cache=True)
def _solve_small(A, b, x):
    """x = A^-1 b for a small square A by Gaussian elimination with partial pivoting (A, b
    overwritten). False when a pivot is exactly zero (singular, as LAPACK's gesv reports)."""
    n = A.shape[0]
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if A[p, c] == 0.0:
            return False
        if p != c:
            for j in range(n):
                A[c, j], A[p, j] = A[p, j], A[c, j]
            b[c], b[p] = b[p], b[c]
        for r in range(c + 1, n):
            f = A[r, c] / A[c, c]
            for j in range(c, n):
                A[r, j] -= f * A[c, j]
            b[r] -= f * b[c]
    for c in range(n - 1, -1, -1):
        s = b[c]
        for j in range(c + 1, n):
            s -= A[c, j] * x[j]
        x[c] = s / A[c, c]
    return True


@njit(cache=True)
def _normal_matrix(anchors_ned_m, range_m, w, k, p, nd, N, g, h):
    """N = H^T W H and g = H^T W (r - rho) at position p over the first k ranges; H rows
    d rho / d (n, e[, d]) (Eq. 23), h (3,) scratch. False when the position coincides with an anchor."""
    for a in range(nd):
        g[a] = 0.0
        for b in range(nd):
            N[a, b] = 0.0
    for i in range(k):
        d0 = p[0] - anchors_ned_m[i, 0]
        d1 = p[1] - anchors_ned_m[i, 1]
        d2 = p[2] - anchors_ned_m[i, 2]
        rho = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if rho < 1e-9:
            return False
        h[0] = d0 / rho
        h[1] = d1 / rho
        h[2] = d2 / rho
        nu = range_m[i] - rho
        for a in range(nd):
            g[a] += h[a] * w[i] * nu
            for b in range(nd):
                N[a, b] += h[a] * w[i] * h[b]
    return True


@njit(cache=True)
def gauss_newton_fix(anchors_ned_m, range_m, sigma_m, k, p, nd, max_iter, tol_m, max_pdop, cov, vec, mat):
    """Weighted Gauss-Newton fix from the first k rows of anchors_ned_m (., 3), range_m and
    sigma_m of the first `nd` (2: north, east; 3: also down) coordinates of p (3,), updated in
    place; the others stay. cov (nd, nd) <- (H^T W H)^-1 at the solution. Scratch: vec
    (6, >= max(k, 3)), mat (2, nd, nd) (a loop over many fixes, `fix_epochs`, allocates them once).

    Returns (status, rms residual m): FIX_OK, FIX_FAILED (fewer than nd + 1 ranges, a range of
    zero length, singular normal matrix, no step below tol_m within max_iter) or
    FIX_POOR_GEOMETRY (sqrt(trace(cov[:2, :2])) / RMS sigma above max_pdop).
    """
    if k < nd + 1:
        return FIX_FAILED, np.nan
    w, g, dx, e, col, h = vec[0], vec[1], vec[2], vec[3], vec[4], vec[5]
    N, A = mat[0], mat[1]
    for i in range(k):
        w[i] = 1.0 / (sigma_m[i] * sigma_m[i])
    converged = False
    for _ in range(max_iter):
        if not _normal_matrix(anchors_ned_m, range_m, w, k, p, nd, N, g, h):
            return FIX_FAILED, np.nan
        if not _solve_small(N, g, dx):
            return FIX_FAILED, np.nan
        step2 = 0.0
        for a in range(nd):
            p[a] += dx[a]
            step2 += dx[a] * dx[a]
        if np.sqrt(step2) < tol_m:
            converged = True
            break
    if not converged:
        return FIX_FAILED, np.nan
    if not _normal_matrix(anchors_ned_m, range_m, w, k, p, nd, N, g, h):
        return FIX_FAILED, np.nan
    for j in range(nd):  # the inverse column by column
        for a in range(nd):
            e[a] = 1.0 if a == j else 0.0
            for b in range(nd):
                A[a, b] = N[a, b]
        if not _solve_small(A, e, col):
            return FIX_FAILED, np.nan
        for a in range(nd):
            cov[a, j] = col[a]
    ss = 0.0
    s2 = 0.0
    for i in range(k):
        d0 = p[0] - anchors_ned_m[i, 0]
        d1 = p[1] - anchors_ned_m[i, 1]
        d2 = p[2] - anchors_ned_m[i, 2]
        res = range_m[i] - np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        ss += res * res
        s2 += sigma_m[i] * sigma_m[i]
    pdop = np.sqrt(cov[0, 0] + cov[1, 1]) / np.sqrt(s2 / k)
    return (FIX_OK if pdop <= max_pdop else FIX_POOR_GEOMETRY), np.sqrt(ss / k)


@njit(cache=True)
def epoch_numbers(t_s, window_s):
    """Epoch of each time-sorted range: a new epoch starts more than window_s after the first
    range of the current one."""
    out = np.empty(t_s.shape[0], np.int64)
    e = -1
    start = -np.inf
    for i in range(t_s.shape[0]):
        if t_s[i] - start > window_s:
            e += 1
            start = t_s[i]
        out[i] = e
    return out


@njit(cache=True)
def _subset_fix(idx, k, skip, anchor, range_m, sd_m, anchors_ned_m, guess, max_iter, tol_m, max_pdop,
                a_sub, r_sub, s_sub, p, cov, vec, mat):
    """Fix from the ranges idx[:k] except position `skip` (-1: all); fills the first rows of a_sub,
    r_sub, s_sub with the ranges used, p and cov. Returns (status, weighted residual sum of
    squares, n used)."""
    m = 0
    for j in range(k):
        if j != skip:
            for c in range(3):
                a_sub[m, c] = anchors_ned_m[anchor[idx[j]], c]
            r_sub[m] = range_m[idx[j]]
            s_sub[m] = sd_m[idx[j]]
            m += 1
    for c in range(3):
        p[c] = guess[c]
    status, _ = gauss_newton_fix(a_sub, r_sub, s_sub, m, p, 2, max_iter, tol_m, max_pdop, cov, vec, mat)
    chi = 0.0
    for j in range(m):
        d0 = p[0] - a_sub[j, 0]
        d1 = p[1] - a_sub[j, 1]
        d2 = p[2] - a_sub[j, 2]
        res = (r_sub[j] - np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)) / s_sub[j]
        chi += res * res
    return status, chi, m


@njit(cache=True)
def fix_epochs(t_s, anchor, range_m, sd_m, anchors_ned_m, bounds, guess_ned_m, min_anchors, chi2_by_dof,
               max_iter, tol_m, max_pdop, o_t, o_z, o_R, o_sens):
    """Horizontal fixes of the epochs rows bounds[e]:bounds[e+1] (see `filter.fix_events`).

    Per epoch: the last range of each anchor (anchors in index order); fewer than min_anchors:
    no fix. Gauss-Newton from the previous fix (the first from guess_ned_m). While the weighted
    residuals' sum of squares of the k ranges exceeds chi2_by_dof[k - 2], the range whose
    omission leaves the smallest sum is dropped (leave-one-out: the largest residual is often
    another range's, pulled by the outlier), down to 3 ranges (2 unknowns and one redundancy;
    min_anchors only decides which epochs get a fix); a 3-range fix that still fails is not used
    (an NLOS range left in would bend it beyond its covariance). Writes fix i's time (latest
    range used), NE position, NE covariance and sensitivity (2, 1 + A) = [K h_d, K per anchor],
    K = cov H^T W; returns the number of fixes.
    """
    n_anchor = anchors_ned_m.shape[0]
    guess = np.empty(3)
    for c in range(3):
        guess[c] = guess_ned_m[c]
    last = np.empty(n_anchor, np.int64)
    idx = np.empty(n_anchor, np.int64)
    a_sub = np.empty((n_anchor, 3))
    r_sub = np.empty(n_anchor)
    s_sub = np.empty(n_anchor)
    cov = np.empty((2, 2))
    p = np.empty(3)
    vec, mat = np.empty((6, max(n_anchor, 3))), np.empty((2, 2, 2))  # gauss_newton_fix's scratch, once
    n_fix = 0
    for e in range(bounds.shape[0] - 1):
        for a in range(n_anchor):
            last[a] = -1
        for i in range(bounds[e], bounds[e + 1]):  # one range per anchor: the last if it answered twice
            last[anchor[i]] = i
        k = 0
        for a in range(n_anchor):
            if last[a] >= 0:
                idx[k] = last[a]
                k += 1
        if k < min_anchors:
            continue
        while True:
            status, chi, _ = _subset_fix(idx, k, -1, anchor, range_m, sd_m, anchors_ned_m, guess, max_iter, tol_m,
                                         max_pdop, a_sub, r_sub, s_sub, p, cov, vec, mat)
            if status != FIX_OK or chi <= chi2_by_dof[k - 2]:
                break
            if k == 3:  # no range left to spare
                status = FIX_FAILED
                break
            best, best_chi = -1, np.inf  # beyond the paper: the NLOS range is the one whose omission fits best
            for j in range(k):
                st_j, chi_j, _ = _subset_fix(idx, k, j, anchor, range_m, sd_m, anchors_ned_m, guess, max_iter, tol_m,
                                             max_pdop, a_sub, r_sub, s_sub, p, cov, vec, mat)
                if st_j == FIX_OK and chi_j < best_chi:
                    best, best_chi = j, chi_j
            if best < 0:
                status = FIX_FAILED
                break
            for j in range(best, k - 1):
                idx[j] = idx[j + 1]
            k -= 1
        if status != FIX_OK:
            continue
        for c in range(3):
            guess[c] = p[c]
        t_max = -np.inf
        for j in range(k):
            t_max = max(t_max, t_s[idx[j]])
        o_t[n_fix] = t_max
        o_z[n_fix, 0] = p[0]
        o_z[n_fix, 1] = p[1]
        o_R[n_fix, 0, 0] = cov[0, 0]
        o_R[n_fix, 0, 1] = cov[0, 1]
        o_R[n_fix, 1, 0] = cov[0, 1]  # exactly symmetric
        o_R[n_fix, 1, 1] = cov[1, 1]
        for r in range(2):
            for c in range(1 + n_anchor):
                o_sens[n_fix, r, c] = 0.0
        for j in range(k):
            d0 = p[0] - a_sub[j, 0]
            d1 = p[1] - a_sub[j, 1]
            d2 = p[2] - a_sub[j, 2]
            rho = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            w = 1.0 / s_sub[j] ** 2
            for r in range(2):
                kr = (cov[r, 0] * d0 / rho + cov[r, 1] * d1 / rho) * w
                o_sens[n_fix, r, 0] += kr * d2 / rho
                o_sens[n_fix, r, 1 + anchor[idx[j]]] += kr
        n_fix += 1
    return n_fix


@njit(cache=True)
def _tri(x, a, b, c):
    """Triangle membership (`fuzzy.triangle`) at one point."""
    if x < a or x > c:
        return 0.0
    left = (x - a) / (b - a) if (x < b and b > a) else 1.0
    right = (c - x) / (c - b) if (x > b and c > b) else 1.0
    return min(max(min(left, right), 0.0), 1.0)


@njit(cache=True)
def _aggregated(y, w, out_tri, rule_out):
    """max over rules of min(firing strength, output membership) at y."""
    g = 0.0
    for r in range(w.shape[0]):
        if w[r] > 0.0:
            o = rule_out[r]
            g = max(g, min(w[r], _tri(y, out_tri[o, 0], out_tri[o, 1], out_tri[o, 2])))
    return g


@njit(cache=True)
def _side(out_tri, o, j):
    """Side j (0 rising, 1 falling) of output triangle o as y(mu) = y0 + (y1 - y0) mu, mu in [0, 1]."""
    if j == 0:
        return out_tri[o, 0], out_tri[o, 1]
    return out_tri[o, 2], out_tri[o, 1]


@njit(cache=True)
def mamdani_centroid(x, in_lo, in_hi, in_tri, out_tri, rule_in, rule_out, out_lo, out_hi, mid, s_out):
    """s_out[i] = centroid over [out_lo, out_hi] of max_r min(mu_in_r(x_i), mu_out_r(y)) (x clamped
    to [in_lo, in_hi]); `mid` where no rule fires.

    The aggregated membership is piecewise linear in y, linear between the sorted breakpoints of
    the firing rules' output sets (their corners, the levels where a side meets a firing
    strength, the crossings of two sides) and the universe's ends; its area and first moment
    are integrated exactly piece by piece, each piece's line taken from two interior points
    (which also handles the steps of shoulder sets).
    """
    n_rules = rule_in.shape[0]
    w = np.empty(n_rules)
    fired = np.empty(n_rules, np.int64)
    pts = np.empty(2 + 3 * n_rules + 4 * n_rules * n_rules + 2 * n_rules * n_rules)
    for i in range(x.shape[0]):
        xi = min(max(x[i], in_lo), in_hi)
        nf = 0
        for r in range(n_rules):
            t = rule_in[r]
            w[r] = _tri(xi, in_tri[t, 0], in_tri[t, 1], in_tri[t, 2])
            if w[r] > 0.0:
                fired[nf] = r
                nf += 1
        if nf == 0:
            s_out[i] = mid
            continue
        pts[0] = out_lo
        pts[1] = out_hi
        m = 2
        for f in range(nf):
            o = rule_out[fired[f]]
            for j in range(3):
                pts[m] = out_tri[o, j]
                m += 1
            for g in range(nf):  # where a side of this set meets a firing strength
                wg = w[fired[g]]
                if wg < 1.0:
                    for j in range(2):
                        y0, y1 = _side(out_tri, o, j)
                        pts[m] = y0 + (y1 - y0) * wg
                        m += 1
            for g in range(f + 1, nf):  # crossings with the sides of another set
                o2 = rule_out[fired[g]]
                for j in range(2):
                    a0, a1 = _side(out_tri, o, j)
                    for j2 in range(2):
                        b0, b1 = _side(out_tri, o2, j2)
                        d = (a1 - a0) - (b1 - b0)
                        if d != 0.0:
                            mu = (b0 - a0) / d
                            if 0.0 <= mu <= 1.0:
                                pts[m] = a0 + (a1 - a0) * mu
                                m += 1
        for j in range(1, m):  # insertion sort of the few breakpoints
            v = pts[j]
            i2 = j - 1
            while i2 >= 0 and pts[i2] > v:
                pts[i2 + 1] = pts[i2]
                i2 -= 1
            pts[i2 + 1] = v
        q = pts
        area = 0.0
        moment = 0.0
        for j in range(m - 1):
            y0 = max(q[j], out_lo)
            y1 = min(q[j + 1], out_hi)
            if y1 <= y0:
                continue
            inside = False  # outside the fired output sets' supports the membership is 0: skip
            for f in range(nf):  # the piece without evaluating it (it would add nothing)
                o = rule_out[fired[f]]
                if y1 > out_tri[o, 0] and y0 < out_tri[o, 2]:
                    inside = True
            if not inside:
                continue
            h = y1 - y0
            g1 = _aggregated(y0 + 0.25 * h, w, out_tri, rule_out)
            g3 = _aggregated(y0 + 0.75 * h, w, out_tri, rule_out)
            if g1 == 0.0 and g3 == 0.0:
                continue
            beta = (g3 - g1) / (0.5 * h)
            alpha = g1 - beta * (y0 + 0.25 * h)
            area += alpha * h + beta * (y1 * y1 - y0 * y0) / 2.0
            moment += alpha * (y1 * y1 - y0 * y0) / 2.0 + beta * (y1**3 - y0**3) / 3.0
        s_out[i] = moment / area if area > 0.0 else mid
