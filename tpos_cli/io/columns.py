"""A table as numpy columns by name (`Columns`), and its Arrow table for a Parquet file.

What `io.tables.read_table` returns and what the drive chain writes (trajectory, innovations): float64,
int64 and bool arrays, text as object arrays of str, all of one length. A one-shot `tpos process` of a
drive never imports pandas (~0.15 s CPU of the process): pyarrow's own numpy conversions (`pa.array`,
`Array.to_numpy`) import it at their first call (pyarrow's pandas shim checks every input for a pandas
object), so `to_arrow` hands numpy's buffers to `pa.Array.from_buffers` in Arrow's documented layout
(values; bit-packed booleans; int64 offsets + UTF-8 bytes for large_string) and `io.tables` reads
numbers through `RecordBatch.to_tensor`. The values are the ones `pa.Table.from_pandas` wrote; the
file has no 'pandas' schema metadata (pandas reads it back to an equal DataFrame).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa

if TYPE_CHECKING:
    import pandas as pd


class Columns:
    """Columns of one length by name. `t[name]` is a read-only array (as pandas' `df[name].to_numpy()`
    gives it); `t.matrix(names)` the (rows, k) float64 array of several columns, column-major as
    `df[names].to_numpy()` gives it (numba kernels' cached signatures see the same arrays)."""

    __slots__ = ("_cols", "_n")

    def __init__(self, cols: Mapping[str, np.ndarray], n_rows: int | None = None) -> None:
        self._cols = dict(cols)
        self._n = n_rows if n_rows is not None else (len(next(iter(self._cols.values()))) if self._cols else 0)

    @property
    def columns(self) -> list[str]:
        return list(self._cols)

    def __len__(self) -> int:
        return self._n

    def __contains__(self, name: object) -> bool:
        return name in self._cols

    def __getitem__(self, name: str) -> np.ndarray:
        v = self._cols[name].view()
        v.flags.writeable = False
        return v

    def matrix(self, names: Iterable[str]) -> np.ndarray:
        return np.stack([self._cols[n] for n in names]).T

    def take(self, rows: np.ndarray) -> Columns:
        """The rows at integer positions or where a boolean mask is True, in that order."""
        return Columns({k: v[rows] for k, v in self._cols.items()})

    def to_pandas(self) -> pd.DataFrame:
        """A DataFrame of the same columns (tests, callers that want pandas)."""
        import pandas as pd

        return pd.DataFrame(self._cols)


def concat(parts: Sequence[Columns]) -> Columns:
    """Rows of `parts` one after the other (every part with the same columns in the same order)."""
    names = parts[0].columns
    return Columns({k: np.concatenate([p._cols[k] for p in parts]) for k in names})


def _string_array(values: np.ndarray) -> pa.Array:
    """large_string from an object array of str: int64 offsets and the UTF-8 bytes. Each distinct value
    is encoded once and its rows found by one comparison (a trajectory's 'solution': 3 names in 10^5
    rows); the bytes are gathered by index, with no Python step per row."""
    distinct = list(set(values.tolist()))
    if not all(isinstance(x, str) for x in distinct):
        raise TypeError("a text column holds something other than str")
    code = np.zeros(values.size, dtype=np.int64)
    for c, u in enumerate(distinct[1:], 1):
        code[values == u] = c
    enc = [u.encode("utf-8") for u in distinct]
    size = np.array([len(e) for e in enc], dtype=np.int64)
    lengths = size[code]
    offsets = np.zeros(values.size + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    start = np.cumsum(size) - size  # of each distinct value's bytes in `encoded`
    encoded = np.frombuffer(b"".join(enc), dtype=np.uint8)
    data = encoded[np.arange(offsets[-1]) - np.repeat(offsets[:-1] - start[code], lengths)]
    return pa.Array.from_buffers(pa.large_string(), values.size, [None, pa.py_buffer(offsets), pa.py_buffer(data)])


def _arrow_array(v: np.ndarray) -> pa.Array:
    """One column in Arrow's layout (no nulls: NaN stays a float value, as from_pandas keeps it)."""
    if v.dtype == np.float64 or v.dtype == np.int64:
        typ = pa.float64() if v.dtype == np.float64 else pa.int64()
        return pa.Array.from_buffers(typ, v.size, [None, pa.py_buffer(np.ascontiguousarray(v))])
    if v.dtype == np.bool_:
        bits = np.packbits(v, bitorder="little")  # Arrow booleans: one bit each, least significant first
        return pa.Array.from_buffers(pa.bool_(), v.size, [None, pa.py_buffer(bits)])
    if v.dtype == object:
        return _string_array(v)
    raise TypeError(f"no Arrow column for dtype {v.dtype}")


def to_arrow(t: Columns) -> pa.Table:
    """The Arrow table of `t`: float64, int64, bool and large_string columns, in `t`'s order."""
    return pa.Table.from_arrays([_arrow_array(np.asarray(t._cols[k])) for k in t.columns], names=t.columns)


def column(t, name: str) -> np.ndarray:
    """Column `name` of a `Columns` or a pandas DataFrame as a numpy array: for the readers of either
    (`quality`, `advice`, `conventions`: the drive chain's tables are `Columns`, other chains' DataFrames)."""
    return t[name] if isinstance(t, Columns) else t[name].to_numpy()


def flags(t, name: str) -> np.ndarray:
    """A boolean column of either kind of table, missing cells False (pandas' `fillna(False)`)."""
    return np.asarray(t[name], dtype=bool) if isinstance(t, Columns) else t[name].fillna(False).to_numpy(bool)


def no_value(v: np.ndarray) -> np.ndarray:
    """Cells of a column with no value (None or NaN), as pandas' `isna`."""
    v = np.asarray(v)
    if v.dtype != object:
        return np.isnan(v) if v.dtype.kind == "f" else np.zeros(v.size, dtype=bool)
    return (v == None) | (v != v)  # noqa: E711 (elementwise: None, or NaN, which equals nothing)


def is_empty(t) -> bool:
    """No rows or no columns (pandas' `DataFrame.empty`), for either kind of table."""
    return len(t) == 0 or len(t.columns) == 0


def as_text(values: np.ndarray) -> np.ndarray:
    """A label column as an object array of str, as pandas' `astype(str)` gives it a run table's labels
    (read as categoricals: a missing one "nan"); a column of str as it is (the distinct values checked)."""
    if values.dtype == object and all(isinstance(x, str) for x in set(values.tolist())):
        return values
    return np.array(["nan" if x is None else str(x) for x in values.tolist()], dtype=object)


def first_appearance_codes(values: np.ndarray) -> tuple[np.ndarray, list]:
    """(code of each row, the distinct values in order of first appearance) of a label column with
    no missing value (pandas' `factorize`): each distinct value found by one comparison over the
    column (a trajectory's 'solution': 3 names in 10^5 rows), no Python step per row."""
    masks = {u: values == u for u in set(values.tolist())}
    names = sorted(masks, key=lambda u: int(np.argmax(masks[u])))
    codes = np.zeros(values.size, dtype=np.int64)
    for k, u in enumerate(names[1:], 1):
        codes[masks[u]] = k
    return codes, names


def groups(a: np.ndarray, b: np.ndarray):
    """((a value, b value), row positions) of each distinct pair, in order of first appearance; pairs
    with a missing value (None, NaN) left out: pandas' `groupby([a, b], sort=False).groups`."""
    keys: dict = {}
    code = np.fromiter((keys.setdefault(k, len(keys)) for k in zip(a.tolist(), b.tolist())), dtype=np.int64, count=len(a))
    for k, c in keys.items():
        if not any(v is None or v != v for v in k):
            yield k, np.flatnonzero(code == c)


def _bits(buf, offset: int, n: int) -> np.ndarray:
    """n booleans of an Arrow bitmap (validity or bool values: least significant bit first) from `offset`."""
    return np.unpackbits(np.frombuffer(buf, dtype=np.uint8), bitorder="little")[offset : offset + n].astype(bool)


def _decoded(d: pa.DictionaryArray) -> np.ndarray:
    """The text of a dictionary array as an object array of str (None where null), each distinct value
    decoded once."""
    n = len(d)
    if n == 0:
        return np.empty(0, dtype=object)
    idx = d.indices
    width = idx.type.bit_width // 8
    kind = "i" if pa.types.is_signed_integer(idx.type) else "u"
    codes = np.frombuffer(idx.buffers()[1], dtype=f"<{kind}{width}")[idx.offset : idx.offset + n].astype(np.int64)
    if idx.null_count:
        codes = np.where(_bits(idx.buffers()[0], idx.offset, n), codes, -1)  # -1: the None after the values
    return np.array([*d.dictionary.to_pylist(), None], dtype=object)[codes]


def _is_text(t: pa.DataType) -> bool:
    return pa.types.is_string(t) or pa.types.is_large_string(t)


def _numpy_column(col: pa.ChunkedArray) -> np.ndarray:
    """One Arrow column as pandas' `to_pandas` gives it for the types tpos writes, without pandas:
    numbers through Arrow's tensor conversion (nulls NaN: an integer column with nulls becomes
    float64), booleans from the bitmap (object with None where null, as pandas has it), text (plain,
    or dictionary-encoded as `ParquetFile(read_dictionary=...)` reads it) as an object array of str
    (None where null), each distinct value decoded once. Other types: pandas."""
    if pa.types.is_dictionary(col.type) and _is_text(col.type.value_type):
        parts = [_decoded(c) for c in col.chunks]  # each row group has its own dictionary
        return parts[0] if len(parts) == 1 else np.concatenate(parts) if parts else np.empty(0, dtype=object)
    a = col.combine_chunks() if col.num_chunks != 1 else col.chunk(0)
    n = len(a)
    if (pa.types.is_floating(a.type) and not pa.types.is_float16(a.type)) or pa.types.is_integer(a.type):
        return pa.RecordBatch.from_arrays([a], ["v"]).to_tensor(null_to_nan=a.null_count > 0, row_major=False).to_numpy()[:, 0]
    if pa.types.is_boolean(a.type):
        validity, values = a.buffers()
        v = _bits(values, a.offset, n) if n else np.zeros(0, dtype=bool)
        if not a.null_count:
            return v
        out = v.astype(object)
        out[~_bits(validity, a.offset, n)] = None
        return out
    if _is_text(a.type):
        import pyarrow.compute as pc  # here: text read without read_dictionary (its import: ~0.06 s)

        return _decoded(pc.dictionary_encode(a))
    return pa.table({"v": a}).to_pandas()["v"].to_numpy()  # a type tpos does not write (an altered file): pandas decides


def from_arrow(table: pa.Table) -> Columns:
    """The columns of an Arrow table by name as numpy arrays (`_numpy_column`), without pandas: the
    values `table.to_pandas()` holds for the float64, int64, bool and string columns tpos writes."""
    return Columns({name: _numpy_column(table.column(i)) for i, name in enumerate(table.column_names)}, table.num_rows)


def _inferred(values: list) -> np.ndarray:
    """A column of Python values with the dtype pandas' DataFrame constructor infers for the kinds a
    report table holds: all booleans bool; all integers int64; numbers (None as NaN) float64; else object."""
    if all(isinstance(v, (bool, np.bool_)) for v in values):
        return np.array(values, dtype=bool)
    if all(isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)) for v in values):
        return np.array(values, dtype=np.int64)
    if all(v is None or (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))) for v in values):
        return np.array([np.nan if v is None else v for v in values], dtype=np.float64)
    return np.array(values, dtype=object)


def from_records(rows: Sequence[Mapping], columns: Sequence[str]) -> Columns:
    """`pd.DataFrame(rows, columns=columns)` as `Columns`, without pandas: one column per name in
    that order, a key a row lacks NaN, dtypes as pandas infers them (`_inferred`); no rows: empty
    object columns (pandas' dtype of a column with nothing in it)."""
    if not rows:
        return Columns({c: np.empty(0, dtype=object) for c in columns}, 0)
    return Columns({c: _inferred([r.get(c, np.nan) for r in rows]) for c in columns}, len(rows))


def records(t: Columns) -> list[dict]:
    """The rows of `t` as dicts of Python values: pandas' `to_dict(orient="records")`."""
    names = t.columns
    return [dict(zip(names, row)) for row in zip(*(t[c].tolist() for c in names))]


def pandas_schema_metadata(table: pa.Table) -> bytes:
    """The 'pandas' schema key pyarrow writes for a DataFrame of `table`'s columns with a default
    index not kept (`to_parquet(index=False)`): pandas reads the file written with it to the frame it
    would have written itself. Column kinds: int64, float64, bool, text (pandas' str: "object" /
    "str") and columns with no value (an empty frame's: arrow null, "empty" / "object")."""
    import json
    from importlib.metadata import version

    kinds = {pa.int64(): ("int64", "int64"), pa.float64(): ("float64", "float64"), pa.bool_(): ("bool", "bool"),
             pa.large_string(): ("object", "str"), pa.null(): ("empty", "object")}
    cols = []
    for f in table.schema:
        pandas_type, numpy_type = kinds[f.type]
        cols.append({"name": f.name, "field_name": f.name, "pandas_type": pandas_type, "numpy_type": numpy_type, "metadata": None})
    meta = {"index_columns": [], "column_indexes": [], "columns": cols, "attributes": {},
            "creator": {"library": "pyarrow", "version": pa.__version__}, "pandas_version": version("pandas")}
    return json.dumps(meta).encode("utf8")


def _arrow_array_as_pandas(v: np.ndarray) -> pa.Array:
    """`_arrow_array`, but a float column's NaN null, as pyarrow converts pandas' floats (NaN is missing)."""
    if v.dtype == np.float64 and np.isnan(v).any():
        valid = ~np.isnan(v)
        bits = np.packbits(valid, bitorder="little")
        return pa.Array.from_buffers(pa.float64(), v.size, [pa.py_buffer(bits), pa.py_buffer(np.ascontiguousarray(v))],
                                     null_count=int(v.size - np.count_nonzero(valid)))
    return _arrow_array(v)


def to_arrow_as_pandas(t: Columns) -> pa.Table:
    """The Arrow table pyarrow makes of `t` as a DataFrame (`pa.Table.from_pandas(df, preserve_index=False)`),
    its 'pandas' schema key included (`pandas_schema_metadata`), without pandas: `to_arrow`'s columns with
    NaN null in the float ones, and an empty text column (an empty table's) Arrow null, as pandas gives them."""
    arrays = [pa.nulls(0) if len(t) == 0 and t[k].dtype == object else _arrow_array_as_pandas(np.asarray(t[k])) for k in t.columns]
    table = pa.Table.from_arrays(arrays, names=t.columns)
    return table.replace_schema_metadata({b"pandas": pandas_schema_metadata(table)})
