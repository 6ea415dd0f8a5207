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
(`ok`, `skipped`, `failed`), wall time, per-stage timings, the one-line error, and the numeric
results of the chain (its accuracy summary) when `report` is set.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import glob
import json
import math
import multiprocessing
import os
import signal
import socket
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tpos_cli.errors import InvalidInputError, TposError

STATUS_OK = "ok"
STATUS_SKIPPED = "skipped"
STATUS_FAILED = "failed"

SUMMARY_FILE = "summary.json"
BATCH_JSON = "batch.json"
BATCH_PARQUET = "batch.parquet"
_GLOB_CHARS = frozenset("*?[")

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
    timings_s: dict[str, float] = field(default_factory=dict)  # per stage, from summary.json
    accuracy: dict[str, float] = field(default_factory=dict)  # with report: chain results and truth.* errors
    report_note: str = ""  # with report: why no accuracy against truth was computed, if it was not


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
        elif path.is_file():
            try:
                lines = path.read_text(encoding="utf-8").splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                raise InvalidInputError(f"{spec}: cannot read session list: {exc}") from exc
            for i, line in enumerate(lines, start=1):
                line = line.split("#", 1)[0].strip()
                if line:
                    expand(line, path.parent, f"{path.name}, line {i}: ")
        else:
            raise InvalidInputError(f"{where}'{spec}': no such session directory or list file")

    for spec in specs:
        expand(spec, base, "")
    if not found:
        raise InvalidInputError("no sessions given")
    return tuple(found)


def plan_batch(
    sessions: Sequence[Path],
    out_root: Path,
    pipeline: str | None = None,
    *,
    force: bool = False,
    report: bool = False,
) -> tuple[SessionTask, ...]:
    """One task per session, run directory `out_root/<session directory name>`.

    A pipeline given as a file path is made absolute (workers may run elsewhere). Raises
    `InvalidInputError` when two sessions share a directory name (their runs would collide).
    """
    root = Path(out_root).expanduser().resolve()
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
        tasks.append(SessionTask(str(s), str(root / s.name), pipeline, force, report))
    return tuple(tasks)


# --------------------------------------------------------------------------- the task


def _read_summary(run_dir: Path) -> dict | None:
    try:
        with open(run_dir / SUMMARY_FILE, encoding="utf-8") as f:
            summary = json.load(f)
    except (OSError, ValueError):
        return None
    return summary if isinstance(summary, dict) else None


def run_is_current(session_dir: Path, pipeline: str | None, summary: Mapping[str, Any]) -> bool:
    """True if `summary` (a finished run's summary.json) is what processing the session now would give:
    the sha256 of every session file now (so an edited or added `gps.csv` counts) equals the recorded
    `inputs`, and the pipeline resolved now (defaults included) has the recorded config hash, under
    the same tpos version.
    """
    import tomllib

    from tpos_cli import __version__
    from tpos_cli.config import resolve_pipeline
    from tpos_cli.pipeline import resolve_config
    from tpos_cli.session import session_file_hashes

    if session_file_hashes(session_dir) != summary.get("inputs"):
        return False
    kind = tomllib.loads((session_dir / "session.toml").read_text(encoding="utf-8")).get("session", {}).get("kind")
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
    except (TposError, OSError, ValueError):  # tomllib.TOMLDecodeError is a ValueError
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


def run_session_task(
    task: SessionTask, process: ProcessFn | None = None, is_current: CurrentFn | None = None
) -> SessionResult:
    """Process one session unless its finished run is current; never raises for a bad session.

    `process(session_dir, pipeline, run_dir)` defaults to `tpos_cli.pipeline.process_session` and
    `is_current` to `run_is_current` (tests pass stand-ins). Errors become the row's one-line `error`; exit code 1 for
    processing errors and unexpected exceptions, 2 for invalid input.
    """
    t_start = time.perf_counter()
    started = _now_utc()
    name = task.name
    common = dict(name=name, session_dir=task.session_dir, run_dir=task.run_dir, started_utc=started)
    try:
        summary = None if task.force else finished_summary(task, is_current)
        status = STATUS_SKIPPED
        if summary is None:
            status = STATUS_OK
            fn = _default_process if process is None else process
            rs = fn(Path(task.session_dir), task.pipeline, Path(task.run_dir))
            summary = getattr(rs, "summary", None)
            if not isinstance(summary, dict):
                summary = _read_summary(Path(task.run_dir)) or {}
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
    return SessionResult(
        **common,
        status=status,
        exit_code=0,
        error="",
        time_s=time.perf_counter() - t_start,
        worker=_worker_id(),
        pipeline=str(summary.get("pipeline") or task.pipeline or ""),
        timings_s=_flatten_numbers(timings) if isinstance(timings, Mapping) else {},
        **(_report(Path(task.run_dir), summary) if task.report else {}),
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
_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS", "ARROW_NUM_THREADS")


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


def _run_pool(
    tasks: Sequence[SessionTask], fn: Callable[[SessionTask], SessionResult], jobs: int,
    emit: Callable[[int, SessionResult], None],
) -> None:
    # spawn, not fork: the parent may hold threads (progress bar, Dask) and forking those is unsafe
    ctx = multiprocessing.get_context("spawn")
    lost: list[int] = []
    t_start = time.time()
    with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_init_worker) as ex:
        with _single_threaded_children():  # workers start during submit
            futures = {ex.submit(fn, t): i for i, t in enumerate(tasks)}
        try:
            for fut in as_completed(futures):
                i = futures[fut]
                try:
                    emit(i, fut.result())
                except BrokenProcessPool:
                    lost.append(i)
        except KeyboardInterrupt:
            # stop now: drop the queued sessions and end the running ones (their outputs are still
            # in temporary directories, never in place); the next call redoes them
            procs = list((getattr(ex, "_processes", None) or {}).values())  # before shutdown drops them
            ex.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                proc.terminate()
            raise
    # A worker died (segfault, out of memory, killed): the pool fails every task it still held,
    # without saying which one killed it. Rerun those one at a time in their own process, so the
    # culprit fails alone and the innocent ones complete.
    for i in sorted(lost):
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_init_worker) as ex:
            try:
                with _single_threaded_children():
                    fut = ex.submit(fn, tasks[i])
                emit(i, _processed_in_this_batch(fut.result(), t_start))
            except BrokenProcessPool:
                emit(i, _failed(tasks[i], "worker process died (crashed, killed or out of memory)"))


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
    if jobs is not None and jobs < 1:
        raise InvalidInputError(f"--jobs must be at least 1, got {jobs}")
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


def batch_rows(results: Iterable[SessionResult]) -> list[dict[str, Any]]:
    """Flat rows: fixed columns, then `timing.<stage>_s`-style and `acc.<key>` columns."""
    rows = []
    for r in results:
        row = {k: v for k, v in asdict(r).items() if k not in ("timings_s", "accuracy")}
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
    """Write `ROOT/batch.json` and `ROOT/batch.parquet` (each replaced atomically); return both paths."""
    import pandas as pd

    from tpos_cli import __version__

    root = Path(batch.root)
    root.mkdir(parents=True, exist_ok=True)
    doc = {
        "tpos_version": __version__,
        "created_utc": _now_utc(),
        "pipeline": pipeline,
        "jobs": batch.jobs,
        "scheduler": batch.scheduler,
        "wall_time_s": batch.wall_time_s,
        "counts": {s: batch.count(s) for s in (STATUS_OK, STATUS_SKIPPED, STATUS_FAILED)},
        "exit_code": batch.exit_code,
        "sessions": [asdict(r) for r in batch.results],
    }
    text = json.dumps(_json_safe(doc), indent=2, allow_nan=False)
    json_path = root / BATCH_JSON
    _atomic_write_bytes(json_path, (text + "\n").encode("utf-8"))

    df = pd.DataFrame(batch_rows(batch.results))
    if df.empty:
        df = pd.DataFrame({k: pd.Series(dtype=object) for k in SessionResult.__slots__ if k not in ("timings_s", "accuracy")})
    pq_path = root / BATCH_PARQUET
    tmp = pq_path.with_name(f".{pq_path.name}.tmp-{os.getpid()}")
    df.to_parquet(tmp, index=False)
    os.replace(tmp, pq_path)
    return json_path, pq_path


_KEY_WORDS = ("rms", "cep", "err", "sigma", "sd", "nees")


def key_accuracy_figures(results: Iterable[SessionResult], n: int = 3) -> list[str]:
    """Up to `n` accuracy keys for the console table: error-like keys first, most common first."""
    counts: dict[str, int] = {}
    for r in results:
        for k in r.accuracy:
            counts[k] = counts.get(k, 0) + 1

    def rank(k: str) -> tuple[int, int, str]:
        leaf = k.rsplit(".", 1)[-1].lower()
        return (0 if any(w in leaf for w in _KEY_WORDS) else 1, -counts[k], k)

    return sorted(counts, key=rank)[:n]
