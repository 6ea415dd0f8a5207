"""Issue 18 on `tpos import`: a source or mapping that is not a regular file (a FIFO would block the
read forever, /dev/zero never ends) or starts with NUL bytes is refused (exit 2) before it is read;
a CSV import with an impossible position (lat 95.5, a height of 1e9 m) is refused naming the line;
nothing is written in any case."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from typer.testing import CliRunner

from tpos_cli.cli import app

runner = CliRunner()

MAPPING = textwrap.dedent("""
    table = "gps"
    [source]
    delimiter = ","
    header = false
    comment = "#"
    names = ["time", "lat", "lon", "alt"]
    [time]
    column = "time"
    unit = "unix"
    clock = "unix"
    [columns]
    lat = { from = "lat", unit = "deg" }
    lon = { from = "lon", unit = "deg" }
    h = { from = "alt", unit = "m" }
    fix = { value = 1 }
""")
GOOD_ROWS = "# t,lat,lon,alt\n1600000000.0,45.5,-73.5,30\n1600000001.0,45.5,-73.5,30\n"


def _import_in_child(args: list[str], cwd: Path, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    """`tpos import ...` in a subprocess with a timeout: a read that blocks fails the test, never hangs it."""
    code = f"import sys; from tpos_cli.cli import main; sys.argv = ['tpos', *{args!r}]; main()"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s, cwd=cwd)


def _fifo(p: Path) -> Path:
    os.mkfifo(p)
    return p


def _dev_zero(p: Path) -> Path:
    p.symlink_to("/dev/zero")
    return p


def _sparse(p: Path) -> Path:
    with open(p, "wb") as fh:
        fh.truncate(64 << 20)  # 64 MiB of NULs, no disk used
    return p


@pytest.mark.parametrize("fmt", ["rtklib-pos", "nmea", "ubx", "csv"])
@pytest.mark.parametrize("make, message", [(_fifo, "is a FIFO"), (_dev_zero, "is a device"), (_sparse, "NUL bytes")],
                         ids=["fifo", "dev_zero", "sparse_nuls"])
def test_source_that_is_not_a_regular_text_file_is_refused_before_reading(tmp_path, fmt, make, message):
    if fmt == "ubx" and make is _sparse:
        pytest.skip("UBX is binary: NULs are data (the frames' checksums reject garbage)")
    src = make(tmp_path / "src.log")
    (tmp_path / "map.toml").write_text(MAPPING)
    args = ["import", fmt, str(src), "-o", str(tmp_path / "s")] + (["--map", str(tmp_path / "map.toml")] if fmt == "csv" else [])
    res = _import_in_child(args, tmp_path)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1 and "src.log" in lines[0] and message in lines[0], res.stderr
    assert not (tmp_path / "s").exists()


def test_mapping_that_is_a_fifo_is_refused(tmp_path):
    (tmp_path / "g.txt").write_text(GOOD_ROWS)
    _fifo(tmp_path / "map.toml")
    args = ["import", "csv", str(tmp_path / "g.txt"), "--map", str(tmp_path / "map.toml"), "-o", str(tmp_path / "s")]
    res = _import_in_child(args, tmp_path)
    assert res.returncode == 2 and "map.toml: is a FIFO" in res.stderr and not (tmp_path / "s").exists()


def test_mapping_nested_too_deeply_is_refused(tmp_path):
    (tmp_path / "g.txt").write_text(GOOD_ROWS)
    (tmp_path / "map.toml").write_text(MAPPING + "x = " + "[" * 600 + "]" * 600 + "\n")
    res = runner.invoke(app, ["import", "csv", str(tmp_path / "g.txt"), "--map", str(tmp_path / "map.toml"), "-o", str(tmp_path / "s")])
    assert res.exit_code == 2 and "nested too deeply" in res.output and not (tmp_path / "s").exists()


@pytest.mark.parametrize("row, message", [
    ("1600000002.0,95.5,-73.5,30", "line 4: lat 95.5 is not a latitude"),
    ("1600000002.0,45.5,-273.5,30", "line 4: lon -273.5 is not a longitude"),
    ("1600000002.0,45.5,-73.5,1e9", "line 4: h 1e+09 is not a height on Earth"),
])
def test_csv_import_refuses_an_impossible_position_naming_the_line(tmp_path, row, message):
    (tmp_path / "g.txt").write_text(GOOD_ROWS + row + "\n")
    (tmp_path / "map.toml").write_text(MAPPING)
    res = runner.invoke(app, ["import", "csv", str(tmp_path / "g.txt"), "--map", str(tmp_path / "map.toml"), "-o", str(tmp_path / "s")])
    assert res.exit_code == 2 and message in res.output, res.output
    assert not (tmp_path / "s").exists()


def test_csv_import_refuses_a_line_that_is_no_log_line(tmp_path):
    # audit (session 11): a 100 MB line after good rows was "dropped 1 unparsable line", exit 0, after a 745 MB peak
    (tmp_path / "g.txt").write_text(GOOD_ROWS + "1600000002.0," + "1" * (1 << 20) + ",-73.5,30\n")
    (tmp_path / "map.toml").write_text(MAPPING)
    res = runner.invoke(app, ["import", "csv", str(tmp_path / "g.txt"), "--map", str(tmp_path / "map.toml"), "-o", str(tmp_path / "s")])
    assert res.exit_code == 2 and "g.txt: line 4: longer than 64 KiB: not a line of a delimited log" in res.output, res.output
    assert not (tmp_path / "s").exists()


def test_csv_import_of_good_rows_still_works(tmp_path):
    (tmp_path / "g.txt").write_text(GOOD_ROWS)
    (tmp_path / "map.toml").write_text(MAPPING)
    res = runner.invoke(app, ["import", "csv", str(tmp_path / "g.txt"), "--map", str(tmp_path / "map.toml"), "-o", str(tmp_path / "s")])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["gps.csv", "session.toml"]


def test_ubx_of_bytes_that_are_no_utf8_after_a_dollar_is_refused_in_one_line(tmp_path):
    # audit (session 9): pyubx2 decodes the bytes after a '$' as NMEA text even with the UBX filter, so a
    # random .ubx was "tpos: internal error: UnicodeDecodeError" (exit 1)
    src = tmp_path / "junk.ubx"
    src.write_bytes(b"\x00\x01$G\xd3\xff\xfe,\x80\x81\r\n" * 300)
    res = CliRunner().invoke(app, ["import", "ubx", str(src), "-o", str(tmp_path / "s")])
    assert res.exit_code == 2 and res.output.strip().endswith("no UBX NAV-PVT messages (enable UBX-NAV-PVT output on the receiver)")
    assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "s").exists()


IMU_MAPPING = textwrap.dedent("""
    table = "imu"
    [source]
    delimiter = ","
    header = true
    [time]
    column = "t"
    unit = "s"
    [columns]
    acc_x = {{ from = "ax", unit = "g" }}
    acc_y = {{ from = "ay", unit = "g" }}
    acc_z = {{ from = "az", unit = "g" }}
    gyro_x = {{ from = "gx", unit = "rad/s" }}
    gyro_y = {{ from = "gy", unit = "rad/s" }}
    gyro_z = {{ from = "gz", unit = "rad/s" }}
    [axes]
    mounting_rpy_deg = {rpy}
""")


@pytest.mark.parametrize("rpy,message", [
    ("[0.0, nan, 4.0]", "must be three finite numbers (roll, pitch, yaw in degrees), got [0.0, nan, 4.0]"),
    ("[true, 0, 0]", "must be three finite numbers (roll, pitch, yaw in degrees), got [True, 0, 0]"),
    ("[[0.0], [1.0], [2.0]]", "must be three finite numbers"),
    ("[0.0, 100.0, 0.0]", "pitch 100 is outside ±90 degrees"),
    ("[0.0, -3.0, 4.0]", None),
])
def test_a_mapping_mounting_follows_the_sessions_rule(tmp_path, rpy, message):
    # audit (session 12): NaN or inf wrote an imu table of NaN (exit 0), true was 1 degree, pitch 100 passed,
    # [[0.0], [1.0], [2.0]] ended in "tpos: internal error" (exit 1)
    rows = "t,ax,ay,az,gx,gy,gz\n" + "".join(f"{k / 100:.2f},0,0,-1,0.001,0,0\n" for k in range(200))
    (tmp_path / "imu.csv").write_text(rows)
    (tmp_path / "map.toml").write_text(IMU_MAPPING.format(rpy=rpy))
    res = runner.invoke(app, ["import", "csv", str(tmp_path / "imu.csv"), "--map", str(tmp_path / "map.toml"), "-o", str(tmp_path / "s")])
    if message is None:
        assert res.exit_code == 0 and (tmp_path / "s" / "imu.parquet").exists(), res.output
        return
    assert res.exit_code == 2 and f"[axes] mounting_rpy_deg: {message}" in res.output, res.output
    assert not (tmp_path / "s").exists()
