"""Reading contract tables (CSV or Parquet) with one-line errors naming file, column and row.

Rows are numbered from 1 over the data rows (the CSV header is not a row), so that CSV row r is
line r + 1 of the file. A table is returned as `io.columns.Columns` (numpy arrays by name). pandas
is imported only for a CSV file or a Parquet column of an unusual type: a drive logged to Parquet
is read without it (its import is ~0.15 s CPU of a one-shot `tpos process`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from tpos_cli.errors import InvalidInputError
from tpos_cli.io.bounded import MAX_LINE_BYTES, MAX_TABLE_BYTES, MAX_TABLE_COLUMNS, MAX_TABLE_ROWS, regular_file_size
from tpos_cli.io.columns import Columns

if TYPE_CHECKING:
    import pandas as pd


@dataclass(frozen=True, slots=True)
class Problem:
    """One thing wrong with a session: where, and what."""

    file: str
    message: str
    column: str | None = None
    row: int | None = None

    def __str__(self) -> str:
        where = self.file
        if self.column is not None:
            where += f": column '{self.column}'"
        if self.row is not None:
            where += f", row {self.row}"
        return f"{where}: {self.message}"


def find_table(session_dir: Path, name: str, csv_only: bool = False) -> Path | None:
    """Path of table `name` in a session (`name.csv` or `name.parquet`), None if absent."""
    csv = session_dir / f"{name}.csv"
    parquet = session_dir / f"{name}.parquet"
    for p in (csv,) if csv_only else (csv, parquet):
        if p.is_symlink() and not p.exists():  # not "missing": the user sees the file there
            raise InvalidInputError(f"{session_dir.name}/{p.name}: a link that leads nowhere (a missing file or a loop)",
                                    [Problem(p.name, "a link that leads nowhere (a missing file or a loop)")])
    if not csv_only and csv.exists() and parquet.exists():
        raise InvalidInputError(
            f"{session_dir.name}/{name}.*: both {csv.name} and {parquet.name} exist; keep one",
            [Problem(f"{name}.*", f"both {csv.name} and {parquet.name} exist; keep one")],
        )
    if csv.exists():
        return csv
    if not csv_only and parquet.exists():
        return parquet
    return None


def table_file_name(session_dir: Path | None, name: str) -> str:
    """The file name a message gives for table `name` of a session: `gps.csv` or `gps.parquet` as the
    session holds it, else `name` itself (absent, or a session without a directory)."""
    path = find_table(Path(session_dir), name) if session_dir is not None else None
    return path.name if path is not None else name


SHOWN_CHARS = 60  # a value quoted in a message is cut to this many characters (a 5 MB cell is one line)


def shown(value) -> str:
    """`value` for a one-line message: its repr (plain Python, never numpy's), cut to SHOWN_CHARS."""
    text = repr(value.item() if isinstance(value, np.generic) else value)
    return text if len(text) <= SHOWN_CHARS else f"{text[:SHOWN_CHARS - 12]}... ({len(text)} characters)"


def _fail(path: Path, message: str, column: str | None = None, row: int | None = None):
    p = Problem(path.name, message, column, row)
    raise InvalidInputError(str(p), [p])


def read_table(path: Path, numeric: tuple[str, ...], text: tuple[str, ...] = (), required: tuple[str, ...] = ()) -> Columns:
    """Read a contract table; numeric columns become float64, text columns str (empty for missing).

    Raises InvalidInputError for unreadable files, missing required columns, no data rows, a
    truncated last line, and cells of numeric columns that are not numbers (first such row).
    """
    try:
        regular_file_size(path, path.name, MAX_TABLE_BYTES)
    except InvalidInputError as exc:
        _fail(path, str(exc).split(": ", 1)[1])
    if path.suffix == ".parquet":
        table = _read_parquet(path, set(numeric) | set(text) | set(required), required)
        names, n_rows = table.column_names, table.num_rows
    else:
        table = _read_csv(path, set(numeric) | set(text) | set(required))
        names, n_rows = list(table.columns), len(table)
        _check_required(path, names, required)
    if n_rows == 0:
        _fail(path, "the table has a header but no data rows")
    out = _arrow_columns(table, numeric, text) if isinstance(table, pa.Table) else None
    if out is None:  # CSV, or Parquet columns whose conversion pandas decides (below)
        df = _to_pandas(path, table) if isinstance(table, pa.Table) else table
        out = {}
        for col in numeric:
            if col in names:
                out[col] = _to_float(path, df[col], col)
        for col in text:
            if col in names:
                out[col] = _to_text(df[col])
        del df
    if isinstance(table, pa.Table):
        del table  # pyarrow's memory pool keeps the decoded buffers otherwise (an hour's drive: RSS 497 -> 399 MB after ingest)
        pa.default_memory_pool().release_unused()
    return Columns(out, n_rows)  # the converted columns as they are (no second copy of a 360k-row table)


def _check_required(path: Path, names, required) -> None:
    """Refuse a table without a required column, naming the columns the FILE has (all of them, not
    only those tpos reads: a `speed` column where `speed_mps` is wanted is the user's clue)."""
    missing = [c for c in required if c not in names]
    if missing:
        found = ", ".join(map(str, names)) or "none"
        found = found if len(found) <= 4 * SHOWN_CHARS else f"{found[:4 * SHOWN_CHARS - 4]} ..."
        _fail(path, f"required column is missing (found: {found})", missing[0])


def _arrow_columns(table: pa.Table, numeric, text) -> dict[str, np.ndarray] | None:
    """The wanted columns of a Parquet table as `_to_float`/`_to_text` would give them, straight from
    Arrow, when each has a plain type: a floating or null-free integer column for a number (nulls of
    a float column are NaN: pandas' conversion), a string column for text. None when any column is
    of another type (booleans, decimals, text in a numeric column, ...): pandas converts those, with
    its own errors."""
    out = {}
    for col in numeric:
        if col not in table.column_names:
            continue
        c = table.column(col)
        if not (pa.types.is_floating(c.type) or (pa.types.is_integer(c.type) and c.null_count == 0)):
            return None
        out[col] = _float_column(table, col)
    for col in text:
        if col not in table.column_names:
            continue
        c = table.column(col)
        if not (pa.types.is_string(c.type) or pa.types.is_large_string(c.type)):
            return None
        stripped: dict = {None: ""}  # each distinct value stripped once (an hour of ranges: 4 ids in 144k cells)
        out[col] = np.array([stripped[v] if v in stripped else stripped.setdefault(v, v.strip())
                             for v in c.to_pylist()], dtype=object)
    return out


def _float_column(table: pa.Table, col: str) -> np.ndarray:
    """A numeric column as float64 through Arrow's tensor conversion, batch by batch (nulls: NaN):
    pyarrow's `to_numpy` would import pandas (its conversion shares pandas' code)."""
    parts = [rb.to_tensor(null_to_nan=True, row_major=False).to_numpy()[:, 0] for rb in table.select([col]).to_batches()]
    return (parts[0] if len(parts) == 1 else np.concatenate(parts)).astype(np.float64, copy=False)


def _to_text(s: pd.Series) -> np.ndarray:
    """A text column as an object array of stripped str, "" where the cell is missing.

    A str column (CSV text, Parquet strings: missing is NaN) is factorized, so that only its
    distinct values are stripped (an hour of ranges to four anchors: 144k cells, 4 values);
    other dtypes (numbers, mixed objects, whose 1, 1.0 and True a factorization would merge)
    cell by cell."""
    import pandas as pd

    if isinstance(s.dtype, pd.StringDtype) and s.dtype.na_value is np.nan:
        codes, uniques = pd.factorize(s)
        values = np.array([str(v).strip() for v in uniques] + [""], dtype=object)
        return values[codes]  # code -1 (missing) -> the last value, ""
    return np.array(["" if (v is None or (isinstance(v, float) and np.isnan(v))) else str(v).strip() for v in s], dtype=object)


def _to_float(path: Path, s: pd.Series, col: str) -> np.ndarray:
    import pandas as pd

    if pd.api.types.is_bool_dtype(s.dtype):
        _fail(path, f"boolean values where numbers are required", col, 1)
    if pd.api.types.is_numeric_dtype(s.dtype):
        return s.to_numpy(dtype=np.float64, na_value=np.nan)
    raw = s.astype(object)
    stripped = raw.map(lambda v: v.strip() if isinstance(v, str) else v)
    conv = pd.to_numeric(stripped.replace("", np.nan), errors="coerce")
    bad = conv.isna() & stripped.notna() & (stripped != "")
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        _fail(path, f"{shown(stripped.iloc[i])} is not a number", col, i + 1)
    return conv.to_numpy(dtype=np.float64, na_value=np.nan)


def _read_parquet(path: Path, wanted: set[str], required=()) -> pa.Table:
    """Only the wanted columns, after the row count in the footer and the `required` columns in the
    schema are checked; the pandas metadata (index, dtypes) is ignored: a damaged one cannot matter,
    the columns are all tpos reads."""
    try:
        pf = pq.ParquetFile(path)  # one open for footer, schema and columns (pq.read_table: a dataset, three opens)
    except (pa.ArrowException, OSError, ValueError) as exc:
        _fail(path, f"not a readable Parquet file ({str(exc).splitlines()[0][:160]})")
    with pf:  # closed on every path, the refusals below included
        try:
            meta = pf.metadata
            names = pf.schema_arrow.names
        except (pa.ArrowException, OSError, ValueError) as exc:
            _fail(path, f"not a readable Parquet file ({str(exc).splitlines()[0][:160]})")
        if meta.num_rows > MAX_TABLE_ROWS:
            _fail(path, f"{meta.num_rows} rows is more than the {MAX_TABLE_ROWS}-row limit for a table")
        if meta.num_columns > MAX_TABLE_COLUMNS:
            _fail(path, f"{meta.num_columns} columns: more than {MAX_TABLE_COLUMNS}, not a contract table")
        _check_required(path, names, required)
        columns = [c for c in names if c in wanted]
        repeated = sorted({c for c in columns if columns.count(c) > 1}, key=columns.index)
        if repeated:
            _fail(path, f"the column appears {columns.count(repeated[0])} times in the file; keep one", repeated[0])
        schema = pf.schema_arrow
        for c in columns:
            kind = schema.field(c).type
            if pa.types.is_temporal(kind):  # pandas would give nanoseconds (or dates) where the contract means seconds
                _fail(path, f"the column is of type {kind} (a date/time type); the contract wants numbers "
                      "(t in seconds on the logger clock, text columns as strings)", c, 1)
        try:
            table = pf.read(columns=columns)
        except (pa.ArrowException, OSError, ValueError, TypeError, KeyError) as exc:
            _fail(path, f"not a readable Parquet file ({str(exc).splitlines()[0][:160]})")
    _check_time_precision(path, table)
    return table


# Times are stored to this resolution or better (1 % of a 1 kHz sample interval); float32 holds t = 1000 s to 61 us.
T_RESOLUTION_S = 1e-5


def _check_time_precision(path: Path, table: pa.Table) -> None:
    """A `t` column in a float type too narrow for its values (float32 or float16 far from zero: a
    100 Hz log at t = 1e5 s is stamped to 7.8 ms, every sample moved by up to 40 % of its interval)."""
    if "t" not in table.column_names:
        return
    kind = table.schema.field("t").type
    if not (pa.types.is_float32(kind) or pa.types.is_float16(kind)):
        return
    v = table.column("t").to_numpy(zero_copy_only=False)
    finite = v[np.isfinite(v)]
    if not finite.size:
        return
    i = int(np.argmax(np.abs(finite)))
    resolution = float(np.spacing(np.abs(finite[i])))
    if resolution > T_RESOLUTION_S:
        row = int(np.flatnonzero(np.abs(v) == np.abs(finite[i]))[0]) + 1
        width = "float32" if pa.types.is_float32(kind) else "float16"
        _fail(path, f"{width} holds t = {float(finite[i]):.7g} s only to {resolution:.2g} s; write t as float64 (seconds)",
              "t", row)


def _to_pandas(path: Path, table: pa.Table) -> pd.DataFrame:
    """A Parquet table through pandas (the columns `_arrow_columns` does not convert itself)."""
    try:
        df = table.to_pandas(ignore_metadata=True)
    except (pa.ArrowException, OSError, ValueError, TypeError, KeyError) as exc:
        _fail(path, f"not a readable Parquet file ({str(exc).splitlines()[0][:160]})")
    return df


def _read_csv(path: Path, wanted: set[str] = frozenset()) -> pd.DataFrame:
    """The CSV table, after the checks of its bytes; a `wanted` column named twice in the header is
    refused as in a Parquet file (pandas would rename the second `name.1` and read the first)."""
    import csv

    import pandas as pd

    try:
        with open(path, "rb") as fh:
            head = fh.read(65536)
    except OSError as exc:
        _fail(path, f"cannot be read ({exc.strerror})")
    if not head.strip():
        _fail(path, "the file is empty (no header, no data)")
    if b"\x00" in head:
        _fail(path, "contains NUL bytes: a binary or sparse file, not CSV text")
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not merely a character cut by the 64 KiB window
            _fail(path, "not UTF-8 text (is it a binary or Parquet file named .csv?)")
    if len(head) == 65536 and b"\n" not in head:
        _fail(path, "the header line is longer than 64 KiB: not a contract table")
    if head.split(b"\n", 1)[0].count(b",") + 1 > MAX_TABLE_COLUMNS:
        _fail(path, f"the header has more than {MAX_TABLE_COLUMNS} columns: not a contract table")
    short_row = _scan_csv(path, head.split(b"\n", 1)[0].count(b","))
    header = head.split(b"\n", 1)[0].decode("utf-8", "replace").strip().lstrip("\ufeff")
    if "," not in header:
        for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "pipes")):
            if sep in header:
                _fail(path, f"the header is separated by {name}; the contract requires commas", row=None)
    n_header = len(header.split(","))
    heads = [h.strip() for h in next(csv.reader([header]), [])]
    repeated = [h for h in heads if h in wanted and heads.count(h) > 1]
    if repeated:
        _fail(path, f"the column appears {heads.count(repeated[0])} times in the header; keep one", repeated[0])
    try:
        # index_col=False: a data line with one empty field more than the header (a trailing comma the
        # header lacks) is that trailing comma; pandas' default took the lines' first fields as an index
        # and shifted every column by one (t read from gyro_x: "time goes backwards")
        with warnings.catch_warnings():
            warnings.simplefilter("error", pd.errors.ParserWarning)
            df = pd.read_csv(path, dtype=None, keep_default_na=True, na_values=[""], skipinitialspace=True,
                             encoding="utf-8-sig", index_col=False)
    except pd.errors.ParserWarning:  # the first data line has more fields than the header (not one empty one)
        _fail(path, f"has more fields than the {n_header} the header names (a value with no column)", row=1)
    except pd.errors.ParserError as exc:
        msg = str(exc)
        row = None
        import re

        m = re.search(r"line (\d+), saw (\d+)", msg)
        if m:
            row = int(m.group(1)) - 1
            _fail(path, f"has {m.group(2)} fields where the header has {n_header}", row=row)
        _fail(path, f"cannot be parsed as CSV ({msg.splitlines()[0][:160]})")
    except (UnicodeDecodeError, ValueError) as exc:
        _fail(path, f"cannot be parsed as CSV ({str(exc).splitlines()[0][:160]})")
    df.columns = [str(c).strip() for c in df.columns]
    _check_last_line(path, n_header, len(df))
    if short_row is not None:  # after the last line's check: a cut last line is said as such
        _fail(path, f"has {short_row[1]} fields where the header has {n_header}: a damaged line (its values cannot be "
              "matched to their columns); repair or delete it", row=short_row[0])
    return df


def _scan_csv(path: Path, header_commas: int, chunk_bytes: int = 16 << 20) -> tuple[int, int] | None:
    """One pass over the bytes before pandas decodes them: the line count against MAX_TABLE_ROWS (a
    2 GB file of short lines decodes to many GB of float64), NUL bytes anywhere (a sparse hole after a
    valid start) and lines longer than MAX_LINE_BYTES (a 300 MB line took pandas 1.7 GB to decode),
    each refused with the row where it is. Returns (row, fields) of the first newline-ended data line
    with fewer fields than the header's `header_commas` + 1 (blank lines aside), or None: pandas fills
    the missing fields of such a line with NaN and takes the others for the columns they are not in."""
    import numpy as np

    lines = 0
    since_newline = 0  # bytes of the line still open at the end of the chunks read so far
    open_commas = 0  # commas of that line
    open_text = False  # whether that line has more than blanks
    short: tuple[int, int] | None = None
    try:
        with open(path, "rb") as fh:
            while chunk := fh.read(chunk_bytes):
                nul = chunk.find(b"\x00")
                if nul >= 0:
                    _fail(path, "contains NUL bytes: a binary or sparse file, not CSV text", row=max(lines + chunk.count(b"\n", 0, nul), 1))
                data = np.frombuffer(chunk, dtype=np.uint8)
                ends = np.flatnonzero(data == 10)
                lengths = np.diff(ends, prepend=-1) - 1  # bytes before each newline since the previous one
                commas = np.diff(np.searchsorted(np.flatnonzero(data == 44), ends), prepend=0)  # per line ended here
                if ends.size:
                    commas[0] += open_commas
                if short is None:
                    short = _first_short_line(chunk, ends, commas, header_commas, lines, open_text)
                if ends.size:
                    lengths[0] += since_newline
                    open_commas = int(np.count_nonzero(data[ends[-1] + 1:] == 44))
                    open_text = bool(chunk[int(ends[-1]) + 1:].strip())
                    since_newline = len(chunk) - 1 - int(ends[-1])
                else:
                    since_newline += len(chunk)
                    open_commas += int(np.count_nonzero(data == 44))
                    open_text = open_text or bool(chunk.strip())
                long = np.flatnonzero(lengths > MAX_LINE_BYTES)
                if long.size or since_newline > MAX_LINE_BYTES:
                    row = lines + (int(long[0]) if long.size else ends.size)
                    _fail(path, f"a line longer than {MAX_LINE_BYTES // 1024} KiB: not a row of a contract table", row=max(row, 1))
                lines += ends.size
                if lines > MAX_TABLE_ROWS + 1:
                    _fail(path, f"more than {MAX_TABLE_ROWS} rows, the row limit for a table")
    except OSError as exc:
        _fail(path, f"cannot be read ({exc.strerror})")
    return short


def _first_short_line(chunk: bytes, ends, commas, header_commas: int, lines_before: int,
                      open_text: bool) -> tuple[int, int] | None:
    """(row, fields) of the first data line among those ending at `ends` of `chunk` with fewer commas
    than the header, skipping blank ones (which pandas skips too); rows count from the header's line 0.
    `open_text`: the part of the first line read in earlier chunks has more than blanks."""
    for k in np.flatnonzero(commas < header_commas):
        row = lines_before + int(k)
        start = int(ends[k - 1]) + 1 if k > 0 else 0
        if row == 0 or not (chunk[start:int(ends[k])].strip() or (k == 0 and open_text)):
            continue  # the header itself, or a blank line
        return row, int(commas[k]) + 1
    return None


def _check_last_line(path: Path, n_header: int, n_rows: int) -> None:
    """A log cut off mid-write leaves a last line with fewer fields than the header. The line is
    read backwards from the end in 1 MiB blocks (a 5 MB cell is one field, not a cut line)."""
    if n_rows == 0:
        return
    commas = 0
    with open(path, "rb") as fh:
        end = fh.seek(0, 2)
        pos = max(0, end - 4096)
        fh.seek(pos)
        tail = fh.read().rstrip(b"\r\n \t")
        while b"\n" not in tail and pos > 0:  # the window lies inside the last line: read further back
            commas += tail.count(b",")
            step = min(pos, 1 << 20)
            pos -= step
            fh.seek(pos)
            tail = fh.read(step)
    line = tail.rsplit(b"\n", 1)[-1]
    if not line.strip() and not commas:
        return
    n_fields = line.count(b",") + commas + 1
    if n_fields < n_header:
        _fail(path, f"the last line has {n_fields} fields where the header has {n_header} (truncated file?)", row=n_rows)
