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


def is_empty(t) -> bool:
    """No rows or no columns (pandas' `DataFrame.empty`), for either kind of table."""
    return len(t) == 0 or len(t.columns) == 0


def groups(a: np.ndarray, b: np.ndarray):
    """((a value, b value), row positions) of each distinct pair, in order of first appearance; pairs
    with a missing value (None, NaN) left out: pandas' `groupby([a, b], sort=False).groups`."""
    keys: dict = {}
    code = np.fromiter((keys.setdefault(k, len(keys)) for k in zip(a.tolist(), b.tolist())), dtype=np.int64, count=len(a))
    for k, c in keys.items():
        if not any(v is None or v != v for v in k):
            yield k, np.flatnonzero(code == c)
