"""`make_report`: the one call behind `tpos report` (run directory in, accuracy files and PDF out)."""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.report.accuracy import Accuracy, compute_accuracy
from tpos_cli.report.health import Health, filter_health
from tpos_cli.report.rundir import RunData, load_run
from tpos_cli.report.truth import ReportTruth, choose_truth, resolve_session_path

OUTPUTS = ("accuracy.parquet", "accuracy.json", "report.pdf")


@dataclass(frozen=True)
class ReportResult:
    run_dir: Path
    summary: dict  # what accuracy.json holds
    accuracy: Accuracy
    health: Health
    truth: ReportTruth
    outputs: tuple[str, ...]
    pages: tuple[str, ...]  # PDF page kinds in order (empty without a PDF)


def _clean_json(x):
    """NaN/inf to None and numpy scalars to Python, so accuracy.json is strict JSON."""
    if isinstance(x, dict):
        return {str(k): _clean_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean_json(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean_json(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(float(x)) else None
    return x


def _records(df: pd.DataFrame | None) -> list[dict]:
    return [] if df is None else df.to_dict(orient="records")


def headline(acc: Accuracy) -> list[dict]:
    """One line per solution: the numbers a reader looks for first (all epochs, all targets)."""
    t = acc.table
    out = []
    for sol in dict.fromkeys(t["solution"]):
        d = t[(t["solution"] == sol) & (t["segment"] == "all") & (t["target"].isin(["", "all"]))]
        for target_kind, dd in (("trajectory", d[d["target"] == ""]), ("targets", d[d["target"] == "all"])):
            if dd.empty:
                continue
            q = dd.set_index("quantity")
            row = {"solution": sol, "of": target_kind, "n": int(q.loc["pos_3d_m", "n"])}
            for name, stat in (("pos_3d_m", "rms"), ("pos_h_m", "rms"), ("pos_v_m", "rms"), ("pos_h_m", "p95"), ("pos_3d_m", "max"), ("pos_3d_m", "mean"), ("pos_3d_m", "sd")):
                row[f"{stat}_{name}"] = float(q.loc[name, stat])
            if target_kind == "targets":
                row["cep_m"] = float(q.loc["pos_h_m", "cep"])
                row["ce90_m"] = float(q.loc["pos_h_m", "ce90"])
            for a in ("roll_deg", "pitch_deg", "yaw_deg", "att_deg"):
                if a in q.index:
                    row[f"rms_{a}"] = float(q.loc[a, "rms"])
            out.append(row)
    return out


def build_summary(run: RunData, session, truth: ReportTruth, acc: Accuracy, health: Health) -> dict:
    from tpos_cli import __version__

    s = run.summary
    return _clean_json(
        {
            "run": str(run.path),
            "report_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "tpos_version": __version__,
            "run_tpos_version": s.get("tpos_version"),
            "session": {"path": truth.session_path, "name": session.meta.name, "kind": session.meta.kind},
            "pipeline": s.get("pipeline"),
            "config_sha256": s.get("config_sha256"),
            "truth": {
                "trajectory": None
                if truth.trajectory is None
                else {"source": truth.trajectory.source, "description": truth.trajectory.description},
                "targets": None if truth.targets is None else {"ids": list(truth.targets.ids), "description": truth.targets.description},
            },
            "conventions": "mean/sd of the signed error (population SD), max_abs/p50/p90/p95 of |error|; "
            "position error = solution - truth in NED at the truth point, vertical = up; CEP/CE90 = p50/p90 of horizontal error",
            "gps_outages": run.outage_windows,
            "mask_gps": run.mask_windows,
            "headline": headline(acc),
            "paper_tables": {k: _records(v) for k, v in acc.paper_tables.items()},
            "targets": _records(acc.targets),
            "health": {
                "nis": _records(health.nis),
                "flags": _records(health.flags),
                "disagreement": _records(health.disagreement),
                "run_warnings": list(s.get("warnings") or []),
            },
            "accuracy": _records(acc.table),
        }
    )


def _atomic_write(path: Path, write) -> None:
    """Write through a temporary sibling and rename, so a reader never sees half a file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def make_report(run_dir: Path, truth_session: Path | None = None, *, pdf: bool = True) -> ReportResult:
    """Compare a run with its truth; write accuracy.parquet, accuracy.json and report.pdf into it.

    Raises InvalidInputError (exit 2) when the run, its session or any truth is missing.
    """
    from tpos_cli.session import load_session

    run_dir = Path(run_dir)
    run = load_run(run_dir)
    session = load_session(resolve_session_path(run.summary, run_dir, truth_session))
    truth = choose_truth(
        session,
        withheld_gps=run.withheld_gps,
        mask_windows=run.mask_windows,
        need_targets=run.targets is not None,
        need_trajectory=run.trajectory is not None,
    )
    acc = compute_accuracy(run, truth, kind=session.meta.kind)
    health = filter_health(run)
    summary = build_summary(run, session, truth, acc, health)
    _atomic_write(run_dir / "accuracy.parquet", lambda p: acc.table.to_parquet(p, index=False))
    _atomic_write(run_dir / "accuracy.json", lambda p: p.write_text(json.dumps(summary, indent=1), encoding="utf-8"))
    outputs = ["accuracy.parquet", "accuracy.json"]
    pages: list[str] = []
    if pdf:
        from tpos_cli.report.pdf import write_pdf

        _atomic_write(run_dir / "report.pdf", lambda p: pages.extend(write_pdf(p, run, session, truth, acc, health, summary)))
        outputs.append("report.pdf")
    return ReportResult(run_dir, summary, acc, health, truth, tuple(outputs), tuple(pages))
