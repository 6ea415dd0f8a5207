"""Error statistics of solutions against truth, and filter-health statistics: pure numpy.

Conventions of every statistic here (and of `accuracy.parquet`):

- `mean` and `sd` are of the *signed* error, `sd` the population SD (so RMS^2 = mean^2 + SD^2);
  `min`/`max` are the signed extremes (paper 002 Table 1 "error range"); `max_abs`, `p50`, `p90`,
  `p95` are of the error magnitude |e| (numpy linear percentiles). For norms (3-D, horizontal) the
  signed error is the magnitude, so `max_abs == max`.
- CEP and CE90 are the radii about the truth holding 50 % / 90 % of horizontal errors: empirically
  the p50/p90 of the horizontal error; predicted from a covariance by `cep_from_sigmas`.
- Position errors are solution minus truth, resolved in the local-level NED frame at the truth
  point; "vertical" is the up component (sign: solution above truth is positive).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from tpos_cli.frames.geodetic import ecef_to_ned_dcm, lla_to_ecef
from tpos_cli.frames.rotation import euler_to_dcm, wrap_angle_deg

STAT_FIELDS = ("n", "mean", "sd", "rms", "min", "max", "max_abs", "p50", "p90", "p95")


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of one error series (see module docstring for the definitions)."""

    n: int
    mean: float
    sd: float
    rms: float
    min: float
    max: float
    max_abs: float
    p50: float
    p90: float
    p95: float

    def as_dict(self) -> dict:
        return {f: getattr(self, f) for f in STAT_FIELDS}


def chi2_ppf(prob, dof):
    """Quantile of the chi-square distribution: 2 P^-1(dof/2, prob), P the regularised lower
    incomplete gamma function (chi2 with k dof is Gamma(k/2, scale 2)). Through scipy.special:
    scipy.stats would add a second to the start-up of every report."""
    return 2.0 * special.gammaincinv(np.asarray(dof, dtype=float) / 2.0, prob)


def error_stats(err) -> ErrorStats:
    """Statistics of a 1-D error series; NaN entries are ignored, an empty series gives NaNs."""
    e = np.asarray(err, dtype=float).ravel()
    e = e[np.isfinite(e)]
    if e.size == 0:
        nan = float("nan")
        return ErrorStats(0, nan, nan, nan, nan, nan, nan, nan, nan, nan)
    a = np.abs(e)
    p50, p90, p95 = np.percentile(a, [50.0, 90.0, 95.0])
    return ErrorStats(
        n=int(e.size),
        mean=float(e.mean()),
        sd=float(e.std()),  # population SD: RMS^2 = mean^2 + SD^2 exactly
        rms=float(np.sqrt(np.mean(e * e))),
        min=float(e.min()),
        max=float(e.max()),
        max_abs=float(a.max()),
        p50=float(p50),
        p90=float(p90),
        p95=float(p95),
    )


def position_errors_ned(sol_lla, truth_lla, truth_offset_ned_m=None, *, truth_r_e=None, truth_C_ne=None):
    """Solution-minus-truth position error, m, shape (N, 3), NED at each truth point.

    Exact (no flat-Earth approximation): the ECEF difference rotated by C_ne of the truth point.
    `truth_offset_ned_m` (N, 3) is added to the solution point first, e.g. `C_nb @ lever_arm` when the
    truth is a GPS antenna and the solution is the IMU point. Rows with NaN give NaN.
    `truth_r_e` and `truth_C_ne` (the truth's ECEF position and C_ne) may be passed when several
    solutions are compared with the same truth epochs.
    """
    sol = np.asarray(sol_lla, dtype=float).reshape(-1, 3)
    tru = np.asarray(truth_lla, dtype=float).reshape(-1, 3)
    r_t = lla_to_ecef(tru) if truth_r_e is None else truth_r_e
    C_ne = ecef_to_ned_dcm(tru[:, 0], tru[:, 1]) if truth_C_ne is None else truth_C_ne
    err = np.einsum("nij,nj->ni", C_ne, lla_to_ecef(sol) - r_t)
    if truth_offset_ned_m is not None:
        err = err + np.asarray(truth_offset_ned_m, dtype=float).reshape(-1, 3)
    return err


def split_position_errors(err_ned_m) -> dict[str, np.ndarray]:
    """Named error series from NED errors: 3-D, horizontal, vertical (up) and the components."""
    e = np.asarray(err_ned_m, dtype=float).reshape(-1, 3)
    return {
        "pos_3d_m": np.sqrt(np.sum(e * e, axis=1)),
        "pos_h_m": np.hypot(e[:, 0], e[:, 1]),
        "pos_v_m": -e[:, 2],
        "pos_n_m": e[:, 0],
        "pos_e_m": e[:, 1],
    }


def rotation_angle_deg(C) -> np.ndarray:
    """Angle of rotation matrices (..., 3, 3), deg: atan2(|vee(C - C^T)| / 2, (trace C - 1) / 2),
    accurate at small and large angles alike (arccos of the trace alone loses digits near 0)."""
    C = np.asarray(C, dtype=float)
    v = np.stack([C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0], C[..., 1, 0] - C[..., 0, 1]], axis=-1)
    return np.degrees(np.arctan2(0.5 * np.linalg.norm(v, axis=-1), 0.5 * (np.trace(C, axis1=-2, axis2=-1) - 1.0)))


def attitude_errors_deg(sol_rpy_deg, truth_rpy_deg, *, truth_C_nb=None) -> dict[str, np.ndarray]:
    """Wrap-aware Euler-angle errors (solution minus truth), deg in (-180, 180], and the total
    rotation angle of C_truth^T C_sol, deg (independent of the Euler convention near gimbal lock).
    `truth_C_nb` (N, 3, 3) may be passed when several solutions share the truth epochs."""
    s = np.asarray(sol_rpy_deg, dtype=float).reshape(-1, 3)
    t = np.asarray(truth_rpy_deg, dtype=float).reshape(-1, 3)
    d = wrap_angle_deg(s - t)
    total = np.full(s.shape[0], np.nan)
    ok = np.all(np.isfinite(s), axis=1) & np.all(np.isfinite(t), axis=1)
    if ok.any():
        Cs = euler_to_dcm(*np.radians(s[ok]).T)
        Ct = euler_to_dcm(*np.radians(t[ok]).T) if truth_C_nb is None else truth_C_nb[ok]
        total[ok] = rotation_angle_deg(np.einsum("nji,njk->nik", Ct, Cs))
    return {"roll_deg": d[:, 0], "pitch_deg": d[:, 1], "yaw_deg": d[:, 2], "att_deg": total}


def cep_from_sigmas(sigma_n_m, sigma_e_m, prob=0.5, rho=0.0) -> float:
    """Radius of the circle about the mean holding `prob` of a zero-mean 2-D Gaussian, m.

    P(R <= r) = 1/(2 pi s1 s2) int_0^{2pi} (1 - exp(-r^2 q/2)) / q dtheta with
    q = cos^2/s1^2 + sin^2/s2^2 (polar integral of the density; s1, s2 the principal SDs),
    evaluated with the periodic trapezoid rule (spectrally accurate) and solved for r.
    Circular case: sigma * sqrt(-2 ln(1 - prob)).
    """
    sn, se = float(sigma_n_m), float(sigma_e_m)
    if not (np.isfinite(sn) and np.isfinite(se)) or sn < 0 or se < 0:
        return float("nan")
    cov = np.array([[sn * sn, rho * sn * se], [rho * sn * se, se * se]])
    s1, s2 = np.sqrt(np.maximum(np.linalg.eigvalsh(cov), 0.0))
    s1, s2 = max(s1, s2), min(s1, s2)
    if s1 == 0.0:
        return 0.0
    if s2 <= 1e-9 * s1:
        # degenerate to 1-D: P(|x| <= r) = prob
        return float(s1 * special.ndtri(0.5 + prob / 2.0))
    th = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    q = np.cos(th) ** 2 / s1**2 + np.sin(th) ** 2 / s2**2

    def cdf(r):
        return float(np.mean((1.0 - np.exp(-0.5 * r * r * q)) / q) / (s1 * s2))

    hi = s1 * 10.0
    from scipy.optimize import (
        brentq,  # lazy: scipy.optimize costs a report's start-up 0.2 s
    )

    return float(brentq(lambda r: cdf(r) - prob, 0.0, hi, xtol=1e-12 * s1))


def ellipse_scale(prob: float = 0.95, dof: int = 2) -> float:
    """Mahalanobis radius of the `prob` confidence ellipse: sqrt(chi2.ppf(prob, dof))."""
    return float(np.sqrt(chi2_ppf(prob, dof)))


@dataclass(frozen=True)
class NisStats:
    """Consistency of one measurement kind: NIS against chi-square (Bar-Shalom's NIS test).

    `mean_nis` is over accepted updates; its two-sided 95 % band is chi2.ppf([.025, .975], sum dof)/n.
    `frac_above_95` is the share of all updates whose NIS exceeds chi2.ppf(0.95, dof) (expected 0.05).
    """

    n: int
    n_accepted: int
    n_rejected: int
    dof: float
    mean_nis: float
    mean_lo: float
    mean_hi: float
    frac_above_95: float
    consistent: bool

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def nis_stats(nis, dof, accepted) -> NisStats:
    """NIS consistency of one solution's updates of one kind."""
    nis = np.asarray(nis, dtype=float).ravel()
    dof = np.broadcast_to(np.asarray(dof, dtype=float), nis.shape)
    acc = np.broadcast_to(np.asarray(accepted, dtype=bool), nis.shape)
    ok = np.isfinite(nis) & np.isfinite(dof) & (dof > 0)
    n = int(ok.sum())
    a = ok & acc
    na = int(a.sum())
    nan = float("nan")
    if n == 0:
        return NisStats(0, 0, 0, nan, nan, nan, nan, nan, False)
    above = float(np.mean(nis[ok] > chi2_ppf(0.95, dof[ok])))
    if na == 0:
        return NisStats(n, 0, n, float(np.median(dof[ok])), nan, nan, nan, above, False)
    sum_dof = float(dof[a].sum())
    mean = float(nis[a].mean())
    lo = float(chi2_ppf(0.025, sum_dof) / na)
    hi = float(chi2_ppf(0.975, sum_dof) / na)
    return NisStats(n, na, n - na, float(np.median(dof[ok])), mean, lo, hi, above, bool(lo <= mean <= hi))


@dataclass(frozen=True)
class Disagreement:
    """Forward/backward disagreement over common epochs (paper 003's two runs of one filter)."""

    n: int
    rms_m: float
    max_m: float
    n_flagged: int
    frac_flagged: float


def disagreement(diff_ned_m, var_sum_ned_m2=None, prob: float = 0.99) -> Disagreement:
    """Statistics of 3-D position differences between two solutions at common epochs.

    An epoch is flagged when d^T (P_a + P_b)^-1 d (diagonal variances) exceeds chi2.ppf(prob, 3):
    the two runs disagree by more than their own SDs allow. Without variances nothing is flagged.
    """
    d = np.asarray(diff_ned_m, dtype=float).reshape(-1, 3)
    ok = np.all(np.isfinite(d), axis=1)
    d = d[ok]
    n = int(d.shape[0])
    if n == 0:
        nan = float("nan")
        return Disagreement(0, nan, nan, 0, nan)
    dist = np.sqrt(np.sum(d * d, axis=1))
    n_flag = 0
    if var_sum_ned_m2 is not None:
        v = np.asarray(var_sum_ned_m2, dtype=float).reshape(-1, 3)[ok]
        good = np.all(np.isfinite(v) & (v > 0), axis=1)
        m2 = np.sum(d[good] ** 2 / v[good], axis=1)
        n_flag = int(np.sum(m2 > chi2_ppf(prob, 3)))
    return Disagreement(n, float(np.sqrt(np.mean(dist**2))), float(dist.max()), n_flag, n_flag / n)
