"""Running a pipeline on a session: the one place where stages are wired and outputs written.

`process_session` loads and validates the session, applies `--mask-gps` windows, runs the chain the
pipeline file names (looked up in the fixed registry `CHAINS`), and writes the run directory
atomically: everything goes to a temporary sibling directory that is renamed into place only when
complete, so a failed or killed run leaves no partial output.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from tpos_cli import __version__, conventions, schema, timebase
from tpos_cli.advice import review
from tpos_cli.chains.context import ChainOutput, RunContext, spare_cpu, warm_numba
from tpos_cli.config import ResolvedConfig, Section, resolve_config, resolve_pipeline
from tpos_cli.errors import InvalidInputError, ProcessingError, TposError
from tpos_cli.io.bounded import read_toml
from tpos_cli.io.columns import Columns
from tpos_cli.io.run_dir import (
    check_run_dir,
    claim_run_dir,
    default_run_dir,
    json_default,
    remove_stale_partials,
    replace_dir,
    run_dir_claims,
    write_parquet,
)
from tpos_cli.session import GpsData, Session, load_session

# Chain name (as written in a pipeline file) -> the module whose `run(session, params, ctx)` it runs.
# A fixed table: a pipeline file can only choose among these keys, and nothing it names is imported;
# only the chain of the run is imported (a drive does not pay the ranging chain's imports). The model
# of each chain's parameter table is `tpos_cli.config.SECTIONS[name]`.
CHAINS: dict[str, str] = {
    "ingest": "tpos_cli.chains.ingest",
    "target_fkf": "tpos_cli.chains.target_fkf",
    "drive_smooth": "tpos_cli.chains.drive_smooth",
    "ranging_fatci": "tpos_cli.chains.ranging_fatci",
}


def chain_needs_gps(chain: str, session: Session) -> bool:
    """Whether `chain` cannot run on `session` without a GPS position fix: the drive filter always,
    the target chain when session.toml gives no [observer] position (`target_fkf.observer_position`)."""
    return chain == "drive_smooth" or (chain == "target_fkf" and session.meta.observer_lla is None)


def chain_runner(chain: str) -> Callable[[Session, Section, RunContext], ChainOutput]:
    """The `run` function of a chain of the fixed table CHAINS (KeyError for any other name)."""
    return importlib.import_module(CHAINS[chain]).run


def _beside(first: Callable, fn: Callable, *args):
    """(first(), fn(*args)): with a spare CPU fn runs in a helper thread meanwhile (it must not
    touch what `first` does), else after it."""
    if not spare_cpu():
        return first(), fn(*args)
    with ThreadPoolExecutor(1, thread_name_prefix="tpos-pipeline") as helper:
        job = helper.submit(fn, *args)
        return first(), job.result()


ACCURACY_NOTE = (
    "A zero exit code means processing completed; it is not a claim of accuracy. "
    "Check the filter-health figures here and run `tpos report` against truth."
)


@dataclass(frozen=True)
class RunSummary:
    run_dir: Path
    summary: dict


def mask_gps(session: Session, windows_s: Sequence[tuple[float, float]], *,
             gps_needed: bool = False) -> tuple[Session, Columns | None]:
    """Withhold GPS fixes inside windows given on the logger clock; returns (session, withheld rows).
    `gps_needed` (the chain cannot run without a fix, `chain_needs_gps`): windows that withhold every
    position fix are refused, naming the windows (the chain's own message would blame the gps file)."""
    if not windows_s:
        return session, None
    if session.gps is None:
        raise InvalidInputError(f"--mask-gps: session {session.meta.name!r} has no gps file")
    for a, b in windows_s:
        if not b > a:
            raise InvalidInputError(f"--mask-gps {a}:{b}: the end must be after the start")
    g = session.gps
    rel = np.array(windows_s, dtype=float) - session.t0_s
    for (a, b), (ra, rb) in zip(windows_s, rel):
        if not np.any((g.t_s >= ra) & (g.t_s < rb)):
            # a window on the wrong clock (seconds from the start on a log stamped in GPS seconds
            # of the week) would withhold nothing and the run would look like a successful test
            raise InvalidInputError(
                f"--mask-gps {a:g}:{b:g}: no GPS fix in that window; the fixes span {g.t_s[0] + session.t0_s:.3f} to "
                f"{g.t_s[-1] + session.t0_s:.3f} s on the logger clock (the clock of the files' t column)")
    held = timebase.in_intervals(g.t_s, rel)
    keep = ~held
    n_fix = int(g.valid.sum())
    if gps_needed and n_fix and not (g.valid & keep).any():
        given = " ".join(f"--mask-gps {a:g}:{b:g}" for a, b in windows_s)
        raise InvalidInputError(f"{given}: withholds all {n_fix} GPS fixes; keep some outside the windows")

    def sub(m):
        return GpsData(t_s=g.t_s[m], lla=g.lla[m], fix=g.fix[m], nsat=g.nsat[m], hdop=g.hdop[m],
                       vel_ned_mps=g.vel_ned_mps[m], sigma_neu_m=g.sigma_neu_m[m])

    withheld = gps_table(sub(held), session.t0_s)
    kept = sub(keep)
    outages = timebase.gps_outages(kept.t_s[kept.valid], 0.0, session.t_end_s)
    counts = dict(session.counts, gps_withheld_fixes=int(held.sum()))
    return dataclasses.replace(session, gps=kept, gps_outages_s=outages, counts=counts), withheld


def gps_table(g: GpsData, t0_s: float) -> Columns:
    """GPS rows as a contract `gps` table on the logger clock."""
    return Columns({
        "t": g.t_s + t0_s, "lat": g.lla[:, 0], "lon": g.lla[:, 1], "h": g.lla[:, 2], "fix": g.fix,
        "nsat": g.nsat, "hdop": g.hdop, "vn": g.vel_ned_mps[:, 0], "ve": g.vel_ned_mps[:, 1],
        "vd": g.vel_ned_mps[:, 2], "sigma_n": g.sigma_neu_m[:, 0], "sigma_e": g.sigma_neu_m[:, 1],
        "sigma_u": g.sigma_neu_m[:, 2],
    })


def _resolve_before_reading(session_dir, pipeline, overrides) -> ResolvedConfig | None:
    """The validated pipeline before the session's data is read: a named pipeline directly, the
    default one through the `kind` in session.toml. None when session.toml cannot tell (then the
    session's own loading reports what is wrong with it first)."""
    if pipeline is not None:
        return resolve_config(resolve_pipeline(pipeline, ""), overrides)
    try:  # bounded: a FIFO or a deep nest is refused at the door, never read
        head = read_toml(Path(session_dir) / "session.toml", "session.toml").get("session", {})
    except InvalidInputError:
        return None
    kind = head.get("kind") if isinstance(head, dict) else None
    # a kind the contract does not know: the loader names the valid ones (no pipeline would help)
    return resolve_config(resolve_pipeline(None, kind), overrides) if kind in schema.SESSION_KINDS else None


def check_imu_gaps(session: Session, section: str, gap_max_s: float | None) -> None:
    """InvalidInputError (exit 2, before the work) for an IMU gap longer than `[section] imu_gap_max_s`:
    the gyro and accelerometer did not record the motion during it, so no attitude or position after
    it can be honest (a drive with an hour-long gap: a track 1.5 km off with 0.6 m sigmas); the user
    splits the log. No limit (None) for chains that do not integrate the IMU."""
    gaps = np.asarray(session.imu_gaps_s, dtype=float).reshape(-1, 2)
    if gap_max_s is None or gaps.size == 0:
        return
    length = gaps[:, 1] - gaps[:, 0]
    k = int(np.argmax(length))
    if length[k] > gap_max_s:
        row = int(np.searchsorted(session.imu.t_s, gaps[k, 0], side="right"))
        raise InvalidInputError(
            f"imu: a gap of {length[k]:.1f} s after sample {row} (t = {gaps[k, 0] + session.t0_s:.3f} s); the attitude "
            f"cannot be carried across an IMU gap longer than {section}.imu_gap_max_s = {gap_max_s:g} s: split the log at the gap")


def process_session(
    session_dir: str | Path,
    pipeline: str | Path | None = None,
    run_dir: str | Path | None = None,
    *,
    mask_gps_windows: Sequence[tuple[float, float]] = (),
    overrides: Mapping[str, object] | None = None,
    progress: bool = False,
) -> RunSummary:
    """Process one session with one pipeline into a run directory (see docs/architecture.md)."""
    ctx = RunContext(progress=progress)
    warm = warm_numba()  # with a spare CPU: numba's set-up while the session is read
    try:
        with ctx.live(f"tpos process {Path(session_dir).name}"), run_dir_claims():
            return _process(ctx, session_dir, pipeline, run_dir, mask_gps_windows, overrides)
    finally:
        if warm is not None:
            warm.join()


def _process(ctx: RunContext, session_dir, pipeline, run_dir, mask_gps_windows, overrides) -> RunSummary:
    t_start = time.perf_counter()
    # the configuration first: a bad key or value is refused before any data is read
    cfg = _resolve_before_reading(session_dir, pipeline, overrides)
    with ctx.stage("ingest"):
        session = load_session(session_dir, with_truth=False)  # reports read the truth, processing never does
    if cfg is None:
        cfg = resolve_config(resolve_pipeline(pipeline, session.meta.kind), overrides)
    pipe = cfg.pipeline
    if pipe.kinds and session.meta.kind not in pipe.kinds:
        # allowed (a drive log's attitude alone, say), but a mistaken -p reads as a bad log otherwise
        ctx.warn(f"pipeline {pipe.name} is made for sessions of kind {' or '.join(pipe.kinds)}; this session is of kind "
                 f"{session.meta.kind!r}: its figures and verdict read it as one (leave out -p for its default)")
    check_imu_gaps(session, pipe.chain, getattr(cfg.params, "imu_gap_max_s", None))
    out_dir = check_run_dir(Path(run_dir) if run_dir is not None else default_run_dir(session.path.name, pipe.name), session.path)
    claim_run_dir(out_dir)  # lock it and try a write now, not after the work (io.run_dir)
    with ctx.stage("time_alignment"):
        session, withheld = mask_gps(session, list(mask_gps_windows), gps_needed=chain_needs_gps(pipe.chain, session))
    with ctx.stage("conventions"):  # units, axes, signs; a unit the contract forbids is refused before the work
        # with a spare CPU the checks (numpy over the whole log) run beside the import of the chain's modules
        run, findings = _beside(lambda: chain_runner(pipe.chain), conventions.session_findings, session)
        conventions.refuse_contract_errors(session, findings)
    try:
        result: ChainOutput = run(session, cfg.params, ctx)
    except TposError:
        raise
    except (np.linalg.LinAlgError, FloatingPointError, ValueError, ZeroDivisionError) as exc:
        raise ProcessingError(f"{pipe.name} failed on {session.meta.name}: {type(exc).__name__}: {exc}") from exc

    result.summary.pop("config", None)  # the chain's own echo of its parameters: cfg.resolved is the record
    with ctx.stage("quality"):  # the verdict (tpos_cli.quality); candidate fixes re-run the chain on a window
        verdict = review(session, result, chain=pipe.chain, config=cfg.resolved, params=cfg.params, run=run,
                         counts={**session.counts, **ctx.counts}, session_findings=findings)
    resolved, chash = cfg.resolved, cfg.sha256
    meta = {"version": __version__, "pipeline": pipe.name, "config_sha256": chash, "session": session.meta.name}
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_partials(out_dir)
    tmp = out_dir.parent / f".{out_dir.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        with ctx.stage("write_outputs"):
            outputs = []
            if result.trajectory is not None:
                write_parquet(result.trajectory, tmp / "trajectory.parquet", meta)
                outputs.append("trajectory.parquet")
            if result.targets is not None:
                write_parquet(result.targets, tmp / "targets.parquet", meta)
                outputs.append("targets.parquet")
            for name, df in result.tables.items():
                write_parquet(df, tmp / f"{name}.parquet", meta)
                outputs.append(f"{name}.parquet")
            if withheld is not None:
                write_parquet(withheld, tmp / "withheld_gps.parquet", meta)
                outputs.append("withheld_gps.parquet")
            for name, data in result.files.items():
                (tmp / name).write_bytes(data)
                outputs.append(name)
        ctx.timings_s["total"] = time.perf_counter() - t_start
        summary = {
            "tpos_version": __version__,
            "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "session": {"path": str(session.path), "name": session.meta.name, "kind": session.meta.kind,
                        "t0": session.t0_s, "duration_s": session.t_end_s, "imu_samples": int(len(session.imu.t_s))},
            "pipeline": pipe.name,
            "pipeline_file": str(pipe.path),
            "chain": pipe.chain,
            "config": resolved,
            "config_sha256": chash,
            "inputs": session.file_hashes,
            "mask_gps": [list(w) for w in mask_gps_windows],
            "gps_outages": (session.gps_outages_s + session.t0_s).tolist(),
            "imu_gaps": (session.imu_gaps_s + session.t0_s).tolist(),
            "timings_s": {k: round(v, 4) for k, v in ctx.timings_s.items()},
            "counts": {**session.counts, **ctx.counts},
            "warnings": [*session.warnings, *ctx.warnings],
            "results": result.summary,
            "quality": verdict.as_dict(),
            "outputs": outputs + ["summary.json"],
            "accuracy_note": ACCURACY_NOTE,
        }
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2, default=json_default))
        replace_dir(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return RunSummary(run_dir=out_dir, summary=summary)
