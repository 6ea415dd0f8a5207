"""Session writer and `tpos simulate`: contract columns, round trip, TOML, CLI behaviour."""

import tomllib

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from typer.testing import CliRunner

from tpos_cli import schema
from tpos_cli.cli import app
from tpos_cli.errors import InvalidInputError
from tpos_cli.sim import simulate_drive, simulate_ranging, simulate_target

runner = CliRunner()

EXPECTED = {
    "drive": {"imu": schema.IMU_REQUIRED, "gps": schema.GPS_REQUIRED + schema.GPS_OPTIONAL,
              "truth": schema.TRUTH_REQUIRED + schema.TRUTH_OPTIONAL},
    "target": {"imu": schema.IMU_REQUIRED + schema.IMU_MAG, "ranges": schema.RANGES_REQUIRED,
               "targets": schema.TARGETS_REQUIRED + ("role",), "shots": schema.SHOTS_REQUIRED,
               "truth": schema.TRUTH_REQUIRED + schema.TRUTH_OPTIONAL},
    "ranging": {"imu": schema.IMU_REQUIRED, "anchors": ("id", "e", "n", "u"),
                "anchor_ranges": schema.ANCHOR_RANGES_REQUIRED,
                "range_calibration": schema.RANGE_CALIBRATION_REQUIRED,
                "truth": schema.TRUTH_REQUIRED + schema.TRUTH_OPTIONAL},
}


def _read(p):
    return pd.read_parquet(p) if p.suffix == ".parquet" else pd.read_csv(p)


@pytest.mark.parametrize("kind,fn", [("drive", simulate_drive), ("target", simulate_target), ("ranging", simulate_ranging)])
def test_written_tables_have_exactly_the_contract_columns(tmp_path, kind, fn):
    sim = fn(30.0, seed=1, t0_s=1000.0)
    out = sim.write(tmp_path / kind)
    files = {p.stem: p for p in out.iterdir() if p.name != "session.toml"}
    assert set(files) == set(EXPECTED[kind])
    for name, cols in EXPECTED[kind].items():
        assert set(_read(files[name]).columns) == set(cols), name
        if name in schema.TABLES_CSV_ONLY:
            assert files[name].suffix == ".csv"
    imu = _read(files["imu"])
    assert_allclose(imu["t"].to_numpy(), sim.imu.t_s + 1000.0, atol=0)
    truth = _read(files["truth"])
    assert_allclose(truth[["lat", "lon", "h"]].to_numpy(), sim.truth.lla, atol=0)  # float64 kept exactly
    assert_allclose(truth["yaw"].to_numpy(), np.degrees(sim.truth.rpy_rad[:, 2]), atol=0)
    meta = tomllib.loads((out / "session.toml").read_text())
    assert meta["session"]["kind"] == kind and meta["imu"]["rate_hz"] == 100.0
    for key in ("gyro_noise_dps", "gyro_bias_dph", "acc_noise_mg", "acc_bias_mg"):
        assert key in meta["imu"]


def test_csv_format_round_trips_to_the_same_numbers(tmp_path):
    sim = simulate_drive(20.0, seed=2)
    sim.write(tmp_path / "p")
    from tpos_cli.sim.writer import write_session

    write_session(sim, tmp_path / "c", fmt="csv")
    a = pd.read_parquet(tmp_path / "p" / "gps.parquet")
    b = pd.read_csv(tmp_path / "c" / "gps.csv")
    assert_allclose(a.to_numpy(dtype=float), b.to_numpy(dtype=float), atol=0)  # shortest round-trip repr is exact


def test_refuses_to_overwrite_without_force(tmp_path):
    sim = simulate_ranging(10.0, seed=0)
    sim.write(tmp_path / "s")
    with pytest.raises(InvalidInputError, match="already exists"):
        sim.write(tmp_path / "s")
    sim.write(tmp_path / "s", overwrite=True)


def test_overwrite_replaces_only_a_session(tmp_path, monkeypatch):
    """`write_session(overwrite=True)` (what `tpos simulate --force` calls) replaced any directory; a library
    caller passing a directory of other files lost them. Now only a session is replaced, and not the one
    holding the current directory (io.run_dir.check_session_out, the CLI's guard)."""
    sim = simulate_ranging(10.0, seed=0)
    other = tmp_path / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(InvalidInputError, match="is not a tpos session"):
        sim.write(other, overwrite=True)
    assert (other / "keep.txt").read_text() == "mine"
    (tmp_path / "f").write_text("x")
    with pytest.raises(InvalidInputError, match="is not a directory"):
        sim.write(tmp_path / "f", overwrite=True)
    s = sim.write(tmp_path / "s")
    (s / "sub").mkdir()
    monkeypatch.chdir(s / "sub")
    with pytest.raises(InvalidInputError, match="holds the current directory"):
        sim.write(s, overwrite=True)
    assert (s / "session.toml").is_file()


def test_cli_simulate_then_validate(tmp_path):
    res = runner.invoke(app, ["simulate", "drive", str(tmp_path / "d"), "--seed", "3", "--duration", "30",
                              "--outage", "5:3", "--outage", "20:2"])
    assert res.exit_code == 0, res.output
    gps = pd.read_parquet(tmp_path / "d" / "gps.parquet")
    assert len(gps) == 31 - 5
    assert runner.invoke(app, ["validate", str(tmp_path / "d")]).exit_code == 0
    # no progress output when stdout is not a terminal (CliRunner captures it)
    assert res.output.strip().splitlines() == [f"drive: wrote {tmp_path / 'd'} (seed 3)"]


def test_cli_rejects_options_of_another_scenario_and_existing_out(tmp_path):
    res = runner.invoke(app, ["simulate", "ranging", str(tmp_path / "r"), "--outage", "1:2"])
    assert res.exit_code == 2
    assert runner.invoke(app, ["simulate", "ranging", str(tmp_path / "r"), "--duration", "10"]).exit_code == 0
    res = runner.invoke(app, ["simulate", "ranging", str(tmp_path / "r"), "--duration", "10"])
    assert res.exit_code == 2 and "already exists" in res.output
    assert runner.invoke(app, ["simulate", "boat", str(tmp_path / "b")]).exit_code == 2
    assert runner.invoke(app, ["simulate", "target", str(tmp_path / "t"), "--grade", "bogus"]).exit_code == 2


def test_cli_help_has_an_example():
    res = runner.invoke(app, ["simulate", "--help"])
    assert res.exit_code == 0 and "Example" in res.output
