"""The run directory: where it goes, what may be replaced, and the atomic write of its files.

Outputs are written into a temporary sibling directory that is renamed into place only when
complete, so a failed or killed run leaves no partial output and an older run is replaced only
by a finished one. A run claims its directory before the work (`claim_run_dir`): a lock, so that a
second run to the same directory is refused instead of racing on the rename, and a test write, so
that a read-only or full disk is found before minutes of computing. Claims live inside
`run_dir_claims()`, which releases them (the lock file included) however the run ends and turns
an OSError of the writing into a plain message (exit code 1).
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import fcntl
import os
import re
import shutil
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from tpos_cli.errors import InvalidInputError, TposError
from tpos_cli.io.columns import Columns, to_arrow

if TYPE_CHECKING:
    import pandas as pd

# A name that becomes one path component: no separators, no "..", no leading dot, no control characters.
_SAFE_NAME = re.compile(r"^[^/\\\x00-\x1f.][^/\\\x00-\x1f]*$")


def default_run_dir(session_name: str, pipeline_name: str) -> Path:
    """`runs/<session directory name>-<pipeline name>` under the current directory.

    Both names become one directory name, so a name holding a path separator, `..`, a leading dot
    or a control character is refused (InvalidInputError): outputs never leave `runs/`."""
    for what, name in (("session directory", session_name), ("pipeline", pipeline_name)):
        if not _SAFE_NAME.match(name) or ".." in name or len(name) > 200:
            raise InvalidInputError(f"{what} name {name!r} cannot name a run directory (no '/', '\\', '..', leading "
                                    "'.' or control characters); rename it or pass -o")
    return Path("runs") / f"{session_name}-{pipeline_name}"


def check_run_dir(run_dir: Path, session_dir: Path) -> Path:
    run_dir = run_dir.resolve()
    if run_dir == session_dir or session_dir.is_relative_to(run_dir):
        raise InvalidInputError(f"run directory {run_dir} would overwrite the session's input files; choose another -o")
    if run_dir.is_relative_to(session_dir):
        raise InvalidInputError(f"run directory {run_dir} is inside the session directory {session_dir}: outputs never go "
                                "into their input; choose an -o outside it (or run from outside it: runs/ is made there)")
    if run_dir.exists() and not run_dir.is_dir():
        raise InvalidInputError(f"run directory {run_dir} exists and is not a directory")
    if run_dir.exists() and any(run_dir.iterdir()) and not (run_dir / "summary.json").exists():
        raise InvalidInputError(f"run directory {run_dir} exists and is not a tpos run (no summary.json); refusing to replace it")
    return run_dir


def check_session_out(out: Path, *, force: bool, src: Path | None = None) -> None:
    """A directory a command writes a new session into (`tpos simulate OUT`, `tpos calibrate-mag -o
    OUT`): absent or empty, or with `force` an existing session (a directory holding session.toml)
    that holds neither the current directory nor the input session `src`. InvalidInputError
    otherwise: --force replaces a session, never a directory of other files (`tpos simulate drive .
    --force` deleted everything in the current directory). Never inside `src`: outputs never go into
    their input (`tpos calibrate-mag s -o s/cal` wrote a session into the session)."""
    out = Path(out)
    if src is not None and out.resolve().is_relative_to(Path(src).resolve()):
        raise InvalidInputError(f"{out}: inside the input session {src}; outputs never go into their input: "
                                "choose a directory outside it")
    if not os.path.lexists(out):
        return
    if not out.is_dir():
        raise InvalidInputError(f"{out}: exists and is not a directory")
    if not any(out.iterdir()):
        return
    if not force:
        raise InvalidInputError(f"{out}: already exists and is not empty (use --force to replace a session)")
    real = out.resolve()
    if not (real / "session.toml").is_file():
        raise InvalidInputError(f"{out}: is not a tpos session (no session.toml); --force replaces only a session "
                                "directory, never a directory of other files: choose a new directory")
    for what, inner in (("the current directory", Path.cwd()), ("the input session", src)):
        if inner is not None and Path(inner).resolve().is_relative_to(real):
            raise InvalidInputError(f"{out}: holds {what}; --force would delete it: choose another directory")


# summary.json's sections and the JSON types tpos writes them as (`pipeline.process_session`): a file
# of another shape is refused in one line (exit 2) before any code reads into it
# (`report.rundir.load_run`, which `tpos report` and `tpos export` read it through). None stands for
# an absent section.
SUMMARY_TYPES: dict[str, type | tuple[type, ...]] = {
    "tpos_version": str, "created_utc": str, "session": dict, "pipeline": str, "pipeline_file": str, "chain": str,
    "config": dict, "config_sha256": str, "inputs": dict, "mask_gps": list, "gps_outages": list, "imu_gaps": list,
    "timings_s": dict, "counts": dict, "warnings": list, "results": dict, "quality": dict, "outputs": list,
    "accuracy_note": str}
SUMMARY_PART_TYPES: dict[str, dict[str, type | tuple[type, ...]]] = {
    "session": {"path": str, "name": str, "kind": str, "t0": (int, float), "duration_s": (int, float), "imu_samples": int},
    "quality": {"verdict": str, "reasons": list, "checks": dict},
}
_JSON_NAMES = {dict: "an object", list: "a list", str: "text", int: "a number", float: "a number"}


def check_summary_shape(doc, what: str) -> None:
    """A parsed summary.json (`what` names it in messages): an object whose sections (SUMMARY_TYPES,
    and the fields of SUMMARY_PART_TYPES) have the JSON types tpos writes; InvalidInputError naming
    the first that has not."""

    def check(obj, types, where):
        if not isinstance(obj, dict):
            raise InvalidInputError(f"{what}: {where or 'the file'} must be a JSON object, got {type(obj).__name__}")
        for key, want in types.items():
            v = obj.get(key)
            ok = v is None or (isinstance(v, want) and not isinstance(v, bool))
            if not ok:
                name = _JSON_NAMES.get(want if isinstance(want, type) else want[0], "another type")
                raise InvalidInputError(f"{what}: '{where}{key}' must be {name}, got {type(v).__name__}: "
                                        "not a summary.json tpos wrote (reprocess the session)")

    check(doc, SUMMARY_TYPES, "")
    for part, types in SUMMARY_PART_TYPES.items():
        if doc.get(part) is not None:
            check(doc[part], types, f"{part}.")


def json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, (datetime, Path)):
        return str(o)
    if dataclasses.is_dataclass(o):
        return dataclasses.asdict(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_parquet(df: pd.DataFrame | Columns, path: Path, metadata: Mapping[str, str] | None = None) -> None:
    """A table as Parquet with `metadata` as tpos.* schema keys; a DataFrame's file also has pandas'
    own key, a `Columns`' has not (`io.columns.to_arrow`: written without pandas)."""
    table = to_arrow(df) if isinstance(df, Columns) else pa.Table.from_pandas(df, preserve_index=False)
    if metadata:
        meta = dict(table.schema.metadata or {})
        meta.update({f"tpos.{k}".encode(): str(v).encode() for k, v in metadata.items()})
        table = table.replace_schema_metadata(meta)
    # dictionary encoding for the columns that repeat (names, kinds, counts, flags), not for the
    # floats: trying it on them was most of the write time (0.17 of 0.2 s on a ranging hour's
    # trajectory), and they come out smaller without it. The values read back are the same.
    pq.write_table(table, path, use_dictionary=[f.name for f in table.schema if not pa.types.is_floating(f.type)])


def remove_stale_partials(out_dir: Path) -> None:
    """Delete the temporary directories of runs into `out_dir` whose process is gone (killed runs)."""
    for p in out_dir.parent.glob(f".{out_dir.name}.tmp-*"):
        pid = p.name.rsplit("-", 1)[-1]
        if pid.isdigit() and not _pid_alive(int(pid)):
            shutil.rmtree(p, ignore_errors=True)


def remove_leftovers(out_dir: Path) -> None:
    """Delete what killed runs into `out_dir` left beside it: their temporary directories
    (`remove_stale_partials`) and the lock file when no process holds its lock any more."""
    out_dir = Path(out_dir)
    remove_stale_partials(out_dir)
    lock_path = out_dir.parent / f".{out_dir.name}.lock"
    try:
        fd = os.open(lock_path, os.O_RDWR)
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if os.fstat(fd).st_ino == os.stat(lock_path).st_ino:
            os.unlink(lock_path)  # unheld, and still the file at that name: as `_Claim.release` does
    except OSError:  # held by a live run, or gone meanwhile
        pass
    finally:
        os.close(fd)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class RunDirBusy(TposError):
    """Another run is writing the same run directory (exit code 1)."""

    exit_code = 1


@dataclasses.dataclass
class _Claim:
    lock_path: Path
    fd: int
    out_dir: Path

    def release(self) -> None:
        with contextlib.suppress(OSError):
            if os.fstat(self.fd).st_ino == os.stat(self.lock_path).st_ino:
                os.unlink(self.lock_path)  # still holding the lock: nobody else uses this inode now
        os.close(self.fd)


_ACTIVE: contextvars.ContextVar[list | None] = contextvars.ContextVar("tpos_run_dir_claims", default=None)


def _plain(exc: OSError, out_dir: Path) -> TposError:
    where = f" ({exc.filename})" if exc.filename else ""
    # pyarrow's OSError carries no errno: "Error writing bytes to file. Detail: [errno 28] No space left on device"
    m = re.search(r"\[errno (\d+)\]", str(exc)) if exc.strerror is None else None
    why = os.strerror(int(m.group(1))) if m else exc.strerror or exc
    return TposError(f"cannot write the run directory {out_dir}: {why}{where}")


@contextlib.contextmanager
def run_dir_claims():
    """Scope of a run's directory claims: released on exit; an OSError becomes a plain TposError."""
    claims: list[_Claim] = []
    token = _ACTIVE.set(claims)
    try:
        yield
    except OSError as exc:
        # name the directory being written (a library's OSError may carry no file name)
        raise _plain(exc, claims[-1].out_dir if claims else Path(exc.filename or "?").parent) from None
    finally:
        _ACTIVE.reset(token)
        for c in reversed(claims):
            c.release()


def claim_run_dir(out_dir: Path) -> None:
    """Lock `out_dir` for this run and check that its parent can be written, before the work.

    Raises RunDirBusy when another run holds it, TposError (exit 1) when it cannot be written."""
    out_dir = Path(out_dir)
    claims = _ACTIVE.get()
    lock_path = out_dir.parent / f".{out_dir.name}.lock"
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise RunDirBusy(f"another tpos run is writing {out_dir}; wait for it to finish or choose another -o") from None
            try:
                same = os.fstat(fd).st_ino == os.stat(lock_path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # the previous holder removed it as we opened it: take the new one
        claim = _Claim(lock_path, fd, out_dir)
        if claims is None:
            import atexit

            atexit.register(claim.release)
        else:
            claims.append(claim)  # released by run_dir_claims however the run ends
        probe = out_dir.parent / f".{out_dir.name}.probe-{os.getpid()}"
        try:
            with open(probe, "wb") as fh:
                fh.write(b"\0" * 65536)  # a run writes at least this much; a full disk says so now
                fh.flush()
                os.fsync(fh.fileno())
        finally:
            with contextlib.suppress(OSError):
                probe.unlink()
    except OSError as exc:
        raise _plain(exc, out_dir) from None


def replace_dir(tmp: Path, out_dir: Path) -> None:
    """Move the finished temporary directory into place, replacing an older run only now."""
    old = None
    if out_dir.exists():
        old = out_dir.parent / f".{out_dir.name}.old-{os.getpid()}"
        out_dir.rename(old)
    tmp.rename(out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
