"""`tpos process` with the drive-smooth pipeline on a simulated drive session, end to end."""

import json

import numpy as np
import pandas as pd
import pytest

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.pipeline import process_session
from tpos_cli.sim.drive import simulate_drive

SIGMA_COLS = ["sigma_n", "sigma_e", "sigma_d", "sigma_vn", "sigma_ve", "sigma_vd", "sigma_roll", "sigma_pitch", "sigma_yaw"]


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    sim = simulate_drive(180.0, seed=7, outages=((90.0, 30.0),), t0_s=1000.0)
    return sim, sim.write(tmp_path_factory.mktemp("drive") / "s")


def test_process_writes_all_solutions(session_dir, tmp_path):
    sim, path = session_dir
    out = process_session(path, "drive-smooth", tmp_path / "run", overrides={"drive_smooth.compare": True})
    traj = pd.read_parquet(out.run_dir / "trajectory.parquet")
    names = set(traj["solution"])
    assert names == {"forward", "backward", "smoothed", "rts", "two_filter", "simplified"}
    for c in ["t", "lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "yaw", "outage", "flag", *SIGMA_COLS]:
        assert c in traj.columns
    assert np.isfinite(traj[SIGMA_COLS].to_numpy()).all() and (traj[SIGMA_COLS].to_numpy() > 0).all()
    sm = traj[traj["solution"] == "smoothed"]
    # t on the logger clock: the session starts at 1000 s
    assert sm["t"].iloc[0] == pytest.approx(1000.0)
    # outage rows marked: the 30 s outage between the last and the next fix, at 10 rows per second
    assert 290 <= sm["outage"].sum() <= 320
    # smoothed against the truth, horizontally, inside and outside the outage (issue 4 budgets,
    # with the filter's default 0.1 m/s GPS velocity SD, twice the simulator's)
    t_rel = sm["t"].to_numpy() - 1000.0
    truth_lla = np.column_stack([np.interp(t_rel, sim.truth.t_s, sim.truth.lla[:, i]) for i in range(3)])
    e = lla_to_ned(sm[["lat", "lon", "h"]].to_numpy(), truth_lla[0]) - lla_to_ned(truth_lla, truth_lla[0])
    eh = np.hypot(e[:, 0], e[:, 1])
    m = sm["outage"].to_numpy()
    assert np.sqrt(np.mean(eh[m] ** 2)) < 1.0
    assert np.sqrt(np.mean(eh[~m] ** 2)) < 0.6
    summary = json.loads((out.run_dir / "summary.json").read_text())
    res = summary["results"]
    assert res["smoothed_method"] == "rts"
    assert res["alignment"]["heading"].startswith("gps velocity")
    assert "forward" in summary["timings_s"] and "backward" in summary["timings_s"]


def test_mask_gps_makes_an_outage(session_dir, tmp_path):
    sim, path = session_dir
    out = process_session(path, "drive-smooth", tmp_path / "run", mask_gps_windows=[(1140.0, 1160.0)])
    traj = pd.read_parquet(out.run_dir / "trajectory.parquet")
    sm = traj[traj["solution"] == "smoothed"]
    t = sm["t"].to_numpy()
    assert sm["outage"].to_numpy()[(t > 1141.0) & (t < 1159.0)].all()
    assert (out.run_dir / "withheld_gps.parquet").exists()


def test_unknown_smoother_is_invalid_input(session_dir, tmp_path):
    _, path = session_dir
    with pytest.raises(InvalidInputError, match="smoother"):
        process_session(path, "drive-smooth", tmp_path / "run", overrides={"drive_smooth.smoother": "magic"})
