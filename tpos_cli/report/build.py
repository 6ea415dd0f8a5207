"""`make_report`: the one call behind `tpos report` (run directory in, accuracy files and PDF out).

Without truth the report is a quality-control report (estimated accuracy, forward/backward
separation, GPS quality, innovations, the run's verdict); with truth it adds the errors against it.
A run whose session files changed since it was processed is refused (see `check_inputs`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow.parquet as pq

from tpos_cli.conventions import output_on_gps_clock
from tpos_cli.errors import InvalidInputError
from tpos_cli.io.columns import Columns, column, is_empty, records, to_arrow_as_pandas
from tpos_cli.report import qc
from tpos_cli.report.accuracy import Accuracy, compute_accuracy
from tpos_cli.report.collector import cyclic_gc_paused
from tpos_cli.report.context import ReportContext, ShotWindows
from tpos_cli.report.files import staged
from tpos_cli.report.health import Health, filter_health
from tpos_cli.report.rundir import RunData, load_run, session_dir_of
from tpos_cli.report.solutions import rank_solutions
from tpos_cli.report.stages import StageClock, timed
from tpos_cli.report.targets import combined_targets
from tpos_cli.report.truth import ReportTruth, choose_truth

if TYPE_CHECKING:
    import pandas as pd

OUTPUTS = ("accuracy.parquet", "accuracy.json", "report.pdf")
REPORT_ONLY_INPUTS = ("truth",)  # session tables only reports read: changing them does not change the run


@dataclass(frozen=True)
class ReportResult:
    run_dir: Path
    summary: dict  # what accuracy.json holds
    accuracy: Accuracy
    health: Health
    truth: ReportTruth | None
    outputs: tuple[str, ...]
    pages: tuple[str, ...]  # PDF page kinds in order (empty without a PDF)
    notes: tuple[str, ...] = ()  # one line each, for the terminal (e.g. inputs not verified)


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


def _records(df: Columns | pd.DataFrame | None) -> list[dict]:
    if df is None:
        return []
    return records(df) if isinstance(df, Columns) else df.to_dict(orient="records")


def headline(acc: Accuracy) -> list[dict]:
    """One line per solution: the numbers a reader looks for first (all targets; all epochs, or where the
    truth holds the GPS fixes the run used only the withheld ones, and no trajectory line when none was
    withheld: agreement with the fixes a run used is not its accuracy, as on page 1)."""
    t = acc.table
    sols, targets, segments, quantities = (t[c].tolist() for c in ("solution", "target", "segment", "quantity"))
    out = []
    for sol in dict.fromkeys(sols):
        for target_kind, of, segment in (("trajectory", "", acc.independent_segment), ("targets", "all", "all")):
            # the rows of this solution's segment (one per quantity) by quantity
            rows = [i for i in range(len(t)) if sols[i] == sol and segments[i] == segment and targets[i] == of]
            if not rows:
                continue
            q = {}
            for i in rows:
                q.setdefault(quantities[i], i)

            def cell(name: str, stat: str, q=q) -> float:
                return t[stat][q[name]]

            row = {"solution": sol, "of": target_kind, "n": int(cell("pos_3d_m", "n"))}
            for name, stat in (
                ("pos_3d_m", "rms"),
                ("pos_h_m", "rms"),
                ("pos_v_m", "rms"),
                ("pos_h_m", "p95"),
                ("pos_3d_m", "max"),
                ("pos_3d_m", "mean"),
                ("pos_3d_m", "sd"),
            ):
                row[f"{stat}_{name}"] = float(cell(name, stat))
            if target_kind == "targets":
                row["cep_m"] = float(cell("pos_h_m", "cep"))
                row["ce90_m"] = float(cell("pos_h_m", "ce90"))
            for a in ("roll_deg", "pitch_deg", "yaw_deg", "att_deg"):
                if a in q:
                    row[f"rms_{a}"] = float(cell(a, "rms"))
            out.append(row)
    return out


def check_inputs(recorded: dict | None, current: dict[str, str], run_name: str) -> list[str]:
    """Compare the session's files with the input hashes recorded when the run was processed.

    Returns the report-only files that changed (truth.*: the run does not depend on them).
    Raises InvalidInputError (exit 2) when a processing input changed, appeared or disappeared: the
    run's solutions would then be reported as if they came from data they were not computed from.
    """
    if not recorded:
        return []

    def report_only(name: str) -> bool:
        return name.partition(".")[0] in REPORT_ONLY_INPUTS

    changed = []
    for name in sorted(set(recorded) | set(current)):
        a, b = recorded.get(name), current.get(name)
        if a == b:
            continue
        if report_only(name):
            changed.append(name)
            continue
        what = "is missing" if b is None else "is new" if a is None else f"changed (sha256 {a[:12]}... when processed, {b[:12]}... now)"
        raise InvalidInputError(
            f"{run_name}: session file {name} {what} since this run was processed; reprocess it (tpos process) before reporting"
        )
    return changed


def _shots(run: RunData, solution: str | None) -> ShotWindows | None:
    tg = run.targets
    if tg is None or solution is None or "t_start" not in tg.columns:
        return None
    d = tg[tg["solution"] == solution]
    t1 = d["t_end"].to_numpy(float) if "t_end" in d.columns else d["t_start"].to_numpy(float)
    return ShotWindows(tuple(d["id"].astype(str)), d["t_start"].to_numpy(float), t1)


def build_summary(ctx: ReportContext) -> dict:
    from tpos_cli import __version__

    s = ctx.run.summary
    sess = ctx.session
    truth = ctx.truth
    return _clean_json(
        {
            "run": str(ctx.run.path),
            "report_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "tpos_version": __version__,
            "run_tpos_version": s.get("tpos_version"),
            "session": {
                "path": str(sess.path) if sess is not None else (s.get("session") or {}).get("path"),
                "name": sess.meta.name if sess is not None else (s.get("session") or {}).get("name"),
                "kind": ctx.kind,
                "inputs_verified": ctx.inputs_note,
            },
            "pipeline": s.get("pipeline"),
            "config_sha256": s.get("config_sha256"),
            "quality": ctx.verdict,
            "truth": None
            if not ctx.has_truth
            else {
                "trajectory": None
                if truth.trajectory is None
                else {"source": truth.trajectory.source, "description": truth.trajectory.description},
                "targets": None if truth.targets is None else {"ids": list(truth.targets.ids), "description": truth.targets.description},
            },
            "conventions": "mean/sd of the signed error (population SD), max_abs/p50/p90/p95 of |error|; "
            "position error = solution - truth in NED at the truth point, vertical = up; CEP/CE90 = p50/p90 of horizontal error; "
            "estimated: h95 = semi-major axis of the stated 95 % horizontal ellipse, v95/yaw95 = 1.96 sigma",
            "gps_outages": ctx.run.outage_windows,
            "mask_gps": ctx.run.mask_windows,
            "best_solution": ctx.best,
            "estimated": _records(ctx.estimated),
            "headline": headline(ctx.acc),
            "paper_tables": {k: _records(v) for k, v in ctx.acc.paper_tables.items()},
            "targets": _records(ctx.acc.targets),
            "targets_combined": {"solution": ctx.target_solution, "rows": _records(ctx.targets)} if ctx.targets is not None else None,
            "health": {
                "nis": _records(ctx.health.nis),
                "flags": _records(ctx.health.flags),
                "disagreement": _records(ctx.health.disagreement),
                "run_warnings": list(s.get("warnings") or []),
            },
            "notes": list(ctx.notes),
            "accuracy": _records(ctx.acc.table),
        }
    )


def _load_session(run: RunData, truth_session: Path | None) -> tuple[object | None, str, str, list[str]]:
    """The session to report with: (session, why its data are not shown, inputs note, notes)."""
    from tpos_cli.session import load_imu, load_session, session_file_hashes

    notes: list[str] = []
    if truth_session is not None:
        p = Path(truth_session)
        if not p.is_dir():
            raise InvalidInputError(f"--truth {truth_session}: not a session directory")
        session = load_session(p)
        same = all(
            session.file_hashes.get(k) == v
            for k, v in (run.summary.get("inputs") or {}).items()
            if k.partition(".")[0] not in REPORT_ONLY_INPUTS
        )
        if same:
            return session, "", "yes (--truth is the processed session)", notes
        notes.append(f"--truth {p.name} is not the session this run was processed from: only its truth is used")
        return session, "the --truth session is not the processed one", "no (--truth session differs)", notes
    sdir = session_dir_of(run.summary, run.path)
    if sdir is None:
        raw = (run.summary.get("session") or {}).get("path")
        notes.append(
            f"session {raw} not found: no truth, GPS or sensor data; give it with --truth SESSION"
            if raw
            else "summary.json names no session: no truth, GPS or sensor data; give it with --truth SESSION"
        )
        return None, "session not found", "no (session not found)", notes
    # A run that recorded its inputs' hashes is checked against them below: its IMU is then the one that
    # was read and checked when it was processed, and only its time column is read here (t0, span); the
    # IMU itself only for the pages that draw it (target: magnetometer; a log at rest: Allan page).
    verifiable = bool(run.summary.get("inputs"))
    try:
        session = load_session(sdir, with_imu=not verifiable)  # records the hashes of its files: they are not hashed twice
    except InvalidInputError:
        check_inputs(run.summary.get("inputs"), session_file_hashes(sdir), run.path.name)  # a changed input explains it
        raise
    changed = check_inputs(run.summary.get("inputs"), session.file_hashes, run.path.name)
    if session.imu is None and session.meta.kind == "target":
        session = replace(session, imu=load_imu(session))
    for name in changed:
        notes.append(f"{name} changed since the run was processed: the report uses the current one")
    if not run.summary.get("inputs"):
        notes.append("summary.json records no input hashes: the session could not be verified")
        return session, "", "no (no input hashes recorded)", notes
    return session, "", "yes", notes


def _truth_apart_in_time(truth: ReportTruth | None, series: dict) -> str | None:
    """Why a reference trajectory cannot score the run: its time span and the run's (logger clock)
    do not overlap, so no epoch has truth. None when they overlap or there is nothing to compare."""
    tt = truth.trajectory if truth is not None else None
    spans = [(float(x.t[0]), float(x.t[-1])) for x in series.values() if x.t.size]
    if tt is None or not tt.t.size or not spans:
        return None
    r0, r1 = min(a for a, _ in spans), max(b for _, b in spans)
    t0, t1 = float(tt.t[0]), float(tt.t[-1])
    if t0 <= r1 and r0 <= t1:
        return None
    return (f"its truth ({tt.description.split(' (')[0]}, {t0:.2f}..{t1:.2f} s) and the run ({r0:.2f}..{r1:.2f} s) do not "
            "overlap in time on the logger clock")


def gps_clock_note(summary: dict, trajectory: Columns | pd.DataFrame | None, solution: str | None = None) -> str | None:
    """A note when the run moved its output to the GPS receiver's clock (`results.gps_clock_offset.
    output_clock` "gps": times t - d, d the estimated IMU-GPS offset) while truth.* is read on the
    session's logger clock, as the contract has it: the two then differ by about v d along the track
    (v the speed), which the errors against truth include. Says how large that is at the run's 95th
    percentile speed (of `solution`'s rows when given), and how to keep the output on the logger's clock."""
    clk = (summary.get("results") or {}).get("gps_clock_offset")
    if not output_on_gps_clock(clk):
        return None
    try:
        d = float(clk["estimate_s"])
    except (KeyError, TypeError, ValueError):
        return None
    v95 = np.nan
    if trajectory is not None and {"vn", "ve"} <= set(trajectory.columns):
        rows = np.ones(len(trajectory), dtype=bool)
        if solution is not None and "solution" in trajectory.columns:
            rows = np.array([str(s) for s in column(trajectory, "solution").tolist()], dtype=object) == solution
        if rows.any():
            v = np.hypot(np.asarray(column(trajectory, "vn"), dtype=float)[rows], np.asarray(column(trajectory, "ve"), dtype=float)[rows])
            v95 = float(np.nanpercentile(v, 95)) if np.isfinite(v).any() else np.nan
    size = f": at the run's 95th-percentile speed, {v95:.1f} m/s, {abs(d) * v95:.2f} m along the track" if np.isfinite(v95) else ""
    return (
        f"the run's output is on the GPS receiver's clock (times moved by the estimated IMU-GPS offset, {d:+.3f} s) "
        f"while truth.* is read on the session's logger clock{size}; right when truth.* is the receiver's own solution "
        "(stamped by its clock), otherwise reprocess with --set drive_smooth.clock_apply_sd=1e9 to keep the output on "
        "the logger's clock"
    )


def build_context(
    run_dir: Path, truth_session: Path | None = None, *, full: bool = False, clock: StageClock | None = None
) -> ReportContext:
    """Everything the report draws, computed once; stages timed on `clock` (loading, accuracy
    tables, filter health, quality figures)."""
    with timed(clock, "load: run"):
        run = load_run(Path(run_dir), frames=False)
    if (run.trajectory is None or is_empty(run.trajectory)) and (run.targets is None or run.targets.empty):
        raise InvalidInputError(
            f"{run.path.name}: nothing to report: the run has no trajectory and no targets (the pipeline wrote no solutions)"
        )
    with timed(clock, "load: session"):
        session, session_note, inputs_note, notes = _load_session(run, truth_session)
    truth = None
    if session is not None:
        with timed(clock, "load: truth"):
            truth = choose_truth(
                session,
                withheld_gps=run.withheld_gps,
                mask_windows=run.mask_windows,
                need_targets=run.targets is not None,
                need_trajectory=run.trajectory is not None,
            )
        if session_note and truth.trajectory is not None and truth.trajectory.source == "gps":
            truth = ReportTruth(None, truth.targets, truth.session_path, truth.notes)  # another session's GPS is no truth
    # the RUN's kind: a --truth session of another kind lends its truth, not its title (audit12: a drive
    # reported with a target session's truth was titled "target survey (static observer)")
    kind = str((run.summary.get("session") or {}).get("kind") or "") or (session.meta.kind if session is not None else "")
    with timed(clock, "load: solutions"):
        series = qc.solution_series(run.trajectory)
        order = rank_solutions(series)
    apart = _truth_apart_in_time(truth, series)
    if apart:
        if truth_session is not None:  # the user named it: the wrong session, or one on another clock
            raise InvalidInputError(f"--truth {Path(truth_session).name}: {apart}; is it the session of this run?")
        notes.append(f"{apart}: no errors against it (a quality-control report)")
        truth = ReportTruth(None, truth.targets, truth.session_path, truth.notes)
    with timed(clock, "accuracy tables"):
        acc = compute_accuracy(run, truth, kind=kind, series=series)
    with timed(clock, "filter health"):
        health = filter_health(run.innovations, series, (run.summary.get("quality") or {}).get("checks"))
    t0 = (run.summary.get("session") or {}).get("t0")  # logger clock of the first IMU sample
    if t0 is not None:
        t_ref = float(t0)
    elif session is not None:
        t_ref = float(session.t0_s)
    else:
        t_ref = float(min(s.t[0] for s in series.values())) if series else 0.0
    targets = target_solution = None
    own_session = session if not session_note else None
    with timed(clock, "quality figures"):
        if run.targets is not None and len(run.targets):
            target_solution = rank_solutions(run.targets["solution"])[0]
            try:
                targets, _ = combined_targets(run, target_solution)
            except InvalidInputError:
                targets = None
        mag_ref = (
            (run.summary.get("results") or {}).get("alignment", {}).get("mag_norm_ut")
            if isinstance((run.summary.get("results") or {}).get("alignment"), dict)
            else None
        )
        gps = qc.gps_quality(own_session) if own_session is not None else None
        mag = qc.magnetic_field(own_session, mag_ref) if own_session is not None and kind == "target" else None
        anchors = qc.anchor_visibility(own_session) if own_session is not None else None
        estimated = qc.estimated_accuracy(series, order)
        shots = _shots(run, target_solution)
    verdict = run.summary.get("quality") if isinstance(run.summary.get("quality"), dict) else None
    if truth is not None and truth.trajectory is not None and truth.trajectory.source == "truth":
        note = gps_clock_note(run.summary, run.trajectory, order[0] if order else None)
        if note:
            notes.append(note)
    return ReportContext(
        run=run,
        session=session,
        session_note=session_note,
        truth=truth,
        acc=acc,
        health=health,
        series=series,
        order=order,
        kind=kind,
        t_ref=t_ref,
        shots=shots,
        targets=targets,
        target_solution=target_solution,
        verdict=verdict,
        gps=gps,
        mag=mag,
        anchors=anchors,
        estimated=estimated,
        full=full,
        inputs_note=inputs_note,
        notes=tuple(notes),
    )


def make_report(
    run_dir: Path, truth_session: Path | None = None, *, pdf: bool = True, full: bool = False, clock: StageClock | None = None
) -> ReportResult:
    """Report on a run (with truth when the session has some); write accuracy.parquet, accuracy.json
    and report.pdf into it, all or none, readable under the umask.

    Raises InvalidInputError (exit 2) when the run is not one, has no solutions, or its session's
    processing inputs changed since it was processed. Stages are timed on `clock` when given.
    """
    with cyclic_gc_paused():
        return _make_report(run_dir, truth_session, pdf=pdf, full=full, clock=clock)


def _make_report(run_dir: Path, truth_session: Path | None, *, pdf: bool, full: bool, clock: StageClock | None) -> ReportResult:
    ctx = build_context(run_dir, truth_session, full=full, clock=clock)
    with timed(clock, "accuracy tables"):
        summary = build_summary(ctx)
    run_dir = ctx.run.path
    names = OUTPUTS if pdf else OUTPUTS[:2]
    pages: list[str] = []
    with staged([run_dir / n for n in names]) as tmp:
        with timed(clock, "accuracy files"):
            # the file `DataFrame.to_parquet(index=False)` wrote, pandas' schema key included, without pandas
            pq.write_table(to_arrow_as_pandas(ctx.acc.table), tmp[run_dir / "accuracy.parquet"])
            tmp[run_dir / "accuracy.json"].write_text(json.dumps(summary, indent=1), encoding="utf-8")
        if pdf:
            from tpos_cli.report.pdf import write_pdf

            pages = write_pdf(tmp[run_dir / "report.pdf"], ctx, summary, clock)
    return ReportResult(run_dir, summary, ctx.acc, ctx.health, ctx.truth, tuple(names), tuple(pages), ctx.notes)
