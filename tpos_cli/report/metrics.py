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
from tpos_cli.frames.rotation import wrap_angle_deg

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


def euler_to_quat(rpy_deg) -> np.ndarray:
    """Scalar-first unit quaternions (4, N) of C_nb = Rz(yaw) Ry(pitch) Rx(roll) from roll, pitch,
    yaw (N, 3) in degrees: q = q_z(yaw) q_y(pitch) q_x(roll), with half angles
    w = cr cp cy + sr sp sy, x = sr cp cy - cr sp sy, y = cr sp cy + sr cp sy, z = cr cp sy - sr sp cy.
    Four numbers an epoch instead of a DCM's nine, and no 3x3 products for the angle between two
    attitudes (`rotation_angle_deg`): what hour-long 100 Hz errors need."""
    h = np.ascontiguousarray(np.radians(np.asarray(rpy_deg, dtype=float).reshape(-1, 3)).T) * 0.5
    (cr, cp, cy), (sr, sp, sy) = np.cos(h), np.sin(h)
    crcp, srsp, srcp, crsp = cr * cp, sr * sp, sr * cp, cr * sp
    return np.stack([crcp * cy + srsp * sy, srcp * cy - crsp * sy, crsp * cy + srcp * sy, crcp * sy - srsp * cy])


def rotation_angle_deg(q_a, q_b) -> np.ndarray:
    """Angle of the rotation between unit quaternions (4, N) `q_a` and `q_b`, deg: with
    q = conj(q_a) q_b = (w, v), angle = 2 atan2(|v|, |w|), accurate at small and large angles alike
    (an arccos of w alone loses digits near 0) and the same for q and -q."""
    a0, a1, a2, a3 = q_a
    b0, b1, b2, b3 = q_b
    w = a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3
    x = a0 * b1 - a1 * b0 - a2 * b3 + a3 * b2
    y = a0 * b2 - a2 * b0 - a3 * b1 + a1 * b3
    z = a0 * b3 - a3 * b0 - a1 * b2 + a2 * b1
    return np.degrees(2.0 * np.arctan2(np.sqrt(x * x + y * y + z * z), np.abs(w)))


def attitude_errors_deg(sol_rpy_deg, truth_rpy_deg, *, truth_quat=None) -> dict[str, np.ndarray]:
    """Wrap-aware Euler-angle errors (solution minus truth), deg in (-180, 180], and the total
    rotation angle of C_truth^T C_sol, deg (independent of the Euler convention near gimbal lock).
    `truth_quat` (4, N), `euler_to_quat` of the truth, may be passed when several solutions share
    the truth epochs."""
    s = np.asarray(sol_rpy_deg, dtype=float).reshape(-1, 3)
    t = np.asarray(truth_rpy_deg, dtype=float).reshape(-1, 3)
    d = wrap_angle_deg(s - t)
    q_t = euler_to_quat(t) if truth_quat is None else truth_quat
    with np.errstate(invalid="ignore"):  # NaN rows stay NaN
        total = rotation_angle_deg(q_t, euler_to_quat(s))
    return {"roll_deg": d[:, 0], "pitch_deg": d[:, 1], "yaw_deg": d[:, 2], "att_deg": total}


def _principal_sds(sigma_n_m, sigma_e_m, rho):
    """Principal SDs (s1 >= s2) of the 2x2 covariance [[sn^2, rho sn se], [rho sn se, se^2]]:
    eigenvalues (a + c)/2 +- sqrt(((a - c)/2)^2 + b^2); uncorrelated, the larger and smaller SD."""
    if rho == 0.0:
        return np.maximum(sigma_n_m, sigma_e_m), np.minimum(sigma_n_m, sigma_e_m)
    a, c, b = sigma_n_m * sigma_n_m, sigma_e_m * sigma_e_m, rho * sigma_n_m * sigma_e_m
    m, r = 0.5 * (a + c), np.hypot(0.5 * (a - c), b)
    return np.sqrt(np.maximum(m + r, 0.0)), np.sqrt(np.maximum(m - r, 0.0))


CEP_NODES = 720  # periodic trapezoid nodes over the polar angle: spectrally accurate


def _solve_cep(s1, s2, prob) -> np.ndarray:
    """r with P(R <= r) = prob for principal SDs s1 >= s2 > 0 (arrays): safeguarded Newton on the
    polar integral of `cep_from_sigmas`, to |step| <= 1e-12 s1, all rows at once.

    The integrand depends on theta through cos^2 and sin^2 only, so the CEP_NODES-point periodic
    trapezoid rule equals a weighted sum over the quarter period [0, pi/2] (its end nodes stand for
    2 nodes each, the inner ones for 4): a quarter of the exponentials, the same rule."""
    k = np.arange(CEP_NODES // 4 + 1)
    th = k * (2.0 * np.pi / CEP_NODES)
    w = np.where((k == 0) | (k == CEP_NODES // 4), 2.0, 4.0) / CEP_NODES
    q = np.cos(th) ** 2 / (s1 * s1)[:, None] + np.sin(th) ** 2 / (s2 * s2)[:, None]
    inv_q = 1.0 / q
    norm = 1.0 / (s1 * s2)
    r = np.sqrt(s1 * s2 * -2.0 * np.log1p(-prob))  # the circular answer at the mean SD
    lo, hi = np.zeros(s1.size), 10.0 * s1
    todo = np.arange(s1.size)
    for _ in range(100):
        if not todo.size:
            break
        rr = r[todo]
        e = np.exp(-0.5 * (rr * rr)[:, None] * q[todo])
        f = ((1.0 - e) * inv_q[todo]) @ w * norm[todo] - prob
        df = rr * (e @ w) * norm[todo]  # d/dr of the same sum
        lo[todo] = np.where(f < 0, rr, lo[todo])
        hi[todo] = np.where(f < 0, hi[todo], rr)
        with np.errstate(divide="ignore", invalid="ignore"):
            nxt = rr - f / df
        inside = (nxt > lo[todo]) & (nxt < hi[todo])
        nxt = np.where(inside, nxt, 0.5 * (lo[todo] + hi[todo]))  # bisect where Newton leaves the bracket
        r[todo] = nxt
        todo = todo[np.abs(nxt - rr) > 1e-12 * s1[todo]]
    return r


def cep_from_sigmas(sigma_n_m, sigma_e_m, prob=0.5, rho=0.0):
    """Radius of the circle about the mean holding `prob` of a zero-mean 2-D Gaussian, m.

    P(R <= r) = 1/(2 pi s1 s2) int_0^{2pi} (1 - exp(-r^2 q/2)) / q dtheta with
    q = cos^2/s1^2 + sin^2/s2^2 (polar integral of the density; s1, s2 the principal SDs),
    evaluated with the periodic trapezoid rule (spectrally accurate) and solved for r.
    Circular case: sigma * sqrt(-2 ln(1 - prob)); 1-D limit (s2 <= 1e-9 s1): P(|x| <= r) = prob.
    Scalars give a float; arrays (one row per target shot) an array, solved together.
    """
    sn, se = np.asarray(sigma_n_m, dtype=float), np.asarray(sigma_e_m, dtype=float)
    scalar = sn.ndim == 0 and se.ndim == 0
    sn, se = np.broadcast_arrays(np.atleast_1d(sn), np.atleast_1d(se))
    out = np.full(sn.shape, np.nan)
    ok = np.isfinite(sn) & np.isfinite(se) & (sn >= 0) & (se >= 0)
    s1, s2 = _principal_sds(sn[ok], se[ok], float(rho))
    res = np.zeros(s1.size)
    one_d = (s1 > 0) & (s2 <= 1e-9 * s1)
    res[one_d] = s1[one_d] * special.ndtri(0.5 + prob / 2.0)
    two_d = (s1 > 0) & ~one_d
    res[two_d] = _solve_cep(s1[two_d], s2[two_d], float(prob))
    out[ok] = res
    return float(out[0]) if scalar else out


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
