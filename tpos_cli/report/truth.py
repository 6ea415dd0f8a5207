"""Choosing the truth a run is judged against, and interpolating it onto solution epochs.

Order of preference (issue 6): the session's reference trajectory `truth.*`; for targets, the
`targets.*` points with `role = truth` (GPS-WAAS surveyed, paper 000 section 6.2.1); for trajectories
without `truth.*`, the GPS fixes themselves, of which only those withheld by `--mask-gps` are
independent of the run. All times here are on the logger clock (`t = t_s + Session.t0_s`).

Interpolation never extrapolates and never bridges a truth gap: a query epoch is covered only when
the two truth samples around it are at most `max_gap_s` apart (NaN truth rows are dropped first, so
BROAD's capture dropouts are gaps). Positions are interpolated linearly in NED about one origin,
attitude by SLERP.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tpos_cli.frames.geodetic import lla_to_ned, ned_to_lla
from tpos_cli.io.columns import column
from tpos_cli.report.fixes import differential_name

GAP_FACTOR = 2.5  # a gap is > 2.5 median intervals: one missed sample plus clock jitter is not a gap


@dataclass(frozen=True)
class TrajectoryTruth:
    """A reference trajectory on the logger clock.

    `independent` is False for samples that the run also used as input (GPS fixes outside the
    `--mask-gps` windows); `lever_arm_b_m` (FRD) is where the truth point sits relative to the IMU
    point (the GPS antenna), zeros for a body-point reference.
    """

    source: str  # "truth" | "gps"
    description: str
    t: np.ndarray
    lla: np.ndarray
    rpy_deg: np.ndarray | None
    movement: np.ndarray | None
    independent: np.ndarray
    lever_arm_b_m: np.ndarray
    max_gap_s: float


@dataclass(frozen=True)
class TargetTruth:
    """Surveyed target positions (`targets.*` rows with role = truth)."""

    ids: tuple[str, ...]
    lla: np.ndarray
    description: str


@dataclass(frozen=True)
class ReportTruth:
    trajectory: TrajectoryTruth | None
    targets: TargetTruth | None
    session_path: str
    notes: tuple[str, ...] = field(default=())


def median_gap_limit(t, factor: float = GAP_FACTOR) -> float:
    """Largest truth interval that interpolation may bridge: `factor` median sample intervals."""
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return 0.0
    return float(factor * np.median(np.diff(t)))


def _clean(t, *arrays):
    """Drop rows with NaN time or NaN in the first array, sort by time, drop duplicate stamps."""
    t = np.asarray(t, dtype=float)
    ok = np.isfinite(t) & np.all(np.isfinite(np.asarray(arrays[0], dtype=float).reshape(t.size, -1)), axis=1)
    if ok.all() and np.all(t[1:] > t[:-1]):  # the usual truth table: nothing to drop or sort, no copies
        return (t,) + tuple(np.asarray(a) for a in arrays)
    idx = np.flatnonzero(ok)
    idx = idx[np.argsort(t[idx], kind="stable")]
    ts = t[idx]
    keep = np.ones(ts.size, dtype=bool)
    keep[1:] = np.diff(ts) > 0
    idx = idx[keep]
    return (t[idx],) + tuple(np.asarray(a)[idx] for a in arrays)


def covered(t_truth, t_query, max_gap_s: float):
    """Bracketing indices (lo, hi) and a mask of the query epochs that truth covers.

    Covered: inside [t_truth[0], t_truth[-1]] and the bracketing samples at most `max_gap_s` apart
    (an epoch equal to a truth stamp is always covered).
    """
    tt = np.asarray(t_truth, dtype=float)
    tq = np.asarray(t_query, dtype=float)
    n = tt.size
    if n == 0:
        z = np.zeros(tq.shape, dtype=int)
        return z, z, np.zeros(tq.shape, dtype=bool)
    hi = np.clip(np.searchsorted(tt, tq, side="left"), 0, n - 1)
    lo = np.clip(hi - 1, 0, n - 1)
    exact = tt[hi] == tq
    lo = np.where(exact, hi, lo)
    inside = (tq >= tt[0]) & (tq <= tt[-1]) & np.isfinite(tq)
    ok = inside & (exact | (tt[hi] - tt[lo] <= max_gap_s))
    return lo, hi, ok


def _brackets(t_truth, values, t_query, max_gap_s: float):
    """Cleaned truth values (K, 3), the mask of covered queries, and for those the bracketing
    truth indices and the weight of the later sample (0 on a truth stamp)."""
    t, v = _clean(t_truth, np.asarray(values, dtype=float).reshape(-1, 3))
    tq = np.asarray(t_query, dtype=float)
    lo, hi, ok = covered(t, tq, max_gap_s)
    lo, hi, q = lo[ok], hi[ok], tq[ok]
    span = t[hi] - t[lo]
    return v, ok, lo, hi, np.divide(q - t[lo], span, out=np.zeros_like(q), where=span > 0)


def interpolate_positions(t_truth, lla_truth, t_query, max_gap_s: float):
    """Truth positions at `t_query`, (Q, 3) lla; linear in NED about the first truth point; NaN
    where not covered. Only the bracketing truth samples are converted (hour-long 100 Hz truth),
    and queries on a truth stamp need no conversion at all."""
    lla, ok, lo, hi, w = _brackets(t_truth, lla_truth, t_query, max_gap_s)
    out = np.full((ok.size, 3), np.nan)
    res = lla[lo].copy()
    between = w > 0
    if between.any():
        origin = lla[0]
        a, b = lla_to_ned(lla[lo[between]], origin), lla_to_ned(lla[hi[between]], origin)
        res[between] = ned_to_lla(a + w[between, None] * (b - a), origin)
    out[ok] = res
    return out


def interpolate_attitude(t_truth, rpy_deg_truth, t_query, max_gap_s: float):
    """Truth roll, pitch, yaw (deg) at `t_query` by SLERP between the bracketing truth samples,
    (Q, 3); NaN where not covered."""
    rpy, ok, lo, hi, w = _brackets(t_truth, rpy_deg_truth, t_query, max_gap_s)
    out = np.full((ok.size, 3), np.nan)
    res = rpy[lo].copy()
    between = w > 0
    if between.any():
        from scipy.spatial.transform import Rotation  # lazy: only for queries between truth samples

        # C_nb = Rz(yaw) Ry(pitch) Rx(roll): scipy intrinsic "ZYX" with (yaw, pitch, roll)
        r_lo = Rotation.from_euler("ZYX", rpy[lo[between]][:, ::-1], degrees=True)
        r_hi = Rotation.from_euler("ZYX", rpy[hi[between]][:, ::-1], degrees=True)
        step = Rotation.from_rotvec(w[between, None] * (r_lo.inv() * r_hi).as_rotvec())  # SLERP
        res[between] = (r_lo * step).as_euler("ZYX", degrees=True)[:, ::-1]
    out[ok] = res
    return out


def interpolate_flag(t_truth, flag, t_query, max_gap_s: float):
    """A truth boolean column at `t_query`: True only where both bracketing samples are True."""
    t, f = _clean(t_truth, np.asarray(flag, dtype=float))
    lo, hi, ok = covered(t, np.asarray(t_query, dtype=float), max_gap_s)
    if t.size == 0:
        return ok
    return ok & (f[lo] > 0.5) & (f[hi] > 0.5)


# ---------------------------------------------------------------- choosing the truth of a run


SAME_ROW_S = 1e-3  # a truth row at a fix's time (s) ...
SAME_ROW_M = 1e-3  # ... and place (m) is that fix written twice: a publisher's truth is the receiver's solution


def nearest(t_sorted, t):
    """(index into t_sorted (sorted, not empty) of the element nearest each of t, the lower one on
    a tie; that element's |distance| to t)."""
    j = np.clip(np.searchsorted(t_sorted, t), 1, max(t_sorted.size - 1, 1))
    hi = np.minimum(j, t_sorted.size - 1)
    k = np.where(np.abs(t_sorted[j - 1] - t) <= np.abs(t_sorted[hi] - t), j - 1, hi)
    return k, np.abs(t_sorted[k] - t)


def used_fix_rows(t, lla, session, withheld) -> np.ndarray:
    """Truth rows (t on the logger clock, lla) that are a GPS fix the run used: the same time
    within SAME_ROW_S and the same point within SAME_ROW_M (fixes withheld by --mask-gps were not
    used). Publishers of RTK drives give the receiver's own solution as the truth; a run that used
    those fixes is judged against itself there (its residual to a fix has variance R - P, not P)."""
    g = session.gps
    used = np.zeros(t.size, dtype=bool)
    if g is None or t.size == 0:
        return used
    ok = np.all(np.isfinite(g.lla), axis=1)
    tg = np.asarray(g.t_s, dtype=float)[ok] + session.t0_s
    lg = np.asarray(g.lla, dtype=float)[ok]
    if withheld is not None and len(withheld):
        far = nearest(np.sort(np.asarray(column(withheld, "t"), dtype=float)), tg)[1] > SAME_ROW_S
        tg, lg = tg[far], lg[far]
    if tg.size == 0:
        return used
    order = np.argsort(tg)
    tg, lg = tg[order], lg[order]
    j, dt = nearest(tg, t)
    near = dt <= SAME_ROW_S
    if not near.any():
        return used
    d = np.full(t.size, np.inf)
    d[near] = np.linalg.norm(lla_to_ned(lla[near], lg[j[near]][0]) - lla_to_ned(lg[j[near]], lg[j[near]][0]), axis=1)
    return near & (d <= SAME_ROW_M)


def _truth_from_reference(session, withheld=None) -> TrajectoryTruth | None:
    tr = session.truth
    if tr is None:
        return None
    t = np.asarray(tr.t_s, dtype=float) + session.t0_s
    lla = np.asarray(tr.lla, dtype=float)
    rpy = np.asarray(tr.rpy_deg, dtype=float) if tr.rpy_deg is not None else None
    has_att = rpy is not None and bool(np.any(np.all(np.isfinite(rpy), axis=1)))
    movement = None
    extra = getattr(tr, "extra", None) or {}
    if "movement" in extra:
        movement = np.asarray(extra["movement"], dtype=float)
    ok = np.all(np.isfinite(lla), axis=1)
    gap = median_gap_limit(np.unique(t[ok])) if ok.sum() > 1 else 0.0
    n_nan = int((~ok).sum())
    rate = 1.0 / np.median(np.diff(np.unique(t[ok]))) if ok.sum() > 1 else float("nan")
    desc = (
        f"session reference trajectory truth.* ({int(ok.sum())} valid rows at about {rate:.3g} Hz, "
        f"{t[ok].min() if ok.any() else float('nan'):.2f}..{t[ok].max() if ok.any() else float('nan'):.2f} s"
        f"{', attitude' if has_att else ', no attitude'}"
        f"{f', {n_nan} NaN rows skipped' if n_nan else ''}"
        f"{', movement phase marked' if movement is not None else ''}); interpolation bridges gaps up to {gap:.3g} s; "
        "its own accuracy is what the data set's publisher states"
    )
    used = used_fix_rows(t, lla, session, withheld)
    n_independent = int((ok & ~used).sum())
    if used.any() and n_independent:
        desc += (f"; {int(used.sum())} of its rows are the GPS fixes the run used (same times and points): only the "
                 f"{n_independent} others are independent truth")
    elif used.any():  # e.g. an RTK log whose truth is its own fixed epochs
        desc += (f"; all {int(used.sum())} of its valid rows are the GPS fixes the run used (same times and points): none is "
                 "independent truth; withhold fixes with `tpos process --mask-gps T0:T1` to score inside the windows")
    return TrajectoryTruth(
        source="truth",
        description=desc,
        t=t,
        lla=lla,
        rpy_deg=rpy if has_att else None,
        movement=movement,
        independent=~used,
        lever_arm_b_m=np.zeros(3),
        max_gap_s=gap,
    )


def _truth_from_gps(session, withheld, mask_windows) -> TrajectoryTruth | None:
    """GPS fixes (fix > 0) of the session plus the run's withheld fixes; independent inside masks."""
    ts, llas, fixes, sig_h = [], [], [], []
    g = session.gps
    if g is not None:
        ok = (np.asarray(g.fix) > 0) & np.all(np.isfinite(g.lla), axis=1)
        ts.append(np.asarray(g.t_s, dtype=float)[ok] + session.t0_s)
        llas.append(np.asarray(g.lla, dtype=float)[ok])
        fixes.append(np.asarray(g.fix)[ok])
        s = np.asarray(g.sigma_neu_m, dtype=float)[ok] if g.sigma_neu_m is not None else np.full((ok.sum(), 3), np.nan)
        sig_h.append(np.hypot(s[:, 0], s[:, 1]))
    if withheld is not None and len(withheld):
        def w(name: str) -> np.ndarray:
            return np.asarray(column(withheld, name), dtype=float)

        lla_w = np.column_stack([w("lat"), w("lon"), w("h")])
        ok = np.isfinite(w("t")) & np.all(np.isfinite(lla_w), axis=1)
        if "fix" in withheld.columns:
            ok &= w("fix") > 0
        ts.append(w("t")[ok])
        llas.append(lla_w[ok])
        fixes.append(w("fix")[ok].astype(int) if "fix" in withheld.columns else np.ones(ok.sum(), int))
        if {"sigma_n", "sigma_e"} <= set(withheld.columns):
            sig_h.append(np.hypot(w("sigma_n"), w("sigma_e"))[ok])
        else:
            sig_h.append(np.full(ok.sum(), np.nan))
    if not ts or sum(a.size for a in ts) == 0:
        return None
    t, lla, fix, sh = (np.concatenate(a) for a in (ts, llas, fixes, sig_h))
    t, lla, fix, sh = _clean(t, lla, fix, sh)
    mask = np.asarray(mask_windows, dtype=float).reshape(-1, 2)
    indep = np.zeros(t.size, dtype=bool)
    if withheld is not None and len(withheld):
        # exactly the fixes the run did not see: those in withheld_gps.parquet
        indep = nearest(np.sort(np.asarray(column(withheld, "t"), dtype=float)), t)[1] <= 1e-6
    else:
        for a, b in mask:  # --mask-gps T0:T1 is a closed window
            indep |= (t >= a) & (t <= b)
    gap = median_gap_limit(t)
    n_diff = int(np.sum(fix == 2))
    diff_name = differential_name(fix, sh)
    med_sh = float(np.nanmedian(sh)) if np.any(np.isfinite(sh)) else float("nan")
    quality = f"median reported horizontal SD {med_sh:.2g} m" if np.isfinite(med_sh) else "no reported SD"
    desc = (
        f"GPS fixes as truth ({t.size} fixes, {n_diff} {diff_name}, {t.size - n_diff} autonomous; {quality}); "
        + (
            f"{int(indep.sum())} fixes withheld by --mask-gps are independent truth; the others were processing input"
            if mask.size
            else "all of them were processing input, so agreement with them is not independent accuracy"
        )
        + "; compared at the antenna (lever arm applied)"
    )
    return TrajectoryTruth(
        source="gps",
        description=desc,
        t=t,
        lla=lla,
        rpy_deg=None,
        movement=None,
        independent=indep,
        lever_arm_b_m=np.asarray(session.meta.lever_arm_b_m, dtype=float).reshape(3),
        max_gap_s=gap,
    )


def _target_truth(session) -> TargetTruth | None:
    tg = session.targets
    if tg is None:
        return None
    idx = [i for i, r in enumerate(tg.role) if str(r).strip().lower() == "truth"]
    if not idx:
        return None
    ids = tuple(str(tg.ids[i]) for i in idx)
    lla = np.asarray(tg.lla, dtype=float)[idx]
    return TargetTruth(ids, lla, f"{len(ids)} surveyed target(s) with role = truth in targets.* (GPS-WAAS survey per the contract)")


def choose_truth(session, *, withheld_gps=None, mask_windows=(), need_targets: bool, need_trajectory: bool) -> ReportTruth:
    """Pick the truth for a run from its session (see module docstring); fields are None where the
    session has nothing to judge that part of the run against (a quality-control-only report)."""
    traj = _truth_from_reference(session, withheld_gps) if need_trajectory else None
    if need_trajectory and traj is None:
        traj = _truth_from_gps(session, withheld_gps, mask_windows)
    tgt = _target_truth(session) if need_targets else None
    return ReportTruth(traj, tgt, str(session.path))
