"""`io.columns`: tables as numpy columns, written and read without pandas, equal to what pandas wrote and read."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from tpos_cli.io.columns import Columns, column, concat, flags, groups, is_empty, to_arrow
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
