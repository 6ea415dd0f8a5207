"""Quality figures a report shows without truth: estimated accuracy, forward/backward separation,
GPS quality, magnetic disturbances, anchor visibility. Pure numpy over the run's and the session's
arrays (one pass each, no per-row Python).

- Estimated accuracy: the 95 % horizontal radius is the semi-major axis of the 95 % ellipse of the
  north-east covariance (sigma_n, sigma_e and cov_ne_m2 where the run writes it); vertical and
  attitude 95 % bounds are 1.96 sigma.
- Separation of two runs of one filter (forward and backward): d = x_a - x_b at the epochs of a,
  with variance P_a + P_b (the runs are treated as independent, as the two-filter smoother does);
  the 99 % bound of the horizontal separation is the semi-major axis of the 99 % ellipse of the
  summed north-east covariance.
- Magnetic disturbance: 1 s medians of |B| farther from the reference field magnitude than
  max(3 uT, 5 x the session's magnetometer noise): well outside sensor noise, well inside the tens
  of uT a nearby car, rebar or a magnet adds. The reference is the field the alignment measured
  (summary.json), else the median of the log.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from scipy import special

from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.io.columns import Columns, column, first_appearance_codes, flags, from_records, is_empty
from tpos_cli.report.metrics import chi2_ppf
from tpos_cli.report.targets import horizontal_ellipse
from tpos_cli.report.truth import covered, median_gap_limit
from tpos_cli.timebase import true_runs

if TYPE_CHECKING:
    import pandas as pd

Z95 = float(special.ndtri(0.975))  # two-sided 95 % of a Gaussian: 1.96 sigma
CHI2_2_95 = float(chi2_ppf(0.95, 2))  # squared Mahalanobis radius of a 95 % ellipse
MAG_THRESHOLD_UT = 3.0
MAG_NOISE_FACTOR = 5.0
MAG_WINDOW_S = 1.0


@dataclass(frozen=True)
class Series:
    """One trajectory solution as arrays (logger clock; NaN where the run wrote none)."""

    name: str
    t: np.ndarray
    lla: np.ndarray  # (N, 3)
    rpy_deg: np.ndarray  # (N, 3)
    sigma_neu_m: np.ndarray  # (N, 3)
    cov_ne_m2: np.ndarray  # (N,), zeros when not written
    sigma_rpy_deg: np.ndarray  # (N, 3) Euler-angle SDs: singular at pitch +-90 deg
    sigma_heading_deg: np.ndarray  # (N,) SD of the attitude error about down (NaN when the run wrote none)
    att95_deg: np.ndarray  # (N,) 95 % bound of the total attitude error angle (`trajectory.attitude_error_sigmas`)
    flag: np.ndarray  # (N,) bool: forward/backward disagreement flagged by the chain
    outage: np.ndarray  # (N,) bool

    @property
    def has_position_sigma(self) -> bool:
        return bool(np.isfinite(self.sigma_neu_m[:, :2]).any())

    @cached_property
    def h95_m(self) -> np.ndarray:
        """95 % horizontal radius of each epoch (`horizontal_95_m`), computed once per solution: the
        summary, the accuracy page and the estimated-accuracy table all draw on it."""
        h = horizontal_ellipse(_cov_ne(self.sigma_neu_m[:, 0], self.sigma_neu_m[:, 1], self.cov_ne_m2)).semi_major_m
        h.setflags(write=False)  # shared by its readers
        return h

    @cached_property
    def is_static(self) -> bool:
        """A fixed point (a tripod observer): its plan view is one point, not a trajectory."""
        p = self.lla[np.isfinite(self.lla).all(axis=1)]
        return bool(len(p) == 0 or np.ptp(p[:, 0]) < 1e-9 and np.ptp(p[:, 1]) < 1e-9)


def _col(df, name: str, fill=np.nan) -> np.ndarray:
    return np.asarray(column(df, name), dtype=float) if name in df.columns else np.full(len(df), fill)


def _flag(df, name: str) -> np.ndarray:
    return flags(df, name) if name in df.columns else np.zeros(len(df), bool)


def _by_solution(labels: np.ndarray) -> dict[str, np.ndarray]:
    """Row positions of each solution, solutions in order of first appearance (pandas'
    `groupby(sort=False).indices`)."""
    codes, names = first_appearance_codes(labels)
    return {str(s): np.flatnonzero(codes == k) for k, s in enumerate(names)}


def solution_series(trajectory: Columns | pd.DataFrame | None) -> dict[str, Series]:
    """Every solution of trajectory.parquet as `Series`: each column converted once for the whole
    table, then split by solution (views of contiguous rows, as `load_run` orders them)."""
    if trajectory is None or is_empty(trajectory):
        return {}
    d = trajectory
    t = _col(d, "t")
    lla = np.stack([_col(d, c) for c in ("lat", "lon", "h")]).T  # column-major, as pandas' to_numpy gave it
    rpy = np.stack([_col(d, c) for c in ("roll", "pitch", "yaw")]).T
    sig_u = _col(d, "sigma_u") if "sigma_u" in d.columns else _col(d, "sigma_d")
    sig_neu = np.column_stack([_col(d, "sigma_n"), _col(d, "sigma_e"), sig_u])
    cov_ne = np.nan_to_num(_col(d, "cov_ne_m2", 0.0))
    sig_rpy = np.column_stack([_col(d, "sigma_roll"), _col(d, "sigma_pitch"), _col(d, "sigma_yaw")])
    sig_heading, att95 = _col(d, "sigma_heading"), _col(d, "att95_deg")
    flag, outage = _flag(d, "flag"), _flag(d, "outage")
    out = {}
    for name, idx in _by_solution(np.asarray(column(d, "solution"))).items():
        rows = slice(idx[0], idx[-1] + 1) if idx[-1] - idx[0] + 1 == idx.size else idx
        out[str(name)] = Series(
            name=str(name),
            t=t[rows],
            lla=lla[rows],
            rpy_deg=rpy[rows],
            sigma_neu_m=sig_neu[rows],
            cov_ne_m2=cov_ne[rows],
            sigma_rpy_deg=sig_rpy[rows],
            sigma_heading_deg=sig_heading[rows],
            att95_deg=att95[rows],
            flag=flag[rows],
            outage=outage[rows],
        )
    return out


def _cov_ne(sn, se, cne) -> np.ndarray:
    return np.stack([np.column_stack([sn**2, cne]), np.column_stack([cne, se**2])], axis=1)


def horizontal_95_m(s: Series) -> np.ndarray:
    """95 % horizontal radius of each epoch: semi-major axis of its 95 % ellipse, m."""
    return s.h95_m


def estimated_accuracy(series: dict[str, Series], order) -> Columns:
    """Per solution: median and 95th percentile over the run of the 95 % bounds it states."""
    rows = []
    for name in order:
        s = series[name]
        h95 = horizontal_95_m(s) if s.has_position_sigma else np.full(s.t.size, np.nan)
        v95 = Z95 * s.sigma_neu_m[:, 2]
        y95 = Z95 * s.sigma_rpy_deg[:, 2]
        r95 = Z95 * np.hypot(s.sigma_rpy_deg[:, 0], s.sigma_rpy_deg[:, 1]) / np.sqrt(2.0)

        def q(a, p):
            a = a[np.isfinite(a)]
            return float(np.percentile(a, p)) if a.size else np.nan

        rows.append(
            {
                "solution": name,
                "n": int(s.t.size),
                "h95_median_m": q(h95, 50),
                "h95_p95_m": q(h95, 95),
                "v95_median_m": q(v95, 50),
                "v95_p95_m": q(v95, 95),
                "tilt95_median_deg": q(r95, 50),
                "yaw95_median_deg": q(y95, 50),
                "yaw95_p95_deg": q(y95, 95),
                "flagged_frac": float(s.flag.mean()) if s.t.size else np.nan,
            }
        )
    return from_records(rows, list(rows[0]) if rows else [])


@dataclass(frozen=True)
class Separation:
    """Forward minus backward at the forward epochs: horizontal distance, its 99 % bound, and the
    normalised squared 3-D separation d^T (P_a + P_b)^-1 d (diagonal variances)."""

    a: str
    b: str
    t: np.ndarray
    dist_h_m: np.ndarray
    bound99_h_m: np.ndarray
    nees3: np.ndarray
    d_ned_m: np.ndarray
    var_ned_m2: np.ndarray


def separation(a: Series, b: Series) -> Separation:
    """Separation of solution a from b, b interpolated linearly at a's epochs (no extrapolation,
    no bridging of b's gaps; NaN there)."""
    origin = a.lla[np.isfinite(a.lla).all(axis=1)][0]
    na, nb = lla_to_ned(a.lla, origin), lla_to_ned(b.lla, origin)
    _, _, ok = covered(b.t, a.t, median_gap_limit(b.t))
    d = np.full_like(na, np.nan)
    var = np.full_like(na, np.nan)
    if ok.any():
        for i in range(3):
            d[ok, i] = na[ok, i] - np.interp(a.t[ok], b.t, nb[:, i])
            var[ok, i] = a.sigma_neu_m[ok, i] ** 2 + np.interp(a.t[ok], b.t, b.sigma_neu_m[:, i] ** 2)
    cne = a.cov_ne_m2 + np.interp(a.t, b.t, b.cov_ne_m2)
    bound = horizontal_ellipse(
        np.stack([np.column_stack([var[:, 0], cne]), np.column_stack([cne, var[:, 1]])], axis=1), prob=0.99
    ).semi_major_m
    with np.errstate(invalid="ignore", divide="ignore"):
        nees = np.sum(d * d / var, axis=1)
    return Separation(a.name, b.name, a.t, np.hypot(d[:, 0], d[:, 1]), bound, nees, d, var)


@dataclass(frozen=True)
class GpsQuality:
    t: np.ndarray  # logger clock
    fix: np.ndarray  # 0 none, 1 autonomous, 2 differential (`report.fixes.differential_name`)
    nsat: np.ndarray | None
    hdop: np.ndarray | None
    sigma_h_m: np.ndarray | None  # reported horizontal SD, sqrt(s_n^2 + s_e^2)


def gps_quality(session) -> GpsQuality | None:
    g = getattr(session, "gps", None)
    if g is None or len(g.t_s) == 0:
        return None

    def opt(a):
        a = None if a is None else np.asarray(a, dtype=float)
        return a if a is not None and np.isfinite(a).any() else None

    s = opt(g.sigma_neu_m)
    return GpsQuality(
        np.asarray(g.t_s, float) + session.t0_s,
        np.asarray(g.fix, float),
        opt(g.nsat),
        opt(g.hdop),
        None if s is None else np.hypot(s[:, 0], s[:, 1]),
    )


def windows_from_mask(t, mask) -> np.ndarray:
    """(K, 2) [start, end] of the runs of True in `mask` over sorted times `t`."""
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return np.empty((0, 2))
    starts, ends = true_runs(m)
    ends = ends - 1
    t = np.asarray(t, dtype=float)
    return np.column_stack([t[starts], t[ends]])


@dataclass(frozen=True)
class MagField:
    t: np.ndarray  # logger clock, bin centres
    norm_ut: np.ndarray  # 1 s medians of |B|
    reference_ut: float
    threshold_ut: float
    disturbed: np.ndarray  # (K, 2) windows, logger clock


def magnetic_field(session, reference_ut: float | None = None) -> MagField | None:
    """|B| in 1 s medians against the reference field (module docstring); None without magnetometer."""
    imu = getattr(session, "imu", None)
    if imu is None or imu.mag_b_ut is None:
        return None
    t = np.asarray(imu.t_s, dtype=float)
    norm = np.linalg.norm(np.asarray(imu.mag_b_ut, dtype=float), axis=1)
    ok = np.isfinite(norm)
    if ok.sum() < 2:
        return None
    t, norm = t[ok], norm[ok]
    rate = 1.0 / np.median(np.diff(t))
    k = max(int(round(rate * MAG_WINDOW_S)), 1)
    nb = norm.size // k
    if nb < 1:
        return None
    med = np.median(norm[: nb * k].reshape(nb, k), axis=1)
    tc = t[: nb * k].reshape(nb, k).mean(axis=1) + session.t0_s
    ref = float(reference_ut) if reference_ut and np.isfinite(reference_ut) else float(np.median(norm))
    noise = getattr(getattr(session.meta, "imu_noise", None), "mag_noise_ut", None) or 0.0
    thr = max(MAG_THRESHOLD_UT, MAG_NOISE_FACTOR * float(noise))
    bad = np.abs(med - ref) > thr
    half = 0.5 * k / rate
    w = windows_from_mask(tc, bad)
    if len(w):
        w = w + np.array([-half, half])
    return MagField(tc, med, ref, thr, w)


@dataclass(frozen=True)
class AnchorVisibility:
    t: np.ndarray  # logger clock, 1 s bins
    n_anchors: np.ndarray  # distinct anchors ranged in each bin
    ids: tuple[str, ...]
    per_anchor: np.ndarray  # (A, bins) bool


def anchor_visibility(session, bin_s: float = 1.0) -> AnchorVisibility | None:
    ar = getattr(session, "anchor_ranges", None)
    anchors = getattr(session, "anchors", None)
    if ar is None or anchors is None or len(ar.t_s) == 0:
        return None
    t = np.asarray(ar.t_s, dtype=float)
    ok = np.isfinite(t) & np.isfinite(np.asarray(ar.range_m, dtype=float))
    a = np.asarray(ar.anchor)[ok].astype(int)
    b = np.floor((t[ok] - t[ok].min()) / bin_s).astype(int)
    nb = int(b.max()) + 1
    seen = np.zeros((len(anchors.ids), nb), dtype=bool)
    seen[a, b] = True
    tc = t[ok].min() + (np.arange(nb) + 0.5) * bin_s + session.t0_s
    return AnchorVisibility(tc, seen.sum(axis=0), tuple(str(i) for i in anchors.ids), seen)


def inside_95(se, s: Series) -> dict[str, float]:
    """Share of epochs whose error lies inside the solution's own 95 % bound: the horizontal error
    inside its 95 % ellipse (Mahalanobis^2 <= chi2_2(0.95)), vertical and yaw within 1.96 sigma.
    About 0.95 for honest sigmas."""
    e = se.err_ned_m
    sn, se_, su = s.sigma_neu_m[:, 0], s.sigma_neu_m[:, 1], s.sigma_neu_m[:, 2]
    c = s.cov_ne_m2
    out = {}
    with np.errstate(invalid="ignore", divide="ignore"):
        m2 = (se_**2 * e[:, 0] ** 2 - 2 * c * e[:, 0] * e[:, 1] + sn**2 * e[:, 1] ** 2) / (sn**2 * se_**2 - c**2)
        ok = np.isfinite(m2)
        out["horizontal"] = float(np.mean(m2[ok] <= CHI2_2_95)) if ok.any() else np.nan
        v = np.abs(e[:, 2]) / su
        ok = np.isfinite(v)
        out["vertical"] = float(np.mean(v[ok] <= Z95)) if ok.any() else np.nan
        if se.att_err_deg is not None:
            y = np.abs(se.att_err_deg["yaw_deg"]) / s.sigma_rpy_deg[:, 2]
            ok = np.isfinite(y)
            out["yaw"] = float(np.mean(y[ok] <= Z95)) if ok.any() else np.nan
    return out
