"""`io.columns`: tables as numpy columns, written and read without pandas, equal to what pandas wrote and read."""

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from tpos_cli.io.columns import (
    Columns,
    column,
    concat,
    first_appearance_codes,
    flags,
    from_arrow,
    from_records,
    groups,
    is_empty,
    records,
    to_arrow,
    to_arrow_as_pandas,
)
from tpos_cli.io.run_dir import write_parquet
from tpos_cli.io.tables import read_table

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_logs" / "drive_outage"


def _table(n: int = 50, seed: int = 1) -> dict:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=n)
    x[::7] = np.nan
    return {"t": np.arange(n, dtype=float), "x": x, "dof": rng.integers(0, 4, n).astype(np.int64),
            "accepted": rng.random(n) > 0.3, "solution": np.array(["forward", "backward", "smoothed", "ü"] * n, dtype=object)[:n]}


def test_to_arrow_equals_from_pandas():
    cols = _table()
    a = to_arrow(Columns(cols))
    b = pa.Table.from_pandas(pd.DataFrame(cols), preserve_index=False)
    assert a.schema.equals(b.schema, check_metadata=False)
    assert a.schema.metadata is None  # no 'pandas' key: nothing of pandas is needed to read it back
    pd.testing.assert_frame_equal(a.to_pandas(), b.to_pandas(), check_exact=True)  # NaN == NaN here
    finite = np.isfinite(cols["x"])
    a, b = (to_arrow(Columns(cols).take(finite)), pa.Table.from_pandas(pd.DataFrame(cols)[finite], preserve_index=False))
    assert a.equals(b)  # Arrow's equality: every value (NaN never equals NaN there)


def test_written_file_reads_back_to_the_frame_pandas_wrote(tmp_path):
    cols = Columns(_table())
    write_parquet(cols, tmp_path / "a.parquet", {"version": "x"})
    write_parquet(cols.to_pandas(), tmp_path / "b.parquet", {"version": "x"})
    a, b = pd.read_parquet(tmp_path / "a.parquet"), pd.read_parquet(tmp_path / "b.parquet")
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert pq.read_table(tmp_path / "a.parquet").schema.metadata == {b"tpos.version": b"x"}


def test_columns_views_are_read_only_and_matrix_is_column_major():
    c = Columns({"a": np.arange(3.0), "b": np.arange(3.0) * 2})
    with pytest.raises(ValueError):
        c["a"][0] = 1.0
    m = c.matrix(["a", "b"])
    assert m.shape == (3, 2) and m.flags.f_contiguous and m.flags.writeable
    assert len(c) == 3 and "a" in c and c.columns == ["a", "b"] and not is_empty(c)
    both = concat([c, c.take(np.array([2, 0]))])
    assert both["a"].tolist() == [0.0, 1.0, 2.0, 2.0, 0.0]


def test_helpers_read_a_dataframe_and_columns_alike():
    cols = _table()
    cols["accepted"] = cols["accepted"].astype(object)
    cols["accepted"][3] = None  # a missing cell: False, as pandas' fillna(False)
    df = pd.DataFrame(cols)
    c = Columns({k: v for k, v in cols.items() if k != "accepted"} | {"accepted": df["accepted"].fillna(False).to_numpy(bool)})
    assert np.array_equal(flags(df, "accepted"), flags(c, "accepted"))
    assert np.array_equal(column(df, "x"), column(c, "x"), equal_nan=True)
    kind = np.array(["gps_pos", "gps_vel"] * 25, dtype=object)
    df["kind"] = kind
    got = [(k, i.tolist()) for k, i in groups(column(df, "solution"), kind)]
    want = [(k, np.asarray(i).tolist()) for k, i in df.groupby(["solution", "kind"], sort=False).groups.items()]
    assert got == want


def _parquet(tmp_path, table: pa.Table, row_group_size: int | None = None) -> Path:
    p = tmp_path / "g.parquet"
    pq.write_table(table, p, row_group_size=row_group_size)
    return p


def test_read_table_through_arrow_gives_what_pandas_gave(tmp_path):
    """Floats with nulls, float32, integers, text with spaces and nulls, several row groups: the arrays
    the pandas conversion (the Parquet path before) gives, value for value and dtype for dtype."""
    n = 1000
    rng = np.random.default_rng(2)
    x = pa.array(np.where(rng.random(n) < 0.1, None, rng.normal(size=n)).tolist(), type=pa.float64())
    t = pa.table({"t": np.arange(n, dtype=float), "x": x, "f32": rng.normal(size=n).astype(np.float32),
                  "i": rng.integers(-5, 5, n), "id": pa.array([None if k % 9 == 0 else f" a{k % 4} " for k in range(n)])})
    p = _parquet(tmp_path, t, row_group_size=300)
    got = read_table(p, ("t", "x", "f32", "i"), ("id",))
    df = t.to_pandas()
    assert np.array_equal(got["x"], df["x"].to_numpy(np.float64, na_value=np.nan), equal_nan=True)
    assert np.array_equal(got["f32"], df["f32"].to_numpy(np.float64)) and got["f32"].dtype == np.float64
    assert np.array_equal(got["i"], df["i"].to_numpy(np.float64)) and got["i"].dtype == np.float64
    assert got["id"].tolist() == ["" if v is None else v.strip() for v in t.column("id").to_pylist()]


def test_read_table_leaves_unusual_columns_to_pandas(tmp_path):
    t = pa.table({"t": [0.0, 1.0], "x": pa.array([1, None], type=pa.int64()), "b": [True, False]})
    p = _parquet(tmp_path, t)
    assert read_table(p, ("t", "x"))["x"].tolist()[0] == 1.0  # an integer column with nulls: NaN there
    with pytest.raises(Exception, match="boolean values"):
        read_table(p, ("t", "b"))


def test_a_drive_in_parquet_is_processed_without_pandas(tmp_path):
    """The drive chain's whole run (ingest, filters, verdict, outputs) never imports pandas."""
    code = ("import sys\nfrom tpos_cli.pipeline import process_session\n"
            f"process_session({str(SAMPLE)!r}, None, {str(tmp_path / 'run')!r})\n"
            "assert 'pandas' not in sys.modules, 'pandas imported'\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=REPO)
    assert res.returncode == 0, res.stderr[-2000:]


def test_drive_outputs_read_back_equal_to_the_pandas_written_files(tmp_path):
    """Each output of the sample drive (written from `Columns`) against the file pandas writes from the
    same rows (what main wrote: `pa.Table.from_pandas`): pandas.read_parquet gives equal DataFrames."""
    from tpos_cli.pipeline import process_session

    res = process_session(SAMPLE, None, tmp_path / "run", mask_gps_windows=[(50.0, 80.0)])
    names = [n for n in res.summary["outputs"] if n.endswith(".parquet")]
    assert names == ["trajectory.parquet", "innovations.parquet", "withheld_gps.parquet"]
    for name in names:
        ours = pq.read_table(tmp_path / "run" / name)
        frame = ours.to_pandas()
        write_parquet(frame, tmp_path / name)
        theirs = pq.read_table(tmp_path / name)
        assert ours.schema.equals(theirs.schema, check_metadata=False) and ours.equals(theirs), name
        pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "run" / name), pd.read_parquet(tmp_path / name), check_exact=True)


def _same_cells(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal arrays of one dtype, NaN equal to NaN and a missing label (None or NaN) to a missing one."""
    if a.dtype != b.dtype:
        return False
    if a.dtype.kind in "fiub":
        return np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    gone = lambda v: v is None or v != v  # noqa: E731
    return all((gone(x) and gone(y)) or x == y for x, y in zip(a.tolist(), b.tolist()))


def test_from_arrow_gives_the_values_to_pandas_gives(tmp_path):
    """Every column kind a run table holds, with and without nulls, over several chunks and from an
    offset (a sliced table), text also read as dictionaries (a dictionary per row group, as
    `report.rundir` reads it): the arrays `Table.to_pandas()` holds (text: object arrays of str)."""
    n = 40
    rng = np.random.default_rng(3)
    x = rng.normal(size=n)
    x[::5] = np.nan
    table = pa.table({
        "x": x,
        "x_null": pa.array(x, mask=np.arange(n) % 7 == 0),
        "k": pa.array(rng.integers(-5, 5, n), type=pa.int64()),
        "k_null": pa.array(rng.integers(0, 5, n), type=pa.int64(), mask=np.arange(n) % 6 == 0),
        "ok": pa.array(rng.random(n) > 0.5),
        "ok_null": pa.array(rng.random(n) > 0.5, mask=np.arange(n) % 4 == 0),
        "label": pa.array(np.array(["forward", "backward", "ü"] * n, dtype=object)[:n], type=pa.large_string()),
        "label_null": pa.array(np.array(["a", "b", None] * n, dtype=object)[:n], type=pa.string()),
    })
    chunked = pa.concat_tables([table.slice(0, 13), table.slice(13)])
    pq.write_table(table, tmp_path / "t.parquet", row_group_size=16)
    text = ["label", "label_null"]
    as_dictionaries = pq.ParquetFile(tmp_path / "t.parquet", read_dictionary=text).read()
    assert pa.types.is_dictionary(as_dictionaries.schema.field("label").type) and as_dictionaries.column("label").num_chunks == 3
    cases = [(table, table), (chunked, chunked), (chunked.slice(5, 30), chunked.slice(5, 30)), (table.slice(0, 0), table.slice(0, 0)),
             (as_dictionaries, table), (as_dictionaries.slice(20, 15), table.slice(20, 15))]
    for t, plain in cases:
        ours, theirs = from_arrow(t), plain.to_pandas()
        assert ours.columns == list(theirs.columns) and len(ours) == len(theirs)
        for c in ours.columns:
            assert _same_cells(ours[c], theirs[c].to_numpy()), c


def test_from_records_infers_the_dtypes_pandas_infers_and_records_gives_its_rows():
    rows = [{"s": "a", "i": 1, "f": 1.5, "m": 1, "b": True, "none": None, "x": np.float64(2.0)},
            {"s": "b", "i": 2, "f": float("nan"), "m": 2.5, "b": np.bool_(False), "none": 3.0}]
    cols = ["s", "i", "f", "m", "b", "none", "x"]
    ours, frame = from_records(rows, cols), pd.DataFrame(rows, columns=cols)
    for c in cols:
        assert _same_cells(ours[c], frame[c].to_numpy()), c
    assert repr(records(ours)) == repr(frame.to_dict(orient="records"))  # the same Python values, NaN included
    empty = from_records([], cols)
    assert len(empty) == 0 and all(empty[c].dtype == pd.DataFrame([], columns=cols)[c].to_numpy().dtype for c in cols)
    assert records(empty) == []


@pytest.mark.parametrize("n_rows", [3, 0])
def test_a_table_written_like_pandas_is_the_file_pandas_writes(n_rows):
    """`to_arrow_as_pandas` + pq.write_table: byte for byte the file `DataFrame.to_parquet(index=False)`
    writes (an accuracy table: text keys, int64 counts, floats with NaN; and with no rows)."""
    cols = ["solution", "segment", "n", "mean", "cep"]
    rows = [{"solution": "forward", "segment": "all", "n": 3, "mean": 0.5, "cep": float("nan")},
            {"solution": "backward", "segment": "outage_1", "n": 0, "mean": float("nan"), "cep": 1.25},
            {"solution": "smoothed", "segment": "all", "n": 7, "mean": -2.0, "cep": 0.75}][:n_rows]
    ours = from_records(rows, cols)
    ours = Columns({c: ours[c].astype(np.int64) if c == "n" else ours[c] for c in cols}, len(ours))  # as the report does
    frame = pd.DataFrame(rows, columns=cols)
    frame["n"] = frame["n"].astype("int64")
    a, b = io.BytesIO(), io.BytesIO()
    pq.write_table(to_arrow_as_pandas(ours), a)
    frame.to_parquet(b, index=False)
    assert a.getvalue() == b.getvalue()


def test_first_appearance_codes_are_pandas_factorize():
    labels = np.array(["smoothed", "forward", "forward", "ü", "smoothed", "backward"] * 3, dtype=object)
    codes, names = first_appearance_codes(labels)
    ref_codes, ref_names = pd.factorize(labels)
    assert codes.tolist() == ref_codes.tolist() and names == list(ref_names)
