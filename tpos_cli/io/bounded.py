"""Bounded reads of input files: regular files only, sizes checked before reading, TOML depth limited.

A FIFO named `imu.csv` would block a read forever, `/dev/zero` never ends, and a sparse file or a
small Parquet file can decode to gigabytes: every input is checked from its metadata (file type,
size, row count) before any byte is decoded, and refused with a one-line `InvalidInputError`
(exit 2) naming the file.
"""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path

from tpos_cli.errors import InvalidInputError

# A contract table larger than this is not a field log (an hour of 100 Hz IMU is about 40 MB of CSV);
# rows are capped so that no table decodes to more than a few GB of float64 columns.
MAX_TABLE_BYTES = 2 << 30
MAX_TABLE_ROWS = 20_000_000
# A contract table has a dozen columns; thousands of them (a 30 MB header) take pandas minutes to set up.
MAX_TABLE_COLUMNS = 1000
# session.toml and pipeline files are a few kB; nesting deeper than this is not metadata.
MAX_TOML_BYTES = 1 << 20
MAX_TOML_DEPTH = 16
# summary.json and batch.json are kB to a few MB.
MAX_JSON_BYTES = 64 << 20
# A receiver or logger file to import is read whole; larger ones are imported in parts (several SRC).
MAX_SOURCE_BYTES = 512 << 20
# A line of a contract table or of a delimited log (numbers, ids, labels) is a few hundred bytes; longer
# is not a log line (a 300 MB line took pandas 1.7 GB to decode); the CSV header's limit too.
MAX_LINE_BYTES = 65536


def regular_file_size(path: Path, what: str, limit: int) -> int:
    """Size of `path` if it is a regular file no larger than `limit` bytes, else InvalidInputError."""
    try:
        st = os.stat(path)  # follows symlinks: a link to /dev/zero is a device
    except OSError as exc:
        raise InvalidInputError(f"{what}: cannot be read ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        kind = "a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) \
            else "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
        raise InvalidInputError(f"{what}: is {kind}; inputs must be regular files")
    if st.st_size > limit:
        raise InvalidInputError(f"{what}: {st.st_size} bytes is more than the {limit}-byte limit for this file")
    return st.st_size


def read_bytes_bounded(path: Path, what: str, limit: int) -> bytes:
    """The bytes of a regular file of at most `limit` bytes (checked before and while reading)."""
    regular_file_size(path, what, limit)
    try:
        with open(path, "rb") as fh:
            data = fh.read(limit + 1)
    except OSError as exc:
        raise InvalidInputError(f"{what}: cannot be read ({exc.strerror})") from None
    if len(data) > limit:
        raise InvalidInputError(f"{what}: more than the {limit}-byte limit for this file")
    return data


def read_source_bytes(path: Path, what: str | None = None, *, text: bool, limit: int = MAX_SOURCE_BYTES) -> bytes:
    """A source file to import: regular, at most `limit` bytes; a text format (`text`) must not start
    with NUL bytes (a sparse or binary file), checked on the first 64 KiB before the whole is read."""
    what = what or str(path)
    if not os.path.lexists(path):
        raise InvalidInputError(f"{what}: file not found")
    regular_file_size(path, what, limit)
    if text:
        try:
            with open(path, "rb") as fh:
                head = fh.read(65536)
        except OSError as exc:
            raise InvalidInputError(f"{what}: cannot be read ({exc.strerror})") from None
        if b"\x00" in head:
            raise InvalidInputError(f"{what}: contains NUL bytes: a binary or sparse file, not text")
    return read_bytes_bounded(path, what, limit)


def read_json_bounded(path: Path, what: str | None = None, limit: int = MAX_JSON_BYTES):
    """A JSON file tpos wrote (summary.json, batch.json), read as untrusted: regular, at most `limit`
    bytes, UTF-8, nested no deeper than the parser's recursion allows; else InvalidInputError."""
    import json

    what = what or str(path)
    data = read_bytes_bounded(path, what, limit)
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise InvalidInputError(f"{what}: not UTF-8 text") from None
    except RecursionError:
        raise InvalidInputError(f"{what}: nested too deeply to be a tpos JSON file") from None
    except ValueError as exc:
        raise InvalidInputError(f"{what}: not readable JSON ({exc})") from None


def toml_depth(value, limit: int = MAX_TOML_DEPTH) -> int:
    """Nesting depth of parsed TOML (tables and arrays), counted without recursion."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        deepest = max(deepest, d)
        if deepest > limit:
            break
        if isinstance(v, dict):
            stack.extend((x, d + 1) for x in v.values())
        elif isinstance(v, list):
            stack.extend((x, d + 1) for x in v)
    return deepest


def parse_toml(text: str, what: str) -> dict:
    """tomllib.loads with a depth limit; every failure is an InvalidInputError naming `what`."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInputError(f"{what}: not valid TOML ({exc})") from None
    except RecursionError:
        raise InvalidInputError(f"{what}: nested too deeply to be metadata (at most {MAX_TOML_DEPTH} levels)") from None
    if toml_depth(doc) > MAX_TOML_DEPTH:
        raise InvalidInputError(f"{what}: nested too deeply to be metadata (at most {MAX_TOML_DEPTH} levels)")
    return doc


def toml_text(data: bytes, what: str) -> str:
    """The text of a TOML file's bytes: UTF-8, a leading byte-order mark (which Windows editors
    write and TOML does not allow) dropped; else InvalidInputError."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InvalidInputError(f"{what}: not UTF-8 text") from None


def read_toml(path: Path, what: str | None = None) -> dict:
    """A small TOML file: regular, at most MAX_TOML_BYTES, UTF-8 (`toml_text`), nested at most
    MAX_TOML_DEPTH levels."""
    what = what or str(path)
    return parse_toml(toml_text(read_bytes_bounded(path, what, MAX_TOML_BYTES), what), what)
