"""Filter health without truth: NIS against chi-square per measurement kind, rejections, the
chain's own `flag` column, and forward/backward disagreement (so a user can judge a run that has
no truth)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from tpos_cli.io.columns import Columns, as_text, column, flags, from_records, groups, is_empty
from tpos_cli.report import metrics
from tpos_cli.report.metrics import chi2_ppf
from tpos_cli.report.qc import Separation, Series, separation
from tpos_cli.report.rundir import ordered_solutions

FLAG_PROBABILITY = 0.99  # the forward/backward separation bound of the disagreement statistics


@dataclass(frozen=True)
class Health:
    nis: Columns  # solution, kind, n, n_accepted, n_rejected, dof, mean_nis, mean_lo, mean_hi, frac_above_95, consistent, band_source
    flags: Columns  # solution, n_epochs, n_flagged
    disagreement: Columns  # a, b, n, rms_m, max_m, n_flagged, frac_flagged
    separations: tuple[Separation, ...] = ()


def nis_table(innovations, checks: Mapping | None = None) -> Columns:
    """Mean NIS per solution and kind (`metrics.nis_stats`). Where the run's verdict checked that
    mean (`checks`: summary.json quality.checks, "nis.SOLUTION.KIND" with its band), the row carries
    the verdict's mean and band (99.9 %, allowing for the gate and for noise figures the chain
    estimated: `consistency.mean_chi2`), so the report and the verdict never disagree on the same
    mean; `band_source` says which band a row holds ("verdict" or "95 %")."""
    cols = ["solution", "kind"] + list(metrics.NisStats.__dataclass_fields__) + ["band_source"]
    if innovations is None or is_empty(innovations):
        return from_records([], cols)
    nis = np.asarray(column(innovations, "nis"), dtype=float)
    dof = np.asarray(column(innovations, "dof"), dtype=float)
    acc = flags(innovations, "accepted")
    labels = [as_text(np.asarray(column(innovations, c))) for c in ("solution", "kind")]
    by = dict(groups(*labels))
    rows = []
    for sol in ordered_solutions(s for s, _ in by):
        for (s, kind), i in by.items():
            if s == sol:
                row = {"solution": sol, "kind": kind, **metrics.nis_stats(nis[i], dof[i], acc[i]).as_dict(), "band_source": "95 %"}
                check = _verdict_band(checks, f"nis.{sol}.{kind}")
                if check is not None and row["n_accepted"]:
                    mean, lo, hi = check
                    row.update(mean_nis=mean, mean_lo=lo, mean_hi=hi, consistent=bool(lo <= mean <= hi), band_source="verdict")
                rows.append(row)
    return from_records(rows, cols)


def _verdict_band(checks: Mapping | None, key: str) -> tuple[float, float, float] | None:
    """(mean, lo, hi) of a verdict NIS check, or None when the run has no such check with finite figures."""
    fig = (checks or {}).get(key)
    if not isinstance(fig, Mapping):
        return None
    band, mean = fig.get("band"), fig.get("mean_nis")
    if not isinstance(band, (list, tuple)) or len(band) != 2:
        return None
    try:
        vals = (float(mean), float(band[0]), float(band[1]))
    except (TypeError, ValueError):
        return None
    return vals if all(np.isfinite(vals)) else None


def disagreement_table(series: dict[str, Series], pairs=(("forward", "backward"),)) -> tuple[Columns, tuple[Separation, ...]]:
    """Position disagreement between solution pairs at the first one's epochs (linear interpolation
    of the second, no extrapolation, no bridging of gaps), and the separation series."""
    cols = ["a", "b", "n", "rms_m", "max_m", "n_flagged", "frac_flagged"]
    rows, seps = [], []
    for a, b in pairs:
        if a not in series or b not in series:
            continue
        sep = separation(series[a], series[b])
        var = sep.var_ned_m2 if np.isfinite(sep.var_ned_m2).any() else None
        st = metrics.disagreement(sep.d_ned_m, var, prob=FLAG_PROBABILITY)
        rows.append({"a": a, "b": b, **st.__dict__})
        seps.append(sep)
    return from_records(rows, cols), tuple(seps)


def flag_table(series: dict[str, Series]) -> Columns:
    cols = ["solution", "n_epochs", "n_flagged"]
    rows = [{"solution": n, "n_epochs": int(s.flag.size), "n_flagged": int(s.flag.sum())} for n, s in series.items() if s.flag.any()]
    return from_records(rows, cols)


def filter_health(innovations, series: dict[str, Series], checks: Mapping | None = None) -> Health:
    """checks: the run's verdict checks (summary.json quality.checks), whose NIS bands the table takes."""
    dis, seps = disagreement_table(series)
    return Health(nis_table(innovations, checks), flag_table(series), dis, seps)


def nis_band(dof, prob: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Per-update two-sided chi-square band of the NIS (NaN where dof is unknown)."""
    d = np.asarray(dof, dtype=float)
    a = (1.0 - prob) / 2.0
    return chi2_ppf(a, d), chi2_ppf(1.0 - a, d)
