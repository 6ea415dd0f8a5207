"""Batch reprocessing: many sessions, one task function, resumable, local processes or a Dask cluster.

`run_session_task(task)` processes one session into `ROOT/<session-name>/` with
`tpos_cli.pipeline.process_session` and never raises for a bad session: the error becomes a row.
It is the only unit of work, submitted unchanged to a local process pool (`jobs`) or to a Dask
distributed scheduler (`scheduler`), so both modes behave the same.

Resumability: a run whose `summary.json` records the same input hashes and the same
`config_sha256` as the session and pipeline now would produce is skipped (unless `force`).
`process_session` writes into a temporary sibling directory and renames it into place only when
complete, so a run killed midway has no `summary.json` in `ROOT/<name>/` and is redone.

The batch record (`batch.json`, `batch.parquet`) has one row per session: status
(`ok`, `skipped`, `failed`), the run's verdict (`summary.json["quality"]["verdict"]`) and warnings,
wall time, per-stage timings, the one-line error, and the numeric results of the chain and its
errors against truth (`truth.*`) when `report` is set.

Re-runs merge into the record: a run that has not changed since the last batch (same sha256 of its
`summary.json`) keeps the figures of its earlier report, so a re-run without `report` does not drop
them and a re-run with `report` does not rebuild it; rows of sessions not named this time are kept
while their run is unchanged (`in_this_batch` false).

Each task has a time limit (`timeout_s`): in a worker process (and with one job, in this process)
an alarm ends the session with exit code 1 at the next Python instruction; a pool whose workers
all stop answering for longer than the limit plus `HARD_GRACE_S` is killed and the sessions it
held are rerun one at a time, each killed if it overruns.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import glob
import hashlib
import json
import math
import multiprocessing
import os
import signal
import socket
import stat
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures import TimeoutError as FutureTimeoutError
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tpos_cli.errors import InvalidInputError, TposError
from tpos_cli.io.bounded import read_json_bounded, read_toml
from tpos_cli.io.run_dir import remove_leftovers

STATUS_OK = "ok"
STATUS_SKIPPED = "skipped"
STATUS_FAILED = "failed"

SUMMARY_FILE = "summary.json"
BATCH_JSON = "batch.json"
BATCH_PARQUET = "batch.parquet"
_GLOB_CHARS = frozenset("*?[")
# A session list is a small text file: a bigger one is not a list (a log passed by mistake).
MAX_LIST_BYTES = 4 << 20
# Default time limit per session (s); 0 or None disables it. Hours of 100 Hz IMU take minutes.
DEFAULT_TIMEOUT_S = 7200.0
# How long past its time limit a silent pool is given before its workers are killed.
HARD_GRACE_S = 60.0
# How long a killed pool's manager thread is waited for (it joins the terminated workers; a bound, not a pause).
MANAGER_JOIN_S = 10.0
# The earlier batch.json is read only up to this size (it holds one row per session).
MAX_RECORD_BYTES = 256 << 20

ProcessFn = Callable[[Path, "str | None", Path], Any]
CurrentFn = Callable[[Path, "str | None", "Mapping[str, Any]"], bool]


@dataclass(frozen=True, slots=True)
class SessionTask:
    """One unit of work: plain data, picklable, the same for the process pool and Dask."""

    session_dir: str  # absolute
    run_dir: str  # absolute: ROOT/<session-name>
    pipeline: str | None = None  # pipeline name or TOML path; None = default for the session kind
    force: bool = False
    report: bool = False
    timeout_s: float | None = None  # time limit of the task, s; None = none
    # This session's row in the root's earlier batch.json (figures of an earlier report), or None.
    previous: Mapping[str, Any] | None = field(default=None, compare=False, hash=False)

    @property
    def name(self) -> str:
        return Path(self.run_dir).name


@dataclass(frozen=True, slots=True)
class SessionResult:
    """What happened to one session (one row of the batch table)."""

    name: str
    session_dir: str
    run_dir: str
    status: str  # ok | skipped | failed
    exit_code: int  # 0 ok/skipped, else the exit code of the error (1 processing, 2 invalid input)
    error: str  # one line, "" when ok
    time_s: float  # wall time of the task, seconds
    started_utc: str
    worker: str  # host:pid that ran the task
    pipeline: str = ""
    kind: str = ""  # the session's kind (summary.json session.kind: target | drive | ranging), "" when unknown
    timings_s: dict[str, float] = field(default_factory=dict)  # per stage, from summary.json
    accuracy: dict[str, float] = field(default_factory=dict)  # with report: chain results and truth.* errors
    report_note: str = ""  # with report: why no accuracy against truth was computed, if it was not
    verdict: str = ""  # summary.json["quality"]["verdict"] (ok | suspect | unreliable), "" when absent
    warnings: tuple[str, ...] = ()  # summary.json["warnings"]: what the run handled or doubts
    quality_reasons: tuple[str, ...] = ()  # summary.json["quality"]["reasons"]
    run_sha256: str = ""  # sha256 of the run's summary.json: which run the figures belong to
    report: str = ""  # "built" now, "reused" (run unchanged), "earlier" (figures of an earlier report), ""
    in_this_batch: bool = True  # False: a row kept from an earlier batch (session not named this time)


@dataclass(frozen=True, slots=True)
class BatchResult:
    """All rows of a batch, in the order of the tasks, and the batch wall time."""

    root: str
    results: tuple[SessionResult, ...]
    wall_time_s: float
    jobs: int
    scheduler: str | None

    def count(self, status: str) -> int:
        return sum(r.status == status for r in self.results)

    @property
    def exit_code(self) -> int:
        """0 when every session is ok or skipped, 1 when any failed."""
        return 1 if self.count(STATUS_FAILED) else 0


# --------------------------------------------------------------------------- planning


def expand_sessions(specs: Sequence[str], cwd: Path | None = None) -> tuple[Path, ...]:
    """Session directories named by globs, directories and list files, in order, without repeats.

    A spec with glob characters matches directories (files it matches, e.g. a README, are ignored);
    a plain directory is a session; a plain file is a list of sessions, one per line (globs allowed,
    `#` comments, paths relative to the list file). Raises `InvalidInputError` for a spec that names
    nothing, so a typo is a usage error (exit 2) rather than an empty batch.
    """
    base = Path.cwd() if cwd is None else cwd
    found: list[Path] = []
    seen: set[Path] = set()

    def add(p: Path) -> None:
        p = p.resolve()
        if p not in seen:
            seen.add(p)
            found.append(p)

    reading: list[Path] = []  # the list files being expanded, outermost first

    def expand(spec: str, rel_to: Path, where: str) -> None:
        spec = spec.strip()
        path = Path(spec).expanduser()
        if not path.is_absolute():
            path = rel_to / path
        if any(c in spec for c in _GLOB_CHARS):
            dirs = sorted(Path(m) for m in glob.glob(str(path)) if Path(m).is_dir())
            if not dirs:
                raise InvalidInputError(f"{where}'{spec}' matches no session directory")
            for d in dirs:
                add(d)
        elif path.is_dir():
            add(path)
        elif path.exists():
            key = path.resolve()
            if key in reading:
                chain = " -> ".join(p.name for p in [*reading, key])
                raise InvalidInputError(f"{where}session list {path.name} includes itself ({chain})")
            for i, line in enumerate(_read_list(path, spec), start=1):
                line = line.split("#", 1)[0].strip()
                if line:
                    reading.append(key)
                    try:
                        expand(line, path.parent, f"{path.name}, line {i}: ")
                    finally:
                        reading.pop()
        else:
            raise InvalidInputError(f"{where}'{spec}': no such session directory or list file")

    for spec in specs:
        expand(spec, base, "")
    if not found:
        raise InvalidInputError("no sessions given")
    return tuple(found)


def _read_list(path: Path, spec: str) -> list[str]:
    """Lines of a session list: a regular UTF-8 text file of bounded size (never a FIFO or device)."""
    try:
        st = path.stat()
    except OSError as exc:
        raise InvalidInputError(f"{spec}: cannot read session list ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InvalidInputError(f"{spec}: a session list must be a regular file (this is a FIFO, device or socket)")
    if st.st_size > MAX_LIST_BYTES:
        raise InvalidInputError(f"{spec}: {st.st_size} bytes is too big for a session list (at most {MAX_LIST_BYTES}); "
                                "is it a log file?")
    try:
        with open(path, "rb") as fh:
            return fh.read(MAX_LIST_BYTES + 1).decode("utf-8").splitlines()
    except OSError as exc:
        raise InvalidInputError(f"{spec}: cannot read session list ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise InvalidInputError(f"{spec}: a session list must be UTF-8 text (one session per line)") from None


def plan_batch(
    sessions: Sequence[Path],
    out_root: Path,
    pipeline: str | None = None,
    *,
    force: bool = False,
    report: bool = False,
    timeout_s: float | None = DEFAULT_TIMEOUT_S,
) -> tuple[SessionTask, ...]:
    """One task per session, run directory `out_root/<session directory name>`.

    A pipeline given as a file path is made absolute (workers may run elsewhere). Each task carries
    its session's row of the root's earlier `batch.json` (to keep the figures of an unchanged run).
    Raises `InvalidInputError` when two sessions share a directory name (their runs would collide),
    when the root lies inside a session (its runs would be written into their input) or the time
    limit is negative or not finite (0 or None: no limit).
    """
    if timeout_s is not None and not (math.isfinite(timeout_s) and timeout_s >= 0):
        raise InvalidInputError(f"--timeout must be a number of seconds >= 0 (0: no limit), got {timeout_s}")
    timeout_s = timeout_s or None
    root = Path(out_root).expanduser().resolve()
    previous = read_batch_record(root)
    if pipeline is not None and (pipeline.endswith(".toml") or Path(pipeline).exists()):
        pipeline = str(Path(pipeline).expanduser().resolve())  # workers may run in another directory
    by_name: dict[str, Path] = {}
    tasks = []
    for s in sessions:
        s = Path(s).resolve()
        if s.name in by_name:
            raise InvalidInputError(
                f"sessions {by_name[s.name]} and {s} share the name '{s.name}': "
                f"both would be written to {root / s.name}"
            )
        by_name[s.name] = s
        if root == s or root.is_relative_to(s):
            raise InvalidInputError(f"--out {out_root}: inside the session directory {s}; outputs never go into their "
                                    "input: choose a directory outside it")
        prev = previous.get(s.name)
        if prev is not None and prev.get("run_dir") != str(root / s.name):
            prev = None
        tasks.append(SessionTask(str(s), str(root / s.name), pipeline, force, report, timeout_s, prev))
    return tuple(tasks)


# --------------------------------------------------------------------------- the task


def _read_summary(run_dir: Path) -> dict | None:
    """The run's summary.json, or None when absent or not a bounded, readable JSON file (a FIFO, a
    deep nest: the session is then processed again)."""
    if not (run_dir / SUMMARY_FILE).exists():
        return None
    try:
        summary = read_json_bounded(run_dir / SUMMARY_FILE)
    except InvalidInputError:
        return None
    return summary if isinstance(summary, dict) else None


def run_is_current(session_dir: Path, pipeline: str | None, summary: Mapping[str, Any]) -> bool:
    """True if `summary` (a finished run's summary.json) is what processing the session now would give:
    the sha256 of every session file now (so an edited or added `gps.csv` counts) equals the recorded
    `inputs`, and the pipeline resolved now (defaults included) has the recorded config hash, under
    the same tpos version.
    """
    from tpos_cli import __version__
    from tpos_cli.config import resolve_pipeline
    from tpos_cli.pipeline import resolve_config
    from tpos_cli.session import session_file_hashes

    if session_file_hashes(session_dir) != summary.get("inputs"):
        return False
    head = read_toml(session_dir / "session.toml", "session.toml").get("session", {})
    kind = head.get("kind") if isinstance(head, dict) else None
    cfg = resolve_config(resolve_pipeline(pipeline, str(kind)))
    return summary.get("tpos_version") == __version__ and summary.get("config_sha256") == cfg.sha256


def finished_summary(task: SessionTask, is_current: CurrentFn | None = None) -> dict | None:
    """The run's `summary.json` if it is a finished, current run of this session, else None.

    Anything that cannot be checked (no or corrupt summary, unreadable session) counts as not
    finished: the session is processed again and fails there with its real message if it is bad.
    """
    summary = _read_summary(Path(task.run_dir))
    if summary is None or not isinstance(summary.get("inputs"), dict):
        return None
    try:
        current = (is_current or run_is_current)(Path(task.session_dir), task.pipeline, summary)
    except (TposError, OSError, ValueError):
        return None
    return summary if current else None


def _flatten_numbers(d: Mapping[str, Any], prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten_numbers(v, key + "."))
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            out[key] = float(v)
    return out


def accuracy_figures(summary: Mapping[str, Any]) -> dict[str, float]:
    """Numeric scalars of `summary["results"]` (the chain's accuracy summary), keys dotted."""
    results = summary.get("results")
    return _flatten_numbers(results) if isinstance(results, Mapping) else {}


def _report(run_dir: Path, summary: Mapping[str, Any]) -> dict:
    """`tpos report` on a finished run (accuracy files and PDF in the run directory) and its headline
    errors against truth as `truth.<solution>.<of>.<statistic>`, beside the chain's own figures.
    No truth, or no run directory, is a note on the row, not a failure of the session."""
    acc = accuracy_figures(summary)
    try:
        from tpos_cli.report.build import headline, make_report

        res = make_report(run_dir)
    except TposError as exc:
        return {"accuracy": acc, "report_note": f"no report: {_one_line(exc)}"}
    for row in headline(res.accuracy):
        for k in ("rms_pos_h_m", "rms_pos_3d_m", "rms_att_deg"):
            if k in row and math.isfinite(row[k]):
                acc[f"truth.{row['solution']}.{row['of']}.{k}"] = float(row[k])
    return {"accuracy": acc}


def _one_line(exc: BaseException) -> str:
    msg = " ".join(str(exc).split())
    if isinstance(exc, TposError):
        return msg or type(exc).__name__
    # not one of ours: a bug or an environment problem; keep the type and where it happened
    tb = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
    return f"{type(exc).__name__}: {msg}{where}"


def _worker_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _now_utc() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _default_process(session_dir: Path, pipeline: str | None, run_dir: Path) -> Any:
    from tpos_cli.pipeline import process_session

    return process_session(session_dir, pipeline, run_dir)


class SessionTimeout(TposError):
    """A session ran past the batch's per-session time limit (exit code 1: processing failure)."""

    exit_code = 1


@contextlib.contextmanager
def _time_limit(seconds: float | None):
    """Raise SessionTimeout in this thread after `seconds` (an interval timer and SIGALRM).

    Only the main thread of a process can take signals: elsewhere (a Dask worker thread) this is a
    no-op. The alarm interrupts blocking system calls (a read that waits forever) and Python code;
    a compiled kernel is interrupted when it returns.
    """
    if not seconds or threading.current_thread() is not threading.main_thread() or not hasattr(signal, "setitimer"):
        yield
        return

    def _expired(signum, frame):
        raise SessionTimeout(f"timed out after {seconds:g} s (batch --timeout)")

    old = signal.signal(signal.SIGALRM, _expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _summary_sha256(run_dir: Path) -> str:
    try:
        return hashlib.sha256((run_dir / SUMMARY_FILE).read_bytes()).hexdigest()
    except OSError:
        return ""


def _session_kind(summary: Mapping[str, Any] | None) -> str:
    head = (summary or {}).get("session")
    kind = head.get("kind") if isinstance(head, Mapping) else None
    return kind if isinstance(kind, str) else ""


def _quality(summary: Mapping[str, Any]) -> tuple[str, tuple[str, ...]]:
    q = summary.get("quality")
    if not isinstance(q, Mapping):
        return "", ()
    verdict = q.get("verdict")
    reasons = q.get("reasons")
    return (str(verdict) if isinstance(verdict, str) else "",
            tuple(str(r) for r in reasons) if isinstance(reasons, (list, tuple)) else ())


def _report_or_reuse(task: SessionTask, run_dir: Path, summary: Mapping[str, Any], run_sha: str) -> dict:
    """The report fields of a row: an earlier report of this very run is kept (with `report`, not
    rebuilt; without, its figures are carried), else `report` builds one now."""
    prev = task.previous or {}
    same_run = bool(run_sha) and prev.get("run_sha256") == run_sha and prev.get("report") in ("built", "reused", "earlier")
    if same_run:
        earlier = {"accuracy": dict(prev.get("accuracy") or {}), "report_note": str(prev.get("report_note") or "")}
        if not task.report:
            return {**earlier, "report": "earlier"}
        if earlier["report_note"] or (run_dir / "accuracy.json").exists():
            return {**earlier, "report": "reused"}
    if not task.report:
        return {}
    return {**_report(run_dir, summary), "report": "built"}


def run_session_task(
    task: SessionTask, process: ProcessFn | None = None, is_current: CurrentFn | None = None
) -> SessionResult:
    """Process one session unless its finished run is current; never raises for a bad session.

    `process(session_dir, pipeline, run_dir)` defaults to `tpos_cli.pipeline.process_session` and
    `is_current` to `run_is_current` (tests pass stand-ins). Errors become the row's one-line `error`; exit code 1 for
    processing errors, time-outs and unexpected exceptions, 2 for invalid input.
    """
    t_start = time.perf_counter()
    started = _now_utc()
    name = task.name
    run_dir = Path(task.run_dir)
    common = dict(name=name, session_dir=task.session_dir, run_dir=task.run_dir, started_utc=started)
    try:
        with _time_limit(task.timeout_s):
            summary = None if task.force else finished_summary(task, is_current)
            status = STATUS_SKIPPED
            if summary is None:
                status = STATUS_OK
                fn = _default_process if process is None else process
                rs = fn(Path(task.session_dir), task.pipeline, run_dir)
                summary = getattr(rs, "summary", None)
                if not isinstance(summary, dict):
                    summary = _read_summary(run_dir) or {}
            run_sha = _summary_sha256(run_dir)
            report_fields = _report_or_reuse(task, run_dir, summary, run_sha)
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:  # one bad session must never stop the others
        return SessionResult(
            **common,
            status=STATUS_FAILED,
            exit_code=int(getattr(exc, "exit_code", 1)),
            error=_one_line(exc),
            time_s=time.perf_counter() - t_start,
            worker=_worker_id(),
            pipeline=str(task.pipeline or ""),
        )
    timings = summary.get("timings_s")
    warnings = summary.get("warnings")
    verdict, reasons = _quality(summary)
    return SessionResult(
        **common,
        status=status,
        exit_code=0,
        error="",
        time_s=time.perf_counter() - t_start,
        worker=_worker_id(),
        pipeline=str(summary.get("pipeline") or task.pipeline or ""),
        kind=_session_kind(summary),
        timings_s=_flatten_numbers(timings) if isinstance(timings, Mapping) else {},
        verdict=verdict,
        warnings=tuple(str(w) for w in warnings) if isinstance(warnings, (list, tuple)) else (),
        quality_reasons=reasons,
        run_sha256=run_sha,
        **report_fields,
    )


def _failed(task: SessionTask, message: str, exit_code: int = 1) -> SessionResult:
    """Row for a task whose worker itself was lost (killed, crashed, out of memory)."""
    return SessionResult(
        name=task.name,
        session_dir=task.session_dir,
        run_dir=task.run_dir,
        status=STATUS_FAILED,
        exit_code=exit_code,
        error=message,
        time_s=float("nan"),
        started_utc="",
        worker="",
        pipeline=str(task.pipeline or ""),
    )


# --------------------------------------------------------------------------- executors


def default_jobs() -> int:
    """Cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


# One worker per core: each worker computes on one thread, or BLAS, OpenMP, numba and Arrow
# thread pools in every worker would compete for the same cores.
_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS", "ARROW_NUM_THREADS",
               "TPOS_THREADS")  # tpos_cli.chains.context.spare_cpu: no helper threads in a worker


@contextlib.contextmanager
def _single_threaded_children():
    """Spawned workers inherit os.environ at start: set the thread limits (unless the user did) meanwhile."""
    added = [k for k in _THREAD_ENV if k not in os.environ]
    os.environ.update(dict.fromkeys(added, "1"))
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)


def _init_worker() -> None:
    # Ctrl-C reaches the whole process group: let the parent alone decide (it cancels and
    # terminates the workers), instead of a traceback from every worker.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # Pay the imports once per worker process, not once per session. numba kernels are compiled
    # with cache=True, so each worker loads them from the on-disk cache on first use.
    try:
        import tpos_cli.pipeline  # noqa: F401
    except ImportError:
        pass  # each task then fails with the import error as its message; the pool must survive


def _worker_ready() -> bool:
    return True


def _kill_workers(ex: ProcessPoolExecutor, wait_s: float = 0.0) -> None:
    """Cancel the queued tasks and terminate the workers; with `wait_s`, wait that long for them to end.
    The pool's manager thread is then joined (up to `MANAGER_JOIN_S`): it reaps the killed workers and
    closes the pool's queues, and shutdown(wait=False) drops it, so the pool's `with` no longer waits
    for it. Left running, it outlived the batch call (a thread alive after `run_batch` returned, which
    turns off `end_process`'s os._exit and broke tests/cli/test_one_shot.py run after tests/test_batch.py)."""
    procs = list((getattr(ex, "_processes", None) or {}).values())  # before shutdown drops them
    manager = getattr(ex, "_executor_manager_thread", None)  # likewise
    ex.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        proc.terminate()
    for proc in procs if wait_s else ():
        proc.join(wait_s)
    if manager is not None:
        manager.join(MANAGER_JOIN_S)


def _run_pool(
    tasks: Sequence[SessionTask], fn: Callable[[SessionTask], SessionResult], jobs: int,
    emit: Callable[[int, SessionResult], None],
) -> None:
    # spawn, not fork: the parent may hold threads (progress bar, Dask) and forking those is unsafe
    ctx = multiprocessing.get_context("spawn")
    lost: list[int] = []
    t_start = time.time()
    limits = [t.timeout_s for t in tasks if t.timeout_s]
    hard_s = max(limits) + HARD_GRACE_S if len(limits) == len(tasks) and limits else None
    with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_init_worker) as ex:
        with _single_threaded_children():  # workers start during submit
            futures = {ex.submit(fn, t): i for i, t in enumerate(tasks)}
        pending = set(futures)
        last_progress = time.monotonic()
        try:
            while pending:
                done, pending = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
                for fut in done:
                    i = futures[fut]
                    try:
                        emit(i, fut.result())
                    except BrokenProcessPool:
                        lost.append(i)
                if done:
                    last_progress = time.monotonic()
                elif hard_s is not None and time.monotonic() - last_progress > hard_s:
                    # every worker is past its own alarm and silent (stuck in compiled code):
                    # kill them; the sessions they held are rerun one at a time below
                    _kill_workers(ex)
                    lost.extend(futures[f] for f in pending)
                    pending = set()
        except KeyboardInterrupt:
            # stop now: drop the queued sessions and end the running ones (their outputs are still
            # in temporary directories, never in place); the next call redoes them. What the killed
            # workers left beside the run directories (lock files, temporaries) goes with them.
            _kill_workers(ex, wait_s=5.0)
            for t in tasks:
                remove_leftovers(Path(t.run_dir))
            raise
    # A worker died (segfault, out of memory, killed): the pool fails every task it still held,
    # without saying which one killed it. Rerun those one at a time in their own process, so the
    # culprit fails alone and the innocent ones complete.
    for i in sorted(lost):
        limit = tasks[i].timeout_s + HARD_GRACE_S if tasks[i].timeout_s else None
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_init_worker) as ex:
            try:
                with _single_threaded_children():
                    ex.submit(_worker_ready).result()  # the limit counts the session, not the worker's start-up
                    fut = ex.submit(fn, tasks[i])
                emit(i, _processed_in_this_batch(fut.result(timeout=limit), t_start))
            except BrokenProcessPool:
                emit(i, _failed(tasks[i], "worker process died (crashed, killed or out of memory)"))
            except FutureTimeoutError:
                _kill_workers(ex)
                emit(i, _failed(tasks[i], f"timed out after {tasks[i].timeout_s:g} s (batch --timeout); worker killed"))


def _processed_in_this_batch(r: SessionResult, t_start: float) -> SessionResult:
    """A lost task may have finished in its worker before the pool broke: its rerun then finds a
    current run and would say `skipped`, but the session was processed by this batch."""
    summary = Path(r.run_dir) / "summary.json"
    if r.status == STATUS_SKIPPED and summary.exists() and summary.stat().st_mtime >= t_start:
        return dataclasses.replace(r, status=STATUS_OK)
    return r


def _run_dask(
    tasks: Sequence[SessionTask], fn: Callable[[SessionTask], SessionResult], address: Any,
    emit: Callable[[int, SessionResult], None],
) -> None:
    try:
        from dask.distributed import Client
        from dask.distributed import as_completed as dask_as_completed
    except ImportError as exc:
        raise InvalidInputError(
            "--scheduler needs dask.distributed: pip install 'tpos[dask]'"
        ) from exc
    try:
        client = Client(address, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise TposError(f"cannot connect to Dask scheduler {address}: {exc}") from exc
    with client:
        # pure=False: a rerun must really run (inputs on disk may have changed), not hit a cache
        futures = client.map(fn, list(tasks), pure=False, key=[f"tpos-batch-{t.name}-{i}" for i, t in enumerate(tasks)])
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in dask_as_completed(futures, loop=client.loop):
            i = index[fut.key]
            try:
                emit(i, fut.result())
            except Exception as exc:  # KilledWorker, lost connection: the task's worker is gone
                emit(i, _failed(tasks[i], f"Dask task lost: {_one_line(exc)}"))


def check_jobs(jobs: int | None) -> None:
    """`--jobs` is at least 1 (None: the default), else invalid usage."""
    if jobs is not None and jobs < 1:
        raise InvalidInputError(f"--jobs must be at least 1, got {jobs}")


def run_batch(
    tasks: Sequence[SessionTask],
    *,
    jobs: int | None = None,
    scheduler: Any = None,
    on_result: Callable[[SessionResult], None] | None = None,
    process: ProcessFn | None = None,
    is_current: CurrentFn | None = None,
) -> BatchResult:
    """Run every task and return all rows; `on_result` sees each row as it completes.

    `scheduler` (a Dask scheduler address) sends the tasks to that cluster; otherwise `jobs`
    worker processes (default: the cores available; 1 runs in this process). `process` replaces
    `process_session` and `is_current` replaces `run_is_current` (for tests); both must be
    picklable (module-level functions) for pools and clusters.
    """
    check_jobs(jobs)
    n_jobs = min(jobs or default_jobs(), max(len(tasks), 1))
    fn = functools.partial(run_session_task, process=process, is_current=is_current)
    results: list[SessionResult | None] = [None] * len(tasks)

    def emit(i: int, r: SessionResult) -> None:
        results[i] = r
        if on_result is not None:
            on_result(r)

    t0 = time.perf_counter()
    if scheduler is not None:
        _run_dask(tasks, fn, scheduler, emit)
    elif n_jobs == 1:
        for i, t in enumerate(tasks):
            emit(i, fn(t))
    else:
        _run_pool(tasks, fn, n_jobs, emit)
    wall = time.perf_counter() - t0
    done = tuple(r if r is not None else _failed(t, "not run") for r, t in zip(results, tasks, strict=True))
    root = str(Path(tasks[0].run_dir).parent) if tasks else ""
    return BatchResult(root, done, wall, n_jobs, None if scheduler is None else str(scheduler))


# --------------------------------------------------------------------------- the batch record


def read_batch_record(root: Path) -> dict[str, dict[str, Any]]:
    """The rows of `root/batch.json` by session name; {} when there is none or it is unreadable
    (a damaged record is rewritten by the next batch, never trusted)."""
    path = Path(root) / BATCH_JSON
    try:
        st = path.stat()
        if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_RECORD_BYTES:
            return {}
        doc = json.loads(path.read_bytes())
    except (OSError, ValueError, RecursionError):
        return {}
    rows = doc.get("sessions") if isinstance(doc, dict) else None
    if not isinstance(rows, list):
        return {}
    return {r["name"]: r for r in rows if isinstance(r, dict) and isinstance(r.get("name"), str)}


def _result_from_row(row: Mapping[str, Any]) -> SessionResult | None:
    """A row of an earlier batch.json as a SessionResult (None if it does not fit the current fields)."""
    kw = {}
    for f in dataclasses.fields(SessionResult):
        if f.name in row:
            v = row[f.name]
            kw[f.name] = tuple(v) if isinstance(v, list) else v
    kw["in_this_batch"] = False
    if kw.get("time_s") is None:
        kw["time_s"] = float("nan")
    try:
        return SessionResult(**kw)
    except TypeError:
        return None


def earlier_rows(root: Path, names: Iterable[str]) -> tuple[SessionResult, ...]:
    """Rows of the earlier record for sessions not in `names` whose run is still there, unchanged."""
    skip = set(names)
    out = []
    for name, row in read_batch_record(root).items():
        if name in skip or row.get("status") == STATUS_FAILED or not row.get("run_sha256"):
            continue
        if _summary_sha256(Path(root) / name) != row["run_sha256"] or row.get("run_dir") != str(Path(root) / name):
            continue
        if "kind" not in row:  # a record written before rows had it: the run (unchanged) says
            row = {**row, "kind": _session_kind(_read_summary(Path(root) / name))}
        r = _result_from_row(row)
        if r is not None:
            out.append(r)
    return tuple(out)


def batch_rows(results: Iterable[SessionResult]) -> list[dict[str, Any]]:
    """Flat rows: fixed columns, then `timing.<stage>_s`-style and `acc.<key>` columns."""
    rows = []
    for r in results:
        row = {k: v for k, v in asdict(r).items() if k not in ("timings_s", "accuracy")}
        row["warnings"] = list(r.warnings)
        row["quality_reasons"] = list(r.quality_reasons)
        row["n_warnings"] = len(r.warnings)
        row.update({f"timing.{k}": v for k, v in r.timings_s.items()})
        row.update({f"acc.{k}": v for k, v in r.accuracy.items()})
        rows.append(row)
    return rows


def _json_safe(x: Any) -> Any:
    # NaN/inf are not JSON (lost tasks have no time): write null
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    return x


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def write_batch_record(batch: BatchResult, *, pipeline: str | None = None) -> tuple[Path, Path]:
    """Write `ROOT/batch.json` and `ROOT/batch.parquet` (each replaced atomically); return both paths.

    The rows are this batch's, then the earlier record's rows of sessions not in this batch whose
    run is unchanged (`in_this_batch` false); `counts` and `exit_code` are this batch's."""
    import pandas as pd

    from tpos_cli import __version__

    root = Path(batch.root)
    root.mkdir(parents=True, exist_ok=True)
    rows = batch.results + earlier_rows(root, (r.name for r in batch.results))
    doc = {
        "tpos_version": __version__,
        "created_utc": _now_utc(),
        "pipeline": pipeline,
        "jobs": batch.jobs,
        "scheduler": batch.scheduler,
        "wall_time_s": batch.wall_time_s,
        "counts": {s: batch.count(s) for s in (STATUS_OK, STATUS_SKIPPED, STATUS_FAILED)},
        "exit_code": batch.exit_code,
        "sessions": [asdict(r) for r in rows],
    }
    text = json.dumps(_json_safe(doc), indent=2, allow_nan=False)
    json_path = root / BATCH_JSON
    _atomic_write_bytes(json_path, (text + "\n").encode("utf-8"))

    df = pd.DataFrame(batch_rows(rows))
    if df.empty:
        df = pd.DataFrame({k: pd.Series(dtype=object) for k in SessionResult.__slots__ if k not in ("timings_s", "accuracy")})
    pq_path = root / BATCH_PARQUET
    tmp = pq_path.with_name(f".{pq_path.name}.tmp-{os.getpid()}")
    df.to_parquet(tmp, index=False)
    os.replace(tmp, pq_path)
    return json_path, pq_path


def _as_written(names) -> list[str]:
    return list(dict.fromkeys(names))


def headline_errors(r: SessionResult, rank: Callable = _as_written) -> tuple[str, float | None, float | None]:
    """(solution, position error m, attitude error deg) against truth for the console table.

    From the row's `truth.<solution>.<trajectory|targets>.<statistic>` figures: the first solution
    in `rank`'s order (the CLI passes `tpos_cli.report.solutions.rank_solutions`, best first); the
    position error is the 3-D RMS of the targets when the run has targets, else the horizontal RMS of
    the trajectory, except for a target session's fixed observer (`r.kind` "target": its trajectory is
    an attitude at a point it was given: None, as `tpos report` leaves it out, whatever the pipeline
    is called); the attitude error is the RMS of the trajectory's attitude. ("", None, None) without
    figures."""
    rank_solutions = rank
    figures: dict[tuple[str, str, str], float] = {}
    for key, v in r.accuracy.items():
        parts = key.split(".")
        if len(parts) >= 4 and parts[0] == "truth":
            figures[(".".join(parts[1:-2]), parts[-2], parts[-1])] = v
    if not figures:
        return "", None, None
    has_targets = any(of == "targets" for _, of, _ in figures)
    pos_key = ("targets", "rms_pos_3d_m") if has_targets else ("trajectory", "rms_pos_h_m")
    sols = [s for s in rank_solutions(sol for sol, _, _ in figures) if (s, *pos_key) in figures]
    if not sols:
        return "", None, None
    sol = sols[0]
    fixed_observer = not has_targets and r.kind == "target"
    return sol, None if fixed_observer else figures[(sol, *pos_key)], figures.get((sol, "trajectory", "rms_att_deg"))


# The console table: (header, width, right-aligned). 79 characters with the separating spaces.
TABLE_COLUMNS = (("session", 21, False), ("status", 7, False), ("verdict", 10, False), ("pos m", 7, True),
                 ("att deg", 7, True), ("solution", 9, False), ("warn", 4, True), ("time s", 7, True))
TABLE_LEGEND = ("pos m, att deg: RMS errors against truth of the best solution (--report);\n"
                "pos is 3-D for targets, horizontal for a trajectory. warn: the run's warnings.\n"
                "Every row, warning and figure: OUT/batch.json and OUT/batch.parquet.")


def _cell(text: str, width: int, right: bool) -> str:
    if len(text) > width:  # keep both ends of a long session name: dates and suffixes differ there
        head = (width - 2) // 2
        text = text[:head] + ".." + text[len(text) - (width - 2 - head):]
    return text.rjust(width) if right else text.ljust(width)


def format_table(results: Iterable[SessionResult], rank: Callable = _as_written) -> list[str]:
    """The final table a person reads in 80 columns: one line per session (`rank` orders solutions,
    best first: see headline_errors)."""
    def num(v: float | None, fmt: str) -> str:
        return "-" if v is None or not math.isfinite(v) else format(v, fmt)

    lines = [" ".join(_cell(h, w, right) for h, w, right in TABLE_COLUMNS).rstrip()]
    for r in results:
        sol, pos, att = headline_errors(r, rank)
        cells = (r.name, r.status, r.verdict or "-", num(pos, ".3g"), num(att, ".3g"), sol or "-",
                 str(len(r.warnings)), num(r.time_s, ".1f"))
        lines.append(" ".join(_cell(c, w, right) for c, (_, w, right) in zip(cells, TABLE_COLUMNS)).rstrip())
    return lines
