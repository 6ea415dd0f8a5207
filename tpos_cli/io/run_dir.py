"""The run directory: where it goes, what may be replaced, and the atomic write of its files.

Outputs are written into a temporary sibling directory that is renamed into place only when
complete, so a failed or killed run leaves no partial output and an older run is replaced only
by a finished one.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from tpos_cli.errors import InvalidInputError


def default_run_dir(session_name: str, pipeline_name: str) -> Path:
    """`runs/<session directory name>-<pipeline name>` under the current directory."""
    return Path("runs") / f"{session_name}-{pipeline_name}"


def check_run_dir(run_dir: Path, session_dir: Path) -> Path:
    run_dir = run_dir.resolve()
    if run_dir == session_dir or session_dir.is_relative_to(run_dir):
        raise InvalidInputError(f"run directory {run_dir} would overwrite the session's input files; choose another -o")
    if run_dir.exists() and not run_dir.is_dir():
        raise InvalidInputError(f"run directory {run_dir} exists and is not a directory")
    if run_dir.exists() and any(run_dir.iterdir()) and not (run_dir / "summary.json").exists():
        raise InvalidInputError(f"run directory {run_dir} exists and is not a tpos run (no summary.json); refusing to replace it")
    return run_dir


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


def write_parquet(df: pd.DataFrame, path: Path, metadata: Mapping[str, str] | None = None) -> None:
    table = pa.Table.from_pandas(df, preserve_index=False)
    if metadata:
        meta = dict(table.schema.metadata or {})
        meta.update({f"tpos.{k}".encode(): str(v).encode() for k, v in metadata.items()})
        table = table.replace_schema_metadata(meta)
    pq.write_table(table, path)


def remove_stale_partials(out_dir: Path) -> None:
    """Delete the temporary directories of runs into `out_dir` whose process is gone (killed runs)."""
    for p in out_dir.parent.glob(f".{out_dir.name}.tmp-*"):
        pid = p.name.rsplit("-", 1)[-1]
        if pid.isdigit() and not _pid_alive(int(pid)):
            shutil.rmtree(p, ignore_errors=True)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def replace_dir(tmp: Path, out_dir: Path) -> None:
    """Move the finished temporary directory into place, replacing an older run only now."""
    old = None
    if out_dir.exists():
        old = out_dir.parent / f".{out_dir.name}.old-{os.getpid()}"
        out_dir.rename(old)
    tmp.rename(out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
