"""Range error model and its least-squares correction (paper 002, Eq. 13-16).

A measured range is `d~_i = f_i d_i + c_i + e_NLOS + Delta_i` (Eq. 13-14); `f_i`, `c_i` minimise
the sum of squared deviations S(f, c) (Eq. 15), whose normal equations dS/df = dS/dc = 0 (Eq. 16)
are the ordinary linear regression of measured on true distance. Corrected ranges are
`(d~ - c_i) / f_i`. Eq. 13 writes one scale `f`; `scale="shared"` fits that (one f, one c_i per
anchor, a joint LS), `scale="per_anchor"` a separate line per anchor.

Beyond the paper: the fit is repeated once without the points whose residual exceeds
`reject_sigma` robust SDs (NLOS spikes in the calibration table would bias the line), and the
distance-dependent range SD (paper Fig. 6, the FIS input of Eq. 31) is fitted as a polynomial of
true distance to the binned residual variances (maximum likelihood).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import InvalidInputError

_MIN_POINTS_PER_ANCHOR = 3  # a line needs 2 points; 3 leaves one degree of freedom for the SD
_MIN_BIN_SIZE = 8  # residuals per SD bin when true distances do not repeat


@dataclass(frozen=True)
class RangeModel:
    """Per-anchor range error model (index = anchor index of `Session.anchors`).

    scale, bias_m, residual_sd_m, n_used, n_rejected : shape (A,)
    sd_poly : polynomial coefficients (numpy.polyval order) of the range SD (m) vs distance (m),
        pooled over anchors; sd_range_m : (min, max) distance where it was fitted (clamped outside)
    pooled_sd_m : SD of all calibration residuals (the constant-R baseline of the `tc` solution)
    fitted : False for the identity model used without a calibration table
    bias_cov_m2 : (A, A) covariance of the error of the corrected ranges that the fit leaves,
        (dc_i + d dF_i) / f_i at d = anchor i's mean calibration distance (where the line is best
        known), from the heteroscedasticity-robust (sandwich) covariance of the LS coefficients;
        constant over a run, so the filters carry it as per-anchor bias states. Zeros: unknown.
    """

    scale: np.ndarray
    bias_m: np.ndarray
    residual_sd_m: np.ndarray
    n_used: np.ndarray
    n_rejected: np.ndarray
    sd_poly: np.ndarray
    sd_range_m: tuple[float, float]
    pooled_sd_m: float
    fitted: bool
    bias_cov_m2: np.ndarray | None = None

    def correct(self, anchor: np.ndarray, range_m: np.ndarray) -> np.ndarray:
        """Invert Eq. 14 without noise: d = (d~ - c_i) / f_i."""
        a = np.asarray(anchor, dtype=np.int64)
        return (np.asarray(range_m, dtype=float) - self.bias_m[a]) / self.scale[a]

    def range_sd_m(self, distance_m: np.ndarray) -> np.ndarray:
        """Fitted range SD (m) at a distance (paper Fig. 6): the polynomial inside the calibrated
        span, its tangent line beyond it (the SD keeps growing with distance: a clamp at the
        span's end understated the ranges beyond it, 27 % at 25 m for a span to 18.6 m)."""
        d = np.asarray(distance_m, dtype=float)
        lo, hi = self.sd_range_m
        dc = np.clip(d, lo, hi)
        sd = np.polyval(self.sd_poly, dc)
        if np.isfinite(lo) and np.isfinite(hi) and self.sd_poly.size > 1:
            slope = np.polyval(np.polyder(self.sd_poly), dc)  # at the nearer end of the span
            sd = sd + slope * (d - dc)
        return np.maximum(sd, 1e-3 * self.pooled_sd_m)

    def summary(self, anchor_ids: tuple[str, ...]) -> dict:
        """Plain-dict view for summary.json."""
        return {
            "fitted": self.fitted,
            "pooled_residual_sd_m": float(self.pooled_sd_m),
            "sd_poly_m": [float(c) for c in self.sd_poly],
            "sd_range_m": [float(v) for v in self.sd_range_m],
            "anchors": {
                aid: {
                    "f": float(self.scale[i]),
                    "c_m": float(self.bias_m[i]),
                    "residual_sd_m": float(self.residual_sd_m[i]),
                    "n_used": int(self.n_used[i]),
                    "n_rejected": int(self.n_rejected[i]),
                    "bias_se_m": float(np.sqrt(self.bias_cov_m2[i, i])) if self.bias_cov_m2 is not None else None,
                }
                for i, aid in enumerate(anchor_ids)
            },
        }


def identity_model(n_anchors: int, sd_m: float) -> RangeModel:
    """No correction (f = 1, c = 0) and a constant range SD `sd_m`."""
    z = np.zeros(n_anchors)
    return RangeModel(
        scale=np.ones(n_anchors), bias_m=z.copy(), residual_sd_m=np.full(n_anchors, sd_m),
        n_used=np.zeros(n_anchors, np.int64), n_rejected=np.zeros(n_anchors, np.int64),
        sd_poly=np.array([sd_m]), sd_range_m=(0.0, np.inf), pooled_sd_m=float(sd_m), fitted=False,
        bias_cov_m2=np.zeros((n_anchors, n_anchors)),
    )


def _design(anchor: np.ndarray, true_m: np.ndarray, n_anchors: int, shared: bool) -> np.ndarray:
    """Columns [f (or f_i), c_1..c_A] of the linear model d~ = f_i d + c_i (Eq. 14)."""
    n = true_m.size
    bias_cols = np.zeros((n, n_anchors))
    bias_cols[np.arange(n), anchor] = 1.0
    if shared:
        return np.column_stack([true_m, bias_cols])
    scale_cols = bias_cols * true_m[:, None]
    return np.column_stack([scale_cols, bias_cols])


def _robust_sd(r: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r))))  # MAD -> SD for a Gaussian


def fit_range_model(
    anchor: np.ndarray,
    true_m: np.ndarray,
    measured_m: np.ndarray,
    n_anchors: int,
    *,
    scale: str = "per_anchor",
    reject_sigma: float = 4.0,
    sd_poly_degree: int = 1,
) -> RangeModel:
    """Fit f, c_i by least squares (Eq. 15-16) and the range SD vs distance.

    Parameters
    ----------
    anchor : int, shape (C,) - anchor index of each calibration pair
    true_m, measured_m : float, shape (C,) - known and measured distances, m
    n_anchors : number of anchors A; anchors without enough pairs raise InvalidInputError
    scale : "per_anchor" (f_i, c_i) or "shared" (one f as Eq. 13, c_i per anchor)
    reject_sigma : residuals beyond this many robust SDs are dropped and the fit repeated once
        (0 disables); sd_poly_degree : degree of the SD(distance) polynomial
    """
    anchor = np.asarray(anchor, dtype=np.int64)
    true_m = np.asarray(true_m, dtype=float)
    measured_m = np.asarray(measured_m, dtype=float)
    if scale not in ("per_anchor", "shared"):
        raise InvalidInputError(f"range model: scale must be 'per_anchor' or 'shared', got {scale!r}")
    counts = np.bincount(anchor, minlength=n_anchors)
    for i in range(n_anchors):
        if counts[i] < _MIN_POINTS_PER_ANCHOR:
            raise InvalidInputError(
                f"range_calibration: anchor index {i} has {counts[i]} pairs, "
                f"at least {_MIN_POINTS_PER_ANCHOR} are needed for the scale/bias fit"
            )
    shared = scale == "shared"
    A = _design(anchor, true_m, n_anchors, shared)
    keep = np.ones(true_m.size, dtype=bool)
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(A[keep], measured_m[keep], rcond=None)  # Eq. 16 normal equations
        resid = measured_m - A @ coef
        if reject_sigma <= 0:
            break
        # against the robust SD at each point's distance: the noise grows with distance, and one
        # SD per anchor (the median distance's) cut ~3 % of the far, noisy but sound readings,
        # which biased the SD curve's slope low by 4-10 %
        sd = _robust_sd_at(true_m[keep], resid[keep], true_m, sd_poly_degree)
        new_keep = np.abs(resid) <= reject_sigma * np.maximum(sd, 1e-12)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    scale_f = np.full(n_anchors, coef[0]) if shared else coef[:n_anchors].copy()
    bias = coef[-n_anchors:].copy()
    n_par = (1 + n_anchors) if shared else 2 * n_anchors
    resid_sd = np.empty(n_anchors)
    n_used = np.empty(n_anchors, np.int64)
    for i in range(n_anchors):
        m = keep & (anchor == i)
        n_used[i] = m.sum()
        dof = max(n_used[i] - (n_par / n_anchors), 1.0)
        resid_sd[i] = np.sqrt(np.sum(resid[m] ** 2) / dof)
    pooled = float(np.sqrt(np.sum(resid[keep] ** 2) / max(keep.sum() - n_par, 1)))
    # Sandwich covariance (White 1980): the range noise grows with distance, so the OLS formula
    # sigma^2 (A^T A)^-1 would misstate the SEs
    Ak = A[keep]
    bread = np.linalg.inv(Ak.T @ Ak)
    cov = bread @ (Ak.T * resid[keep] ** 2) @ Ak @ bread
    J = np.zeros((n_anchors, coef.size))  # corrected-range error of anchor i at its mean distance
    for i in range(n_anchors):
        d_ref = float(np.mean(true_m[keep & (anchor == i)]))
        J[i, 0 if shared else i] = d_ref / scale_f[i]
        J[i, (1 if shared else n_anchors) + i] = 1.0 / scale_f[i]
    bias_cov = J @ cov @ J.T
    # Residuals in range units: the SD of the corrected range is SD(resid) / f.
    f_per = scale_f[anchor]
    poly, span = _fit_sd_curve(true_m[keep], resid[keep] / f_per[keep], sd_poly_degree)
    return RangeModel(
        scale=scale_f, bias_m=bias, residual_sd_m=resid_sd / scale_f, n_used=n_used,
        n_rejected=counts - n_used, sd_poly=poly, sd_range_m=span,
        pooled_sd_m=pooled / float(np.mean(scale_f)), fitted=True, bias_cov_m2=0.5 * (bias_cov + bias_cov.T),
    )


def _bins(true_m: np.ndarray) -> list[np.ndarray]:
    """Index groups of the calibration points by distance: one per repeated known distance
    (paper 3.3), else quantile bins of a few points each; groups of fewer than 2 dropped."""
    uniq, inv = np.unique(np.round(true_m, 6), return_inverse=True)
    if uniq.size * 3 <= true_m.size:
        groups = [np.flatnonzero(inv == k) for k in range(uniq.size)]
    else:
        order = np.argsort(true_m)
        groups = np.array_split(order, max(true_m.size // _MIN_BIN_SIZE, 1))
    return [g for g in groups if g.size >= 2]


def _robust_sd_at(true_m: np.ndarray, resid_m: np.ndarray, at_m: np.ndarray, degree: int) -> np.ndarray:
    """Robust range SD at the distances at_m: MAD-SDs of the distance bins (NLOS spikes do not
    inflate them), a polynomial through them, clamped to the binned span; at least the smallest
    bin's SD."""
    groups = _bins(true_m)
    if len(groups) < 2:
        return np.full(np.shape(at_m), _robust_sd(resid_m))
    d = np.array([true_m[g].mean() for g in groups])
    sd = np.array([_robust_sd(resid_m[g]) for g in groups])
    deg = int(min(degree, len(groups) - 1))
    poly = np.polyfit(d, sd, deg, w=np.array([np.sqrt(g.size) for g in groups]))
    return np.maximum(np.polyval(poly, np.clip(at_m, d.min(), d.max())), max(sd.min(), 1e-12))


def _ml_sd_poly(d, var, dof, start, max_iter: int = 100) -> np.ndarray:
    """Coefficients c (highest power first) minimizing the bins' negative log-likelihood
    f(c) = sum_b dof_b / 2 (log p_b^2 + var_b / p_b^2), p_b = polyval(c, d_b), by Fisher scoring
    from `start`: with J = d p / d c, the score J^T g, g_b = dof_b (1 / p_b - var_b / p_b^3), and
    the expected information J^T W J, W_b = 2 dof_b / p_b^2 (positive: each step descends), the
    step halved until f decreases; to a step below 1e-13 relative. (scipy.optimize is not used:
    its import alone costs 0.2-0.3 s of every ranging run.)"""
    J = np.vander(d, len(start))

    def nll(c):
        p = J @ c
        return np.inf if np.any(p <= 0) else 0.5 * float(np.sum(dof * (np.log(p * p) + var / (p * p))))

    c = np.asarray(start, dtype=float)
    f = nll(c)
    if not np.isfinite(f):
        return c
    for _ in range(max_iter):
        p = J @ c
        g = dof * (1.0 / p - var / p**3)
        step = np.linalg.solve(J.T @ (J * (2.0 * dof / p**2)[:, None]), -(J.T @ g))
        a = 1.0
        while a > 1e-6:
            f_new = nll(c + a * step)
            if f_new <= f:
                break
            a *= 0.5
        else:
            break  # no decrease along the scoring direction: at the minimum to rounding
        c, f = c + a * step, f_new
        if np.max(np.abs(a * step)) <= 1e-13 * max(np.max(np.abs(c)), 1e-300):
            break
    return c


def _fit_sd_curve(true_m: np.ndarray, resid_m: np.ndarray, degree: int) -> tuple[np.ndarray, tuple[float, float]]:
    """Range SD vs distance (paper Fig. 6): a polynomial sd(d) fitted to the residual variances of
    distance bins by maximum likelihood.

    Bin b of n_b residuals has sample variance s_b^2 with (n_b - 1) s_b^2 / sd(d_b)^2 ~ chi2(n_b - 1),
    so the negative log-likelihood is sum_b (n_b - 1) / 2 (log sd(d_b)^2 + s_b^2 / sd(d_b)^2). A
    least-squares line through the bins' sample SDs, weighted by those same SDs, was biased low
    (bins whose SD came out small weighed more, and a sample SD underestimates: ~4 % in SD with 20
    readings per bin, which the filters' NIS showed as ~8 % excess).
    """
    groups = _bins(true_m)
    d = np.array([true_m[g].mean() for g in groups])
    var = np.array([resid_m[g].var(ddof=1) for g in groups])
    dof = np.array([g.size - 1.0 for g in groups])
    deg = int(min(degree, max(len(groups) - 1, 0)))
    if deg == 0:
        return np.array([float(np.sqrt(np.mean(resid_m**2)))]), (float(true_m.min()), float(true_m.max()))
    sd = np.sqrt(var)
    start = np.polyfit(d, sd, deg, w=np.sqrt(dof) / np.maximum(sd, 1e-9))
    poly = _ml_sd_poly(d, var, dof, start)
    poly = poly if np.all(np.polyval(poly, d) > 0) else start
    return poly, (float(d.min()), float(d.max()))
