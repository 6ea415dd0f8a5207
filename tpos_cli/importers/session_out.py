"""Write imported tables into a session directory (new, or one being assembled by several imports).

Only the output session is ever written: sources are read, never touched. A table that already
exists in the output is replaced only with `force=True`. `session.toml` is merged with tomlkit:
sections the import knows (e.g. `[imu] axes`, `rate_hz`) are set, every other key, comment, quoted
key, datetime and array of tables already there is kept as written. Everything is checked and the
new `session.toml` text built before the first file is written; each file is replaced atomically.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import pandas as pd
import tomlkit

from tpos_cli.errors import InvalidInputError
from tpos_cli.io.bounded import MAX_TOML_BYTES, parse_toml, read_bytes_bounded, toml_text

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


def _atomic_write(path: Path, write) -> None:
    """`write(tmp)` to a temporary beside `path`, then renamed over it: `path` is whole or unchanged,
    and the temporary never stays behind (a failed write or Ctrl-C removes it)."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    _atomic_write(path, lambda tmp: tmp.write_bytes(data))


def merge_toml(base: dict, update: dict) -> dict:
    """Recursive merge: `update` wins key by key, sub-tables are merged."""
    out = dict(base)
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge_toml(out[k], v)
        else:
            out[k] = v
    return out


def _merge_into(doc, update: dict, where: str) -> None:
    """Set `update`'s keys in the tomlkit container `doc`, recursing into tables; a key the update
    needs as a table but the file has as a value (or the reverse) is refused."""
    for k, v in update.items():
        if isinstance(v, dict):
            if k not in doc:
                doc[k] = tomlkit.table()
            elif not isinstance(doc[k], dict):
                raise InvalidInputError(f"{where}: {k} is a value, not a table ([{k}]); the import needs to add keys to it")
            _merge_into(doc[k], v, where)
        else:
            if k in doc and isinstance(doc[k], dict):
                raise InvalidInputError(f"{where}: {k} is a table; the import needs to set it to a value")
            doc[k] = v


def session_toml_text(toml_path: Path, toml_update: dict, default_name: str) -> str:
    """The new `session.toml`: the existing file (bounded, valid, kept as written) with the
    update merged in, and `[session] name`/`kind` when missing; checked by a re-parse."""
    where = str(toml_path)
    if toml_path.exists():
        text = toml_text(read_bytes_bounded(toml_path, where, MAX_TOML_BYTES), where)
        parse_toml(text, where)
        doc = tomlkit.parse(text)
    else:
        doc = tomlkit.document()
        doc["session"] = tomlkit.table()
    if "session" not in doc:
        doc["session"] = tomlkit.table()
    if not isinstance(doc["session"], dict):
        raise InvalidInputError(f"{where}: session must be a table ([session] with name and kind)")
    _merge_into(doc, toml_update, where)
    doc["session"].setdefault("name", default_name)
    doc["session"].setdefault("kind", "drive")
    try:
        out = tomlkit.dumps(doc)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{where}: the imported keys cannot be written as TOML ({exc})") from None
    parse_toml(out, where)
    return out


def write_session(out_dir: Path, tables: dict[str, pd.DataFrame], toml_update: dict, *, force: bool = False) -> list[Path]:
    """Add `tables` ({"imu": df, "gps": df, ...}) and `toml_update` to the session at `out_dir`.

    Creates the directory and a `[session]` section (name = directory name, kind = "drive" unless
    given) when needed. Returns the files written. Raises InvalidInputError, before writing any
    file, when a table exists and `force` is False or when `session.toml` cannot take the update.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InvalidInputError(f"{out_dir}: exists and is not a session directory")
    toml_path = out_dir / "session.toml"
    if out_dir.is_dir() and not toml_path.exists() and any(out_dir.iterdir()):
        # `-o s/../../../etc` wrote gps.csv and session.toml into /etc (audit, session 10); a raw-data folder
        # would get a session mixed into it
        raise InvalidInputError(f"{out_dir}: holds other files and is not a session (no session.toml): -o must name a "
                                "session, or a new or empty directory")
    for name in tables:
        existing = [p for p in (out_dir / f"{name}.csv", out_dir / f"{name}.parquet") if p.exists()]
        if existing and not force:
            raise InvalidInputError(
                f"{existing[0]}: the session already has a '{name}' table; use --force to replace it"
            )
    toml_text = session_toml_text(toml_path, toml_update, out_dir.resolve().name)
    encoded = {}
    for name, df in tables.items():
        if name not in PARQUET_TABLES:
            encoded[name] = df.to_csv(index=False).encode("utf-8")
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for name, df in tables.items():
        if name in PARQUET_TABLES:
            path = out_dir / f"{name}.parquet"
            _atomic_write(path, lambda tmp, df=df: df.to_parquet(tmp, index=False))
            other = out_dir / f"{name}.csv"
        else:
            path = out_dir / f"{name}.csv"
            _atomic_write_bytes(path, encoded[name])
            other = out_dir / f"{name}.parquet"
        if other.exists():
            other.unlink()  # the table now lives in `path` only
        written.append(path)
    _atomic_write_bytes(toml_path, toml_text.encode("utf-8"))
    written.append(toml_path)
    return written
