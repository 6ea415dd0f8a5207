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


def imu_time_in_ms(s):
    df = pd.read_csv(s / "imu.csv")
    df.assign(t=df.t * 1000.0).to_csv(s / "imu.csv", index=False)


def ranges_in_mm(s):
    df = pd.read_csv(s / "ranges.csv")
    df.assign(d1=df.d1 * 1000, d2=df.d2 * 1000, d3=df.d3 * 1000).to_csv(s / "ranges.csv", index=False)


def duplicate_target_ids(s):
    pd.DataFrame({"id": ["T1", "T2", "T1"], "lat": [45.0, 45.001, 45.01], "lon": [-73.0] * 3, "h": [10.0] * 3,
                  "role": ["truth"] * 3}).to_csv(s / "targets.csv", index=False)


def overlapping_shots(s):
    pd.DataFrame({"id": ["T1", "T2"], "t_start": [1001.0, 1003.0], "t_end": [1004.0, 1006.0]}).to_csv(s / "shots.csv", index=False)


CASES = [
    (fifo_imu, {}, "imu.csv", "FIFO"),
    (dev_zero_imu, {}, "imu.csv", "device"),
    (sparse_nul_imu, {}, "imu.csv", "NUL bytes"),
    (parquet_with_many_rows, {}, "imu.parquet", "row limit"),
    (bad_pandas_metadata, {}, "gps.parquet", "not a readable Parquet file"),
    (deep_toml, {}, "session.toml", "nested too deeply"),
    (deep_tables, {}, "session.toml", "nested too deeply"),
    (section_as_scalar, {}, "session.toml", "gps must be a table"),
    (time_as_scalar, {}, "session.toml", "time must be a table"),
    (declination_1e308, {}, "session.toml", "declination_deg 1e+308 is outside"),
    (singular_soft_iron, {}, "session.toml", "soft_iron is singular"),
    (gps_outside_imu_span, {}, None, "no GPS fix falls within the IMU's time span"),  # a warning: the verdict names it
    (imu_time_in_ms, {}, "imu.csv", "t is in milliseconds"),
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
