"""io.tables text columns and the anchor-range ids read through them (the factorized paths)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.helpers.sessions import write_minimal_session
from tpos_cli.errors import InvalidInputError
from tpos_cli.io.tables import _to_text
from tpos_cli.session import load_session


def _cell_by_cell(s: pd.Series) -> np.ndarray:
    return np.array(["" if (v is None or (isinstance(v, float) and np.isnan(v))) else str(v).strip() for v in s], dtype=object)


@pytest.mark.parametrize(
    "s",
    [
        pd.Series(["A1", None, " A2", "A2", "A1 ", "", " "], dtype="str"),
        pd.Series(["é", "ß ", np.nan], dtype="str"),
        pd.Series([], dtype="str"),
        pd.Series([1.0, np.nan, -0.0, 0.0]),  # numbers: -0.0 and 0.0 stay apart
        pd.Series([1, True, 1.0, None, " x"], dtype=object),  # 1, True and 1.0 stay apart
    ],
)
def test_text_column_is_the_cell_by_cell_conversion(s):
    got = _to_text(s)
    want = _cell_by_cell(s)
    assert got.dtype == object and list(got) == list(want)
    assert all(type(v) is str for v in got)


def _anchor_session(tmp_path, fmt):
    s = write_minimal_session(tmp_path / "s", with_anchors=True)
    d = pd.read_csv(s / "anchor_ranges.csv")
    d["id"] = [f" {a} " if i % 3 == 0 else a for i, a in enumerate(d["id"].astype(str))]  # padded ids are the same ids
    if fmt == "parquet":
        (s / "anchor_ranges.csv").unlink()
        d.to_parquet(s / "anchor_ranges.parquet", index=False)
    else:
        d.to_csv(s / "anchor_ranges.csv", index=False)
    return s, d


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_anchor_ranges_ids_map_to_anchors_row_by_row(tmp_path, fmt):
    s, d = _anchor_session(tmp_path, fmt)
    ses = load_session(s)
    ids = list(ses.anchors.ids)
    idx = np.array([ids.index(a.strip()) for a in d["id"]])
    kept = np.isfinite(d["range"].to_numpy()) & ~pd.DataFrame({"t": d["t"], "a": idx}).duplicated().to_numpy()
    assert ses.anchor_ranges.anchor.dtype == np.int64
    assert np.array_equal(ses.anchor_ranges.anchor, idx[kept])
    assert len(set(ids)) == len(ids) and all(i == i.strip() for i in ids)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_unknown_anchor_id_is_named_with_its_row(tmp_path, fmt):
    s, d = _anchor_session(tmp_path, fmt)
    d.loc[9, "id"] = "A9"
    if fmt == "parquet":
        d.to_parquet(s / "anchor_ranges.parquet", index=False)
    else:
        d.to_csv(s / "anchor_ranges.csv", index=False)
    with pytest.raises(InvalidInputError) as exc:
        load_session(s)
    assert f"anchor_ranges.{fmt}: column 'id', row 10: anchor id 'A9' is not in anchors.csv" in str(exc.value)


def _parquet_gps_session(tmp_path):
    s = write_minimal_session(tmp_path / "s", fmt="parquet")
    import pyarrow.parquet as pq

    return s, pq.read_table(s / "gps.parquet")


def test_parquet_column_repeated_is_named_not_an_internal_error(tmp_path):
    """A Parquet file may hold two columns of one name; pyarrow's column lookup raised KeyError
    ("tpos: internal error", exit 1) on the Arrow path."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    s, g = _parquet_gps_session(tmp_path)
    pq.write_table(pa.Table.from_arrays(g.columns + [g.column("lat")], names=g.column_names + ["lat"]), s / "gps.parquet")
    with pytest.raises(InvalidInputError) as exc:
        load_session(s)
    assert str(exc.value) == "s/gps.parquet: column 'lat': the column appears 2 times in the file; keep one"


@pytest.mark.parametrize("kind", ["timestamp[ns]", "timestamp[ns, tz=UTC]", "duration[ns]"])
def test_parquet_time_column_of_a_date_type_is_refused(tmp_path, kind):
    """A t column stored as timestamp/duration was read as integer nanoseconds (t = 1e12 'seconds'): `tpos
    validate` said ok and `process` ran on a clock 1e9 times too slow."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    s, g = _parquet_gps_session(tmp_path)
    unit = pa.timestamp("ns", tz="UTC") if "UTC" in kind else pa.timestamp("ns") if kind.startswith("timestamp") else pa.duration("ns")
    t_ns = pa.array((g.column("t").to_numpy() * 1e9).astype("int64")).cast(unit)
    pq.write_table(g.set_column(0, "t", t_ns), s / "gps.parquet")
    with pytest.raises(InvalidInputError) as exc:
        load_session(s)
    assert str(exc.value).startswith(f"s/gps.parquet: column 't', row 1: the column is of type {kind} (a date/time type)")


@pytest.mark.parametrize("case", ["int32", "float32", "dictionary", "nulls", "row_groups"])
def test_parquet_plain_variants_read_as_the_float64_file(tmp_path, case):
    """Odd but valid column types give the same numbers as the float64 file (Arrow path or pandas')."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    s, g = _parquet_gps_session(tmp_path)
    want = load_session(s).gps
    i = g.column_names.index("fix")
    if case == "int32":
        g2 = g.set_column(i, "fix", g.column("fix").cast(pa.int32()))
    elif case == "float32":
        j = g.column_names.index("h")
        g2 = g.set_column(j, "h", pa.array(g.column("h").to_numpy().astype(np.float32)))
    elif case == "dictionary":
        g2 = g.set_column(i, "fix", pa.array([str(int(v)) for v in g.column("fix").to_pylist()]).dictionary_encode())
    elif case == "nulls":
        j = g.column_names.index("h")
        g2 = g.set_column(j, "h", pa.array([None] + g.column("h").to_pylist()[1:], pa.float64()))
    else:
        g2 = g
    if case == "row_groups":
        with pq.ParquetWriter(s / "gps.parquet", g.schema) as w:
            w.write_table(g.slice(0, 3))
            w.write_table(g.slice(3, 0))
            w.write_table(g.slice(3))
    else:
        pq.write_table(g2, s / "gps.parquet")
    got = load_session(s).gps
    a_lla, b_lla, a_fix, b_fix = got.lla, want.lla.copy(), got.fix, want.fix
    if case == "float32":
        b_lla[:, 2] = b_lla[:, 2].astype(np.float32)
    if case == "nulls":  # a fix without its height is dropped to fix = 0 (with a warning)
        assert a_fix[0] == 0 and np.isnan(a_lla[0, 2])
        a_lla, b_lla, a_fix, b_fix = a_lla[1:], b_lla[1:], a_fix[1:], b_fix[1:]
    assert np.array_equal(got.t_s, want.t_s)
    assert np.array_equal(a_lla, b_lla) and np.array_equal(a_fix, b_fix)


def test_a_huge_cell_or_last_line_is_one_short_line(tmp_path):
    # audit (session 9): a 5 MB cell in the last row was "the last line has 6 fields where the header has 7
    # (truncated file?)" (the last-line check saw 4 KiB of it); once that was mended, the error quoted the 5 MB cell
    from tpos_cli.errors import InvalidInputError
    from tpos_cli.io.tables import read_table

    head = "t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z\n"
    p = tmp_path / "imu.csv"
    p.write_text(head + "0,0,0,0,0,0,-9.8\n1," + "x" * (5 << 20) + ",0,0,0,0,-9.8\n")
    with pytest.raises(InvalidInputError) as exc:
        read_table(p, ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"))
    msg = str(exc.value)
    # since session 11 a line past 64 KiB is refused before it is decoded (a 300 MB line took 1.7 GB); the cell
    # itself was named "column 'gyro_x', row 2: 'xxx... (5242882 characters) is not a number" before
    assert msg == "imu.csv, row 2: a line longer than 64 KiB: not a row of a contract table"
    p.write_text(head + "0,0,0,0,0,0,-9.8\n1," + "x" * 60000 + ",0,0,0,0,-9.8\n")  # a long cell within the line limit
    with pytest.raises(InvalidInputError) as exc:
        read_table(p, ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"))
    msg = str(exc.value)
    assert msg.startswith("imu.csv: column 'gyro_x', row 2: 'xxx") and msg.endswith("(60002 characters) is not a number")
    assert len(msg) < 150
    p.write_text(head + "0,0,0,0,0,0,-9.8\n1,0,0,0," + "1" * 5000 + ",0\n")  # a long last line that IS cut short
    with pytest.raises(InvalidInputError, match="fields where the header has 7"):
        read_table(p, ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"))


def test_a_tables_file_name_in_messages_is_built_once(tmp_path):
    """review (session 10): drive_smooth.fixes_from_session built "the gps file's name" in each refusal
    (and conventions a third time); `table_file_name` serves all, and a session without a directory (a
    library caller's) is named by the table, not an internal TypeError."""
    import dataclasses

    from tpos_cli.chains.drive_smooth import fixes_from_session
    from tpos_cli.config import DriveSmoothParams
    from tpos_cli.io.tables import table_file_name

    s = write_minimal_session(tmp_path / "s")
    assert table_file_name(s, "imu") == "imu.csv" and table_file_name(s, "anchors") == "anchors"
    assert table_file_name(None, "gps") == "gps"
    session = load_session(s)
    gps = dataclasses.replace(session.gps, t_s=session.gps.t_s + 1e6)  # on another clock
    for path, name in ((session.path, table_file_name(s, "gps")), (None, "gps")):
        with pytest.raises(InvalidInputError, match=rf"^{name}: column 't': no position fix falls within the IMU"):
            fixes_from_session(dataclasses.replace(session, gps=gps, path=path), DriveSmoothParams())


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_a_missing_required_column_lists_the_columns_the_file_has(tmp_path, fmt):
    # audit (session 12): a Parquet odometry table with `speed` for `speed_mps` said "found: t" (only the
    # columns tpos reads), hiding the column the user had named differently
    s = write_minimal_session(tmp_path / "s")
    imu = pd.read_csv(s / "imu.csv").rename(columns={"acc_z": "accel_z"})
    (s / "imu.csv").unlink()
    imu.to_csv(s / "imu.csv", index=False) if fmt == "csv" else imu.to_parquet(s / "imu.parquet", index=False)
    with pytest.raises(InvalidInputError) as e:
        load_session(s)
    assert f"imu.{fmt}: column 'acc_z': required column is missing (found: " in str(e.value)
    assert "accel_z" in str(e.value)


def _imu_lines(s):
    text = (s / "imu.csv").read_text().splitlines()
    return text[0], text[1:]


@pytest.mark.parametrize("where", ["every_data_line", "first_data_line"])
def test_a_trailing_comma_the_header_lacks_is_read_as_a_trailing_comma(tmp_path, where):
    # audit (session 12): pandas took each line's first field as an index and shifted the columns by one
    # (t read from gyro_x: "column 't', row 3: time goes backwards"); on the first line only, silently
    s = write_minimal_session(tmp_path / "s")
    want = load_session(s).imu
    header, rows = _imu_lines(s)
    rows = [r + "," for r in rows] if where == "every_data_line" else [rows[0] + ","] + rows[1:]
    (s / "imu.csv").write_text("\n".join([header, *rows]) + "\n")
    got = load_session(s).imu
    assert np.array_equal(got.t_s, want.t_s) and np.array_equal(got.gyro_b_rps, want.gyro_b_rps)
    assert np.array_equal(got.acc_b_mps2, want.acc_b_mps2)


def test_a_value_beyond_the_headers_columns_is_refused_on_its_row(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    header, rows = _imu_lines(s)
    (s / "imu.csv").write_text("\n".join([header, rows[0] + ",7.5", *rows[1:]]) + "\n")
    with pytest.raises(InvalidInputError) as e:
        load_session(s)
    assert str(e.value).startswith("s/imu.csv, row 1: has more fields than the ")


IMU_COLS = ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")


def _plain_imu_lines(n: int) -> list[str]:
    return ["t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z"] + [f"{i / 100:.2f},0.001,0.002,0.003,0.1,0.2,-9.8" for i in range(n)]


@pytest.mark.parametrize("damaged", ["0.50,0.001,0.002", "0.50,0.001,0.003,0.1,0.2,-9.8", "garbage"])
def test_a_damaged_line_inside_a_csv_is_refused_with_its_row(tmp_path, damaged):
    # audit (session 25): a line cut short inside imu.csv (or one that lost a field) was read with NaN in its
    # missing fields and its other values in the wrong columns, then dropped as "1 samples with empty/NaN gyro or
    # acc values" with no row named; in a GPS table a line without `h` would have been kept with lon's neighbours
    # shifted into h and fix. Only a cut LAST line was refused.
    from tpos_cli.io.tables import read_table

    lines = _plain_imu_lines(100)
    lines[51] = damaged  # data row 51
    p = tmp_path / "imu.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InvalidInputError, match="fields where the header has 7: a damaged line") as exc:
        read_table(p, IMU_COLS)
    assert str(exc.value).startswith("imu.csv, row 51: ")


@pytest.mark.parametrize("chunk_bytes", [5, 37, 1 << 20])
def test_the_damaged_line_scan_matches_per_line_counts_across_chunks(tmp_path, chunk_bytes):
    # The scan carries a line's commas across its read chunks; blank lines (pandas skips them) and CRLF endings
    # are no damage. Reference: the fields of each line counted in Python.
    from tpos_cli.io.tables import _scan_csv

    lines = _plain_imu_lines(40)
    lines[7] = ""
    lines[12] = "   \r"
    lines = [ln + "\r" if i % 2 else ln for i, ln in enumerate(lines)]
    p = tmp_path / "imu.csv"
    p.write_text("\n".join(lines) + "\n")
    assert _scan_csv(p, 6, chunk_bytes=chunk_bytes) is None
    lines[23] = "0.22,1,2,3,4\r"
    p.write_text("\n".join(lines) + "\n")
    assert _scan_csv(p, 6, chunk_bytes=chunk_bytes) == (23, 5)
