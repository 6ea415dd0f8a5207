"""Issue 18: hostile and broken inputs end cleanly: refused at the door (exit 2, one line, nothing
written), or a plain exit 1 for an output that cannot be written; reads are bounded in time and memory."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from tests.helpers.sessions import write_minimal_session
from tpos_cli.cli import app

runner = CliRunner()
REPO = Path(__file__).resolve().parents[2]


def _toml_add(s: Path, text: str) -> None:
    (s / "session.toml").write_text((s / "session.toml").read_text() + "\n" + text + "\n")


@pytest.fixture(scope="module")
def baseline_rss_kb(tmp_path_factory):
    """Peak memory of `tpos validate` on a valid session here: the imports (and a cold numba cache)."""
    d = tmp_path_factory.mktemp("baseline")
    s = write_minimal_session(d / "s")
    res, peak_kb = _run_cli_bounded(["validate", str(s)], d)
    assert res.returncode == 0, res.stderr
    return peak_kb


def _run_cli_bounded(args: list[str], cwd: Path, timeout_s: float = 120.0, mem_bytes: int = 1 << 30):
    """The CLI in a subprocess under a 1 GB address-space limit and a wall-clock timeout."""
    peak_file = cwd / "peak_rss_kb"
    code = textwrap.dedent(f"""
        import atexit, resource, sys
        resource.setrlimit(resource.RLIMIT_AS, ({mem_bytes} * 4, {mem_bytes} * 4))  # virtual: numba/llvm reserve
        atexit.register(lambda: open({str(peak_file)!r}, "w").write(str(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)))
        from tpos_cli.cli import main
        sys.argv = ["tpos", *{args!r}]
        main()
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s, cwd=cwd)
    return res, int(peak_file.read_text())  # this child's own peak resident set, kB


# ------------------------------------------------------------------ refused at the door (validate: exit 2)

def fifo_imu(s):
    (s / "imu.csv").unlink()
    os.mkfifo(s / "imu.csv")


def dev_zero_imu(s):
    (s / "imu.csv").unlink()
    (s / "imu.csv").symlink_to("/dev/zero")


def sparse_nul_imu(s):
    (s / "imu.csv").unlink()
    with open(s / "imu.csv", "wb") as fh:
        fh.truncate(1 << 30)  # 1 GiB of NULs, no disk used


def nul_hole_after_valid_rows(s):
    with open(s / "imu.csv", "r+b") as fh:  # valid rows, then a 1 GiB hole: pandas would decode it as one huge field
        fh.seek(0, 2)
        fh.truncate(fh.tell() + (1 << 30))


def header_line_past_64_kib(s):
    n = 20_000  # pandas takes minutes to set up 3 million columns; a header this long is not a contract table
    (s / "imu.csv").write_text(",".join(f"c{i}" for i in range(n)) + "\n" + ",".join("0" for _ in range(n)) + "\n")


def data_line_of_100_mb(s):
    # audit (session 11): a 300 MB line after a valid header took pandas 1.7 GB to decode (the last-line check
    # then named it); a line past 64 KiB is refused while the bytes are scanned
    with open(s / "imu.csv", "ab") as fh:
        fh.write(b"1" * (100 << 20) + b"\n")


def csv_with_1500_columns(s):
    df = pd.read_csv(s / "imu.csv")
    extra = pd.DataFrame(np.zeros((len(df), 1500)), columns=[f"x{i}" for i in range(1500)])
    pd.concat([df, extra], axis=1).to_csv(s / "imu.csv", index=False)


def parquet_with_1500_columns(s):
    df = pd.read_csv(s / "imu.csv")
    (s / "imu.csv").unlink()
    pq.write_table(pa.table({**{c: df[c].to_numpy() for c in df.columns}, **{f"x{i}": np.zeros(len(df)) for i in range(1500)}}),
                   s / "imu.parquet")


def parquet_with_many_rows(s):
    (s / "imu.csv").unlink()
    n = 25_000_000  # above the row limit; a constant column compresses to almost nothing
    cols = ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
    t = pa.table({c: pa.array(np.zeros(n)) for c in cols})
    pq.write_table(t, s / "imu.parquet", compression="zstd", row_group_size=5_000_000)


def bad_pandas_metadata(s):
    df = pd.read_csv(s / "gps.csv")
    (s / "gps.csv").unlink()
    table = pa.Table.from_pandas(df, preserve_index=False)
    table = table.replace_schema_metadata({b"pandas": b"{not json"})
    pq.write_table(table, s / "gps.parquet")


def deep_toml(s):
    _toml_add(s, "[extra]\nx = " + "[" * 600 + "]" * 600)


def deep_tables(s):
    _toml_add(s, "[" + ".".join(f"a{i}" for i in range(40)) + "]\nx = 1")


def _toml_top(s: Path, text: str) -> None:
    (s / "session.toml").write_text(text + "\n" + (s / "session.toml").read_text())


def section_as_scalar(s):
    _toml_top(s, "gps = 1")  # top level, before the first [table]


def time_as_scalar(s):
    _toml_top(s, 'time = "late"')


def declination_1e308(s):
    _toml_add(s, "[magnetic]\ndeclination_deg = 1e308")


def singular_soft_iron(s):
    _toml_add(s, "[magnetic]\nsoft_iron = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]")


def gps_outside_imu_span(s):
    df = pd.read_csv(s / "gps.csv")
    df.assign(t=df.t + 3600.0).to_csv(s / "gps.csv", index=False)


def gps_in_gps_week_seconds(s):
    """audit (session 11): GPS `t` as seconds of the GPS week (the receiver's clock) beside an IMU on
    the logger's: `tpos validate` warned (exit 0) while `tpos process` refused it (exit 2)."""
    df = pd.read_csv(s / "gps.csv")
    df.assign(t=df.t - df.t.iloc[0] + 345600.0).to_csv(s / "gps.csv", index=False)


def imu_time_in_ms(s):
    df = pd.read_csv(s / "imu.csv")
    df.assign(t=df.t * 1000.0).to_csv(s / "imu.csv", index=False)


def acc_in_g_after_20_s(s):
    # audit (session 11): two logs joined, the second in g: validate exit 0, process verdict unreliable ("at rest
    # |f| = 5.47 m/s^2 ...: accelerometer scale or units are off"), outputs written, exit 0
    df = pd.read_csv(s / "imu.csv")
    later = np.arange(len(df)) >= 2000
    for c in ("acc_x", "acc_y", "acc_z"):
        df[c] = np.where(later, df[c] / 9.80665, df[c])
    df.to_csv(s / "imu.csv", index=False)


def gps_time_in_ms(s):
    # audit (session 11): validate said nothing; process ran dead reckoning, exit 0, the verdict blaming the GPS clock
    df = pd.read_csv(s / "gps.csv")
    df.assign(t=df.t * 1000.0).to_csv(s / "gps.csv", index=False)


def odometry_time_in_ms(s):
    # audit (session 12): validate and process exit 0, silent: 3 of the 200 rows fell inside the IMU's span and
    # their speeds (the first 0.1 s of the drive) were used 0, 50 and 100 ms... as if at 0, 50 and 100 s
    t = 1000.0 + np.arange(200) * 0.05
    pd.DataFrame({"t": t * 1000.0, "speed_mps": 0.0}).to_csv(s / "odometry.csv", index=False)


def odometry_in_seconds(s):
    t = 1000.0 + np.arange(200) * 0.05
    pd.DataFrame({"t": t, "speed_mps": 0.0}).to_csv(s / "odometry.csv", index=False)


def _mag_times(s, factor: float) -> None:
    """A static magnetometer reading the Earth's field at 45 N (about 20 µT north, 49 µT down) times `factor`."""
    df = pd.read_csv(s / "imu.csv")
    df.assign(mag_x=20.0 * factor, mag_y=0.5 * factor, mag_z=49.0 * factor).to_csv(s / "imu.csv", index=False)


def mag_in_nt(s):
    # audit (session 12): validate exit 0 with a warning; `tpos process` of a target session ended with exit 1,
    # "LinAlgError: SVD did not converge" after a numpy RuntimeWarning on stderr
    _mag_times(s, 1000.0)


def mag_in_gauss(s):
    _mag_times(s, 0.01)  # was exit 0, verdict "suspect: 29 % of the samples disturbed", no word of the unit


def mag_in_tesla(s):
    _mag_times(s, 1e-6)


def mag_all_zero(s):
    _mag_times(s, 0.0)  # was exit 1 in a target session: "the magnetic update needs setup.mag_ref"


def mag_in_ut(s):
    _mag_times(s, 1.0)


def mag_in_milligauss(s):
    _mag_times(s, 10.0)  # a µT log with a few hundred µT of hard iron reads the same: a warning, not a refusal


def gps_time_in_us(s):
    df = pd.read_csv(s / "gps.csv")
    df.assign(t=df.t * 1e6).to_csv(s / "gps.csv", index=False)


def ranges_in_mm(s):
    df = pd.read_csv(s / "ranges.csv")
    df.assign(d1=df.d1 * 1000, d2=df.d2 * 1000, d3=df.d3 * 1000).to_csv(s / "ranges.csv", index=False)


def duplicate_target_ids(s):
    pd.DataFrame({"id": ["T1", "T2", "T1"], "lat": [45.0, 45.001, 45.01], "lon": [-73.0] * 3, "h": [10.0] * 3,
                  "role": ["truth"] * 3}).to_csv(s / "targets.csv", index=False)


def overlapping_shots(s):
    pd.DataFrame({"id": ["T1", "T2"], "t_start": [1001.0, 1003.0], "t_end": [1004.0, 1006.0]}).to_csv(s / "shots.csv", index=False)


def _moving_gps(s: Path, swap_latlon: bool = False, swap_velocity: bool = False, radians: bool = False) -> None:
    """20 s of 1 Hz fixes on a curving 15-25 m/s track with the velocities that go with it."""
    t = 1000.0 + np.arange(10.0)
    heading = np.deg2rad(30.0 + 12.0 * np.arange(10.0))
    speed = 15.0 + np.arange(10.0)
    vn, ve = speed * np.cos(heading), speed * np.sin(heading)
    north = np.concatenate([[0.0], np.cumsum(0.5 * (vn[1:] + vn[:-1]))])
    east = np.concatenate([[0.0], np.cumsum(0.5 * (ve[1:] + ve[:-1]))])
    lat = 45.0 + north / 111_132.0 + 2e-6 * np.sin(np.arange(10.0))  # a few decimetres of fix noise
    lon = -73.0 + east / (111_320.0 * np.cos(np.deg2rad(45.0)))
    if swap_latlon:
        lat, lon = lon, lat
    if swap_velocity:
        vn, ve = ve, vn
    if radians:
        lat, lon = np.deg2rad(lat), np.deg2rad(lon)
    pd.DataFrame({"t": t, "lat": lat, "lon": lon, "h": 50.0, "fix": 2, "vn": vn, "ve": ve, "vd": 0.0}).to_csv(s / "gps.csv", index=False)


def gps_latlon_swapped(s):
    _moving_gps(s, swap_latlon=True)


def gps_latlon_in_radians(s):
    # audit (session 11): validate passed it; process blamed the gyro ("the gyro is in deg/s"), verdict unreliable
    _moving_gps(s, radians=True)


def gps_moving_as_given(s):
    _moving_gps(s)


def gps_velocity_columns_swapped(s):
    _moving_gps(s, swap_velocity=True)  # not a lat/lon swap: the check must not call it one


def gps_height_1e9(s):
    df = pd.read_csv(s / "gps.csv")
    df.assign(h=np.where(np.arange(len(df)) == 4, 1e9, df.h)).to_csv(s / "gps.csv", index=False)


def _targets_and_observer(s: Path, swap_targets: bool, swap_observer: bool) -> None:
    obs = (45.4946, -73.5622) if not swap_observer else (-73.5622, 45.4946)
    _toml_add(s, f"[observer]\nlat = {obs[0]}\nlon = {obs[1]}\nh = 40.0")
    lat, lon = np.array([45.49467, 45.49472]), np.array([-73.56207, -73.56218])
    if swap_targets:
        lat, lon = lon, lat
    targets = pd.DataFrame({"id": ["T1", "T2"], "lat": lat, "lon": lon, "h": [42.5, 45.0], "role": ["truth"] * 2})
    targets.to_csv(s / "targets.csv", index=False)


def targets_latlon_swapped(s):
    _targets_and_observer(s, swap_targets=True, swap_observer=False)


def observer_latlon_swapped(s):
    _targets_and_observer(s, swap_targets=False, swap_observer=True)


def targets_near_observer(s):
    _targets_and_observer(s, swap_targets=False, swap_observer=False)


def observer_height_in_mm(s):
    _toml_add(s, "[observer]\nlat = 45.4946\nlon = -73.5622\nh = 40000000.0")


CASES = [
    (fifo_imu, {}, "imu.csv", "FIFO"),
    (nul_hole_after_valid_rows, {}, "imu.csv, row 1001", "NUL bytes"),
    (gps_latlon_swapped, {}, "gps.csv: column 'lat'", "lat and lon look exchanged"),
    (gps_latlon_in_radians, {}, "gps.csv: column 'lat'", "lat and lon look like radians"),
    (gps_moving_as_given, {}, None, None),
    (gps_velocity_columns_swapped, {}, None, None),
    (gps_height_1e9, {}, "gps.csv: column 'h', row 5", "not an ellipsoidal height"),
    (targets_latlon_swapped, {}, "targets.csv: column 'lat', row 1", "lat and lon are exchanged"),
    (observer_latlon_swapped, {}, "targets.csv: column 'lat', row 1", "lat and lon are exchanged"),
    (targets_near_observer, {}, None, None),
    (observer_height_in_mm, {}, "session.toml", "[observer] h 4e+07 m is not an ellipsoidal height"),
    (dev_zero_imu, {}, "imu.csv", "device"),
    (sparse_nul_imu, {}, "imu.csv", "NUL bytes"),
    (parquet_with_many_rows, {}, "imu.parquet", "row limit"),
    (header_line_past_64_kib, {}, "imu.csv", "header line is longer than 64 KiB"),
    (data_line_of_100_mb, {}, "imu.csv, row 1001", "a line longer than 64 KiB"),
    (csv_with_1500_columns, {}, "imu.csv", "more than 1000 columns"),
    (parquet_with_1500_columns, {}, "imu.parquet", "1507 columns: more than 1000"),
    (bad_pandas_metadata, {}, None, None),  # never parsed: the columns are read through Arrow (io.columns)
    (deep_toml, {}, "session.toml", "nested too deeply"),
    (deep_tables, {}, "session.toml", "nested too deeply"),
    (section_as_scalar, {}, "session.toml", "gps must be a table"),
    (time_as_scalar, {}, "session.toml", "time must be a table"),
    (declination_1e308, {}, "session.toml", "declination_deg 1e+308 is outside"),
    (singular_soft_iron, {}, "session.toml", "soft_iron is singular"),
    (gps_outside_imu_span, {}, "gps.csv: column 't', row 1", "no position fix falls within the IMU's time span"),
    (gps_in_gps_week_seconds, {}, "gps.csv: column 't', row 1", "(fixes 345600.000-345609.000 s, IMU 1000.000-1009.990 s"),
    (imu_time_in_ms, {}, "imu.csv", "t is in milliseconds"),
    (acc_in_g_after_20_s, {"seconds": 40.0}, "imu.csv: column 'acc_x', row 2001", "that part is in g units"),
    (gps_time_in_ms, {}, "gps.csv: column 't', row 2", "divided by 1000 they fall within it: t is in milliseconds"),
    (gps_time_in_us, {}, "gps.csv: column 't', row 2", "t is in microseconds"),
    (odometry_time_in_ms, {}, "odometry.csv: column 't', row 2",
     "the rows span 1e+06-1.00995e+06 where the IMU spans 1000-1009.99 s; divided by 1000 they fall within it: t is in milliseconds"),
    (odometry_in_seconds, {}, None, None),
    (mag_in_nt, {}, "imu.csv: column 'mag_x'", "median |mag| is 5.29e+04, where the Earth's field is 22-67 µT"),
    (mag_in_gauss, {}, "imu.csv: column 'mag_x'", "it looks like gauss (multiply by 100); the contract requires µT"),
    (mag_in_tesla, {}, "imu.csv: column 'mag_x'", "it looks like tesla (multiply by 1e6); the contract requires µT"),
    (mag_all_zero, {}, "imu.csv: column 'mag_x'", "zero in every sample: no magnetometer reading"),
    (mag_in_ut, {}, None, None),
    (mag_in_milligauss, {}, None, "it looks like mG (milligauss)"),
    (ranges_in_mm, {"with_ranges": True}, "ranges.csv", "millimetres"),
    (duplicate_target_ids, {}, "targets.csv", "target id 'T1' appears twice"),
    (overlapping_shots, {}, "shots.csv", "shot windows overlap"),
]


@pytest.mark.parametrize("case,opts,fname,message", CASES, ids=[c[0].__name__ for c in CASES])
def test_hostile_session_ends_cleanly_within_time_and_memory(tmp_path, case, opts, fname, message, baseline_rss_kb):
    s = write_minimal_session(tmp_path / "s", **opts)
    case(s)
    res, peak_kb = _run_cli_bounded(["validate", str(s)], tmp_path, timeout_s=120.0)
    assert "Traceback" not in res.stderr and "internal error" not in res.stderr, res.stderr
    # the input adds less than 256 MB to what tpos needs on a valid session (well under 1 GB in all)
    assert peak_kb - baseline_rss_kb < 256 << 10, f"peak RSS {peak_kb} kB, valid session {baseline_rss_kb} kB"
    if fname is None:
        assert res.returncode == 0, res.stderr
        assert message is None or message in res.stdout
        return
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and fname in lines[0] and message in lines[0], lines


def test_gps_velocity_spans_are_built_once_for_both_checks(tmp_path, monkeypatch):
    """Review (session 11): the swap check and the radians check each built the fixes' velocity spans."""
    from tpos_cli.io import plausibility
    from tpos_cli.session import load_session

    s = write_minimal_session(tmp_path / "s")
    _moving_gps(s)
    calls = []
    build = plausibility.velocity_spans
    monkeypatch.setattr(plausibility, "velocity_spans", lambda *a: calls.append(1) or build(*a))
    load_session(s)
    assert len(calls) == 1


# ------------------------------------------------------------------ outputs never leave their directory

def test_pipeline_name_with_a_path_never_escapes_runs(tmp_path, monkeypatch):
    s = write_minimal_session(tmp_path / "s")
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "summary.json").write_text("{}")
    pipe = tmp_path / "evil.toml"
    pipe.write_text('[pipeline]\nname = "x/../../victim"\nchain = "ingest"\n[ingest]\n')
    monkeypatch.chdir(tmp_path / "s")
    res = runner.invoke(app, ["process", str(s), "-p", str(pipe)])
    assert res.exit_code == 2 and "cannot name a run directory" in res.output
    assert (victim / "summary.json").read_text() == "{}" and sorted(p.name for p in victim.iterdir()) == ["summary.json"]


def test_a_run_directory_inside_the_session_is_refused_before_the_work(tmp_path):
    """Outputs never go into their input: `-o` inside the session directory is exit 2, nothing written."""
    s = write_minimal_session(tmp_path / "s")
    before = sorted(p.name for p in s.iterdir())
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(s / "run")])
    assert res.exit_code == 2 and "inside the session directory" in res.output, res.output
    assert sorted(p.name for p in s.iterdir()) == before


# ------------------------------------------------------------------ outputs that cannot be written

@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_output_is_a_plain_exit_1_before_the_work(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(ro / "run")])
    assert res.exit_code == 1 and "cannot write the run directory" in res.output and "internal error" not in res.output


def test_full_disk_is_a_plain_exit_1(tmp_path, monkeypatch):
    s = write_minimal_session(tmp_path / "s")
    import tpos_cli.io.run_dir as rd

    def full(*a, **k):
        raise OSError(28, "No space left on device", str(tmp_path / "out" / "trajectory.parquet"))

    monkeypatch.setattr(rd.os, "fsync", full)  # the claim's test write meets a full disk
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(tmp_path / "out")])
    assert res.exit_code == 1 and "No space left on device" in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]  # no lock, probe or partial output left


def test_two_runs_to_one_directory_do_not_race(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    from tpos_cli.errors import TposError
    from tpos_cli.io.run_dir import claim_run_dir, run_dir_claims

    out = tmp_path / "run"
    with run_dir_claims():
        claim_run_dir(out)  # a first run holds the directory
        res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(out)])
        assert res.exit_code == 1 and "another tpos run is writing" in res.output
        with pytest.raises(TposError):
            claim_run_dir(out)
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "s"]  # no .lock, .old-PID or .tmp left


# ------------------------------------------------------------------ import never corrupts a session

POS = ("% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix)\n"
       "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns\n"
       "2021/06/15 12:00:00.000   45.500000000  -73.550000000    30.0000   5   9\n")


@pytest.mark.parametrize("extra", [
    '"operator name" = "Zoë"',
    "start_utc = 2021-06-15T12:00:00Z",
    "[[notes]]\ntext = \"first\"\n[[notes]]\ntext = \"second\"",
])
def test_import_keeps_session_toml_as_written(tmp_path, extra):
    s = write_minimal_session(tmp_path / "s", with_gps=False)
    text = (s / "session.toml").read_text().replace("[session]\n", "[session]\n" + extra.split("\n[[")[0] + "\n", 1)
    if "[[notes]]" in extra:
        text = (s / "session.toml").read_text() + "\n" + extra + "\n"
    (s / "session.toml").write_text(text)
    (tmp_path / "a.pos").write_text(POS)
    res = runner.invoke(app, ["import", "rtklib-pos", str(tmp_path / "a.pos"), "-o", str(s)])
    assert res.exit_code == 0, res.output
    after = (s / "session.toml").read_text()
    assert after == text  # nothing to add: the file is kept byte for byte
    assert (s / "gps.csv").exists()
    from tpos_cli.io.bounded import read_toml

    assert read_toml(s / "session.toml")["session"]["kind"] == "drive"


def test_import_refuses_before_writing_anything(tmp_path):
    s = write_minimal_session(tmp_path / "s", with_gps=False)
    _toml_top(s, "session = 1")  # invalid TOML (session defined twice): refused, nothing written
    before = {p.name: p.read_bytes() for p in s.iterdir()}
    (tmp_path / "a.pos").write_text(POS)
    res = runner.invoke(app, ["import", "rtklib-pos", str(tmp_path / "a.pos"), "-o", str(s)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert {p.name: p.read_bytes() for p in s.iterdir()} == before


# ------------------------------------------------------------------ TOML read by `process` before the session

def test_fifo_session_toml_is_refused_by_process_with_the_default_pipeline(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    (s / "session.toml").unlink()
    os.mkfifo(s / "session.toml")  # the default pipeline comes from [session] kind: read before the session
    res, _ = _run_cli_bounded(["process", str(s), "-o", str(tmp_path / "run")], tmp_path, timeout_s=60.0)
    assert res.returncode == 2 and "session.toml: is a FIFO" in res.stderr, res.stderr
    assert not (tmp_path / "run").exists()


def test_fifo_pipeline_file_is_refused(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    os.mkfifo(tmp_path / "p.toml")
    res, _ = _run_cli_bounded(["process", str(s), "-p", str(tmp_path / "p.toml"), "-o", str(tmp_path / "run")], tmp_path, timeout_s=60.0)
    assert res.returncode == 2 and "p.toml: is a FIFO" in res.stderr, res.stderr
    assert not (tmp_path / "run").exists()


def test_pipeline_file_nested_too_deeply_is_invalid_input(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    pipe = tmp_path / "deep.toml"
    pipe.write_text('[pipeline]\nname = "deep"\nchain = "ingest"\n[ingest]\nx = ' + "[" * 600 + "]" * 600 + "\n")
    res = runner.invoke(app, ["process", str(s), "-p", str(pipe), "-o", str(tmp_path / "run")])
    assert res.exit_code == 2 and "deep.toml: nested too deeply" in res.output and "internal error" not in res.output
    assert not (tmp_path / "run").exists()


def test_set_value_nested_too_deeply_is_a_usage_error(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "--set", "ingest.x=" + "[" * 600 + "]" * 600, "-o", str(tmp_path / "run")])
    assert res.exit_code == 2 and "nested too deeply" in res.output and "internal error" not in res.output
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------ CSV rows counted before decoding

def test_csv_with_more_rows_than_the_limit_is_refused_before_decoding(tmp_path, monkeypatch):
    import pandas as pd

    import tpos_cli.io.tables as tables

    s = write_minimal_session(tmp_path / "s")  # 1000 IMU rows
    monkeypatch.setattr(tables, "MAX_TABLE_ROWS", 500)
    real_read_csv = pd.read_csv

    def read_csv(path, *a, **k):
        assert Path(path).name != "imu.csv", "imu.csv decoded before its rows were counted"
        return real_read_csv(path, *a, **k)

    monkeypatch.setattr(pd, "read_csv", read_csv)  # io.tables imports pandas where it reads a CSV
    res = runner.invoke(app, ["validate", str(s)])
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and "imu.csv" in lines[0] and "more than 500 rows" in lines[0], lines


# ------------------------------------------------------------------ a disk that fills during the writing

def test_disk_full_while_writing_outputs_is_a_plain_exit_1_naming_the_run(tmp_path, monkeypatch):
    s = write_minimal_session(tmp_path / "s")
    import tpos_cli.io.run_dir as rd

    def full(*a, **k):  # what pyarrow raises: an OSError with no file name
        raise OSError("Error writing bytes to file. Detail: [errno 28] No space left on device")

    monkeypatch.setattr(rd.pq, "write_table", full)
    out = tmp_path / "out"
    res = runner.invoke(app, ["process", str(s), "-p", "drive-smooth", "-o", str(out)])
    assert res.exit_code == 1, res.output
    assert f"cannot write the run directory {out}" in res.output and "No space left" in res.output, res.output
    # audit (session 11): pyarrow's wording "Error writing bytes to file. Detail: [errno 28] ..." was passed on as is
    assert res.output.strip().endswith(f"cannot write the run directory {out}: No space left on device"), res.output
    assert "internal error" not in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]  # no partial run, lock or temporary directory


# ------------------------------------------------------------------ run directories read back (report, batch)

@pytest.mark.parametrize("command", ["report", "export"])
@pytest.mark.parametrize("make", ["fifo", "deep"])
def test_report_and_export_refuse_a_summary_json_that_is_a_fifo_or_nested_without_end(tmp_path, make, command):
    run = tmp_path / "run"
    run.mkdir()
    if make == "fifo":
        os.mkfifo(run / "summary.json")
    else:
        (run / "summary.json").write_text("[" * 100_000 + "]" * 100_000)
    res, _ = _run_cli_bounded([command, str(run)], tmp_path, timeout_s=60.0)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1 and "summary.json" in lines[0], res.stderr
    assert sorted(p.name for p in run.iterdir()) == ["summary.json"]


def test_batch_does_not_block_on_a_fifo_summary_json_of_an_earlier_run(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    (tmp_path / "out" / "s").mkdir(parents=True)
    os.mkfifo(tmp_path / "out" / "s" / "summary.json")  # not a finished run: processed again
    res, _ = _run_cli_bounded(["batch", str(s), "-o", str(tmp_path / "out"), "-p", "ingest", "-j", "1", "-q"], tmp_path, timeout_s=120.0)
    assert res.returncode == 0, (res.stdout, res.stderr)
    assert (tmp_path / "out" / "s" / "summary.json").is_file()


# ------------------------------------------------------------------ an IMU gap no INS can cross

def _imu_gap(s: Path, gap_s: float, tables: tuple[str, ...]) -> None:
    for name in tables:
        df = pd.read_csv(s / f"{name}.csv")
        df.assign(t=np.where(df.t > 1005.0, df.t + gap_s, df.t)).to_csv(s / f"{name}.csv", index=False)


@pytest.mark.parametrize("pipeline, opts, tables", [
    ("drive-smooth", {}, ("imu", "gps")),
    ("ranging-fatci", {"with_anchors": True}, ("imu", "anchor_ranges")),
])
def test_hour_long_imu_gap_is_refused_before_the_work(tmp_path, pipeline, opts, tables):
    s = write_minimal_session(tmp_path / "s", **opts)
    _imu_gap(s, 3600.0, tables)
    res = runner.invoke(app, ["process", str(s), "-p", pipeline, "-o", str(tmp_path / "run")])
    section = pipeline.replace("-", "_")
    assert res.exit_code == 2 and "a gap of 3600.0 s after sample 501" in res.output, res.output
    assert f"{section}.imu_gap_max_s = 1 s" in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]  # refused before the run directory was claimed


def test_short_imu_gap_is_still_processed(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    _imu_gap(s, 0.5, ("imu", "gps"))
    res = runner.invoke(app, ["process", str(s), "-p", "drive-smooth", "-o", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output


def test_toml_files_with_a_byte_order_mark_are_read(tmp_path):
    # audit (session 10): a session.toml saved by a Windows editor (UTF-8 with BOM) was refused as
    # "not valid TOML (Invalid statement (at line 1, column 1))"; the BOM is dropped, nothing else changes
    from tpos_cli.io.bounded import read_toml

    s = write_minimal_session(tmp_path / "s", with_gps=False)
    plain = (s / "session.toml").read_text()
    (s / "session.toml").write_bytes(b"\xef\xbb\xbf" + plain.encode())
    assert read_toml(s / "session.toml") == read_toml_text(plain)
    res = runner.invoke(app, ["validate", str(s)])
    assert res.exit_code == 0, res.output
    pipe = tmp_path / "p.toml"
    from tpos_cli.config import pipelines_dir

    pipe.write_bytes(b"\xef\xbb\xbf" + (pipelines_dir() / "ingest.toml").read_bytes())
    res = runner.invoke(app, ["process", str(s), "-p", str(pipe), "-o", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    # (processed before the import below: POS's one fix, at 216000 s of the GPS week, lies outside
    # this drive's IMU log, which a drive session refuses since session 11)
    (tmp_path / "a.pos").write_text(POS)  # an import into it merges with the file as read
    res = runner.invoke(app, ["import", "rtklib-pos", str(tmp_path / "a.pos"), "-o", str(s)])
    assert res.exit_code == 0, res.output
    assert read_toml(s / "session.toml")["session"] == read_toml_text(plain)["session"]
    (s / "session.toml").write_bytes(b"\xef\xbb\xbf\xef\xbb\xbf" + plain.encode())  # one mark only: a second is text
    res = runner.invoke(app, ["validate", str(s)])
    assert res.exit_code == 2 and "session.toml: not valid TOML" in res.output


def read_toml_text(text):
    import tomllib

    return tomllib.loads(text)


def test_times_that_cannot_resolve_the_samples_are_refused(tmp_path):
    # audit (session 10): a 100 Hz IMU with t rounded to 0.1 s kept 601 of 6000 samples ("5399 duplicate time
    # stamps; the first sample of each kept") with verdict ok; t as float32 near 1e5 s stamped every sample to 7.8 ms,
    # silently. Here t rounded to 0.1 s over 10 s: 101 distinct stamps of 1000
    from tpos_cli.session import load_session

    s = write_minimal_session(tmp_path / "round", t0=100000.0)
    imu = pd.read_csv(s / "imu.csv")
    imu.assign(t=imu["t"].round(1)).to_csv(s / "imu.csv", index=False)
    res = runner.invoke(app, ["validate", str(s)])
    assert res.exit_code == 2 and "imu.csv: column 't': 899 of 1000 samples repeat the time stamp before them" in res.output
    assert len(res.output.strip().splitlines()) == 1
    rows = pd.concat([imu, imu.iloc[::20]]).sort_values("t", kind="stable")  # a logger's repeated rows: kept first, counted
    rows.to_csv(s / "imu.csv", index=False)
    assert load_session(s).counts["duplicate_stamps_imu"] == 50
    f32 = write_minimal_session(tmp_path / "f32", fmt="parquet", t0=100000.0)
    imu = pd.read_parquet(f32 / "imu.parquet")
    imu.assign(t=imu["t"].astype("float32")).to_parquet(f32 / "imu.parquet", index=False)
    res = runner.invoke(app, ["validate", str(f32)])
    assert res.exit_code == 2 and "imu.parquet: column 't', row 1000: float32 holds t = 100010 s only to 0.0078 s" in res.output
    near0 = write_minimal_session(tmp_path / "near0", fmt="parquet", t0=0.0)  # float32 of t <= 10 s: to 1 us, fine
    imu = pd.read_parquet(near0 / "imu.parquet")
    imu.assign(t=imu["t"].astype("float32")).to_parquet(near0 / "imu.parquet", index=False)
    assert runner.invoke(app, ["validate", str(near0)]).exit_code == 0


def test_a_table_that_is_a_dangling_or_looping_link_is_named_as_such(tmp_path):
    # audit (session 10): imu.parquet linking to itself (or to a missing file) read "imu.*: missing: every session
    # needs imu.csv or imu.parquet", while the user sees the file there
    s = write_minimal_session(tmp_path / "s", fmt="parquet")
    (s / "imu.parquet").unlink()
    (s / "imu.parquet").symlink_to("imu.parquet")
    res = runner.invoke(app, ["validate", str(s)])
    assert res.exit_code == 2 and res.output.strip() == f"{s}/imu.parquet: a link that leads nowhere (a missing file or a loop)"
    (s / "imu.parquet").unlink()
    write_minimal_session(tmp_path / "t", fmt="parquet")
    (s / "imu.parquet").symlink_to(tmp_path / "t" / "imu.parquet")  # a link to a table is fine
    (s / "gps.parquet").unlink()
    (s / "gps.parquet").symlink_to(tmp_path / "nothing.parquet")
    res = runner.invoke(app, ["process", str(s), "-o", str(tmp_path / "run")])
    assert res.exit_code == 2 and "a link that leads nowhere" in res.output and not (tmp_path / "run").exists()


@pytest.mark.parametrize("lat_shift_deg", [0.0, 0.01])
def test_a_gps_duplicate_stamp_with_another_fix_is_counted_and_said(tmp_path, lat_shift_deg):
    # audit (session 12): a duplicate GPS stamp 1.1 km from the kept fix was one more "duplicate time stamp"
    from tpos_cli.session import load_session

    s = write_minimal_session(tmp_path / "s")
    g = pd.read_csv(s / "gps.csv")
    twin = g.iloc[[3]].assign(lat=g.lat[3] + lat_shift_deg)
    pd.concat([g.iloc[:4], twin, g.iloc[4:]]).to_csv(s / "gps.csv", index=False)
    ses = load_session(s)
    assert ses.counts["duplicate_stamps_gps"] == 1
    said = [w for w in ses.warnings if "share a time stamp" in w]
    if lat_shift_deg == 0.0:
        assert "gps_duplicate_conflicts" not in ses.counts and not said
        return
    assert ses.counts["gps_duplicate_conflicts"] == 1
    assert said == ["gps.csv: 1 rows share a time stamp with an earlier row but not its fix: up to 1.11e+03 m from the kept fix "
                    "(row 5); the first row of each time stamp is used"]


def _climbing_gps(s: Path, feet: bool, climb_m: float) -> None:
    """120 s of 1 Hz fixes on a road that climbs and descends `climb_m` (vd as logged), heights with 0.5 m of noise."""
    rng = np.random.default_rng(5)
    t = 1000.0 + np.arange(120.0)
    up = 0.5 * climb_m * (1.0 - np.cos(2 * np.pi * np.arange(120.0) / 60.0))
    vd = -0.5 * climb_m * (2 * np.pi / 60.0) * np.sin(2 * np.pi * np.arange(120.0) / 60.0)
    h = 50.0 + up + 0.5 * rng.standard_normal(120)
    lat = 45.0 + 10.0 * np.arange(120.0) / 111_132.0
    g = pd.DataFrame({"t": t, "lat": lat, "lon": -73.0, "h": h / 0.3048 if feet else h, "fix": 2, "vn": 10.0, "ve": 0.0, "vd": vd})
    g.to_csv(s / "gps.csv", index=False)


@pytest.mark.parametrize("feet,climb_m,refused", [(True, 30.0, True), (False, 30.0, False), (True, 0.0, False)])
def test_gps_heights_in_feet_are_refused_where_the_fixes_climb(tmp_path, feet, climb_m, refused):
    # audit (session 12): heights in feet passed validate and process (finding left by audit11); a log that climbs
    # tells them by vd (rtklibexplorer part 1 with h in feet: gain 3.29 +- 0.02); a flat one cannot (accepted)
    from tpos_cli.errors import InvalidInputError
    from tpos_cli.session import load_session

    s = write_minimal_session(tmp_path / "s", seconds=120.0)
    _climbing_gps(s, feet, climb_m)
    if not refused:
        load_session(s, with_imu=False)
        return
    with pytest.raises(InvalidInputError) as e:
        load_session(s, with_imu=False)
    assert "gps.csv: column 'h': h looks like feet: the fixes' height changes are 3.2" in str(e.value)
