"""Write imported tables into a session directory (new, or one being assembled by several imports).

Only the output session is ever written: sources are read, never touched. A table that already
exists in the output is replaced only with `force=True`. `session.toml` is merged: sections the
import knows (e.g. `[imu] axes`, `rate_hz`) are set, every other key already there is kept.
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path

import pandas as pd

from tpos_cli.errors import InvalidInputError

PARQUET_TABLES = ("imu", "truth")  # large tables go to Parquet, the rest to CSV (readable)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"cannot write {v!r} to TOML")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_toml(doc: dict) -> str:
    """Serialize a two-level dict (sections of scalars/arrays, or sub-tables) to TOML text."""
    lines: list[str] = []

    def section(prefix: str, table: dict) -> None:
        scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
        subs = {k: v for k, v in table.items() if isinstance(v, dict)}
        if prefix and (scalars or not subs):
            lines.append(f"[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {_toml_value(v)}")
        if scalars:
            lines.append("")
        for k, v in subs.items():
            section(f"{prefix}.{k}" if prefix else k, v)

    section("", doc)
    return "\n".join(lines).rstrip() + "\n"


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def merge_toml(base: dict, update: dict) -> dict:
    """Recursive merge: `update` wins key by key, sub-tables are merged."""
    out = dict(base)
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge_toml(out[k], v)
        else:
            out[k] = v
    return out


def write_session(out_dir: Path, tables: dict[str, pd.DataFrame], toml_update: dict, *, force: bool = False) -> list[Path]:
    """Add `tables` ({"imu": df, "gps": df, ...}) and `toml_update` to the session at `out_dir`.

    Creates the directory and a `[session]` section (name = directory name, kind = "drive" unless
    given) when needed. Returns the files written. Raises InvalidInputError when a table exists
    and `force` is False.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    toml_path = out_dir / "session.toml"
    doc: dict = {}
    if toml_path.exists():
        try:
            doc = tomllib.loads(toml_path.read_text(encoding="utf-8"))
        except tomllib.TOMLDecodeError as exc:
            raise InvalidInputError(f"{toml_path}: not valid TOML ({exc})") from exc
    for name in tables:
        existing = [p for p in (out_dir / f"{name}.csv", out_dir / f"{name}.parquet") if p.exists()]
        if existing and not force:
            raise InvalidInputError(
                f"{existing[0]}: the session already has a '{name}' table; use --force to replace it"
            )
    doc = merge_toml(doc, toml_update)
    session = doc.setdefault("session", {})
    session.setdefault("name", out_dir.resolve().name)
    session.setdefault("kind", "drive")
    written: list[Path] = []
    for name, df in tables.items():
        for p in (out_dir / f"{name}.csv", out_dir / f"{name}.parquet"):
            if p.exists():
                p.unlink()
        if name in PARQUET_TABLES:
            path = out_dir / f"{name}.parquet"
            tmp = path.with_name(f".{path.name}.tmp")
            df.to_parquet(tmp, index=False)
            os.replace(tmp, path)
        else:
            path = out_dir / f"{name}.csv"
            _atomic_write_bytes(path, df.to_csv(index=False).encode("utf-8"))
        written.append(path)
    # keep [session] first, as in the contract's example
    ordered = {"session": doc.pop("session"), **doc}
    _atomic_write_bytes(toml_path, dumps_toml(ordered).encode("utf-8"))
    written.append(toml_path)
    return written
