"""`tpos process` with the drive-smooth pipeline on a simulated drive session, end to end."""

import json

import numpy as np
import pandas as pd
import pytest

from tests.helpers.paths import SHARED_DATA
from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.pipeline import process_session
from tpos_cli.sim.drive import simulate_drive

SIGMA_COLS = ["sigma_n", "sigma_e", "sigma_d", "sigma_vn", "sigma_ve", "sigma_vd", "sigma_roll", "sigma_pitch", "sigma_yaw"]


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    sim = simulate_drive(180.0, seed=7, outages=((90.0, 30.0),), t0_s=1000.0)
    return sim, sim.write(tmp_path_factory.mktemp("drive") / "s")


def test_gyro_noise_counts_the_rotation_of_a_swaying_platform():
    """A gyro whose white noise is 0.05 deg/s on a platform turning back and forth at up to 40 deg/s
    (0.1 Hz): the filter's gyro noise is 1 % of the RMS rate (`fusion.constraints.rotation_gyro_noise_dps`),
    above the white noise that first differences measure; a still platform keeps its white noise."""
    from types import SimpleNamespace

    from tpos_cli.chains.drive_smooth import drive_imu_noise
    from tpos_cli.config import DriveSmoothParams

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 60.0, 1 / 160.0)
    white = np.radians(0.05) * rng.standard_normal((t.size, 3))
    acc = np.tile([0.0, 0.0, -9.81], (t.size, 1)) + 0.01 * rng.standard_normal((t.size, 3))
    sway = np.column_stack([np.radians(40.0) * np.sin(2 * np.pi * 0.1 * t), np.zeros((t.size, 2))])
    for gyro, expected in ((white + sway, 0.01 * 40.0 / np.sqrt(2.0)), (white, 0.05)):
        session = SimpleNamespace(imu=SimpleNamespace(gyro_b_rps=gyro, acc_b_mps2=acc), meta=SimpleNamespace(imu_noise=None))
        nz = drive_imu_noise(DriveSmoothParams(), session)
        assert nz["gyro_noise_dps"] == pytest.approx(expected, rel=0.05)


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


def test_mask_gps_windows_that_withhold_every_fix_are_refused(session_dir, tmp_path):
    """`--mask-gps` over the whole log: one line naming the windows (exit 2), before the run; it said
    "gps.parquet: no row holds a position fix (... in all 0 rows left)", blaming a file that is fine. A chain
    that runs without GPS (the target chain with an [observer] position) may have every fix withheld."""
    import dataclasses

    from tpos_cli.pipeline import chain_needs_gps, mask_gps
    from tpos_cli.session import load_session

    _, path = session_dir
    with pytest.raises(InvalidInputError, match=r"^--mask-gps 900:1100 --mask-gps 1100:1200: withholds all \d+ GPS fixes; "
                                                 r"keep some outside the windows$"):
        process_session(path, "drive-smooth", tmp_path / "run", mask_gps_windows=[(900.0, 1100.0), (1100.0, 1200.0)])
    assert not (tmp_path / "run").exists()
    s = load_session(path, with_truth=False)
    n = int(s.gps.valid.sum())
    assert chain_needs_gps("drive_smooth", s) and chain_needs_gps("target_fkf", s)  # no [observer]: GPS places it
    with pytest.raises(InvalidInputError, match=rf"withholds all {n} GPS fixes"):
        mask_gps(s, [(0.0, 5000.0)], gps_needed=True)
    s_obs = dataclasses.replace(s, meta=dataclasses.replace(s.meta, observer_lla=s.gps.lla[0]))
    assert not chain_needs_gps("target_fkf", s_obs) and not chain_needs_gps("ranging_fatci", s)
    masked, withheld = mask_gps(s_obs, [(0.0, 5000.0)], gps_needed=chain_needs_gps("target_fkf", s_obs))
    assert not masked.gps.valid.any() and masked.counts["gps_withheld_fixes"] == s.gps.t_s.size


def test_unknown_smoother_is_invalid_input(session_dir, tmp_path):
    _, path = session_dir
    with pytest.raises(InvalidInputError, match="smoother"):
        process_session(path, "drive-smooth", tmp_path / "run", overrides={"drive_smooth.smoother": "magic"})


def test_targets_from_the_moving_platform(session_dir):
    """Shots on roadside targets while the vehicle stands (static start) and while it drives."""
    import dataclasses

    from tpos_cli.chains.drive_smooth import geolocate_shots, process_drive, range_epochs
    from tpos_cli.config import DriveSmoothParams
    from tpos_cli.session import RangeData, Shots, load_session
    from tpos_cli.targeting import geolocate

    sim, path = session_dir
    session = load_session(path)
    tr = sim.truth
    rng = np.random.default_rng(5)
    d_m, sigma_r = 40.0, 0.05
    t_r, r_m, starts, targets = [], [], [], []
    for t_a in (5.0, 60.0, 140.0):  # standing, driving, driving
        i = int(np.searchsorted(tr.t_s, t_a))
        tgt = geolocate(tr.lla[i], tr.C_nb[i], d_m).lla[0]  # exact target on the beam
        targets.append(tgt)
        starts.append(t_a)
        t_r.append(tr.t_s[i])
        r_m.append(d_m + sigma_r * rng.standard_normal())
    ranges = RangeData(np.array(t_r), np.column_stack([r_m, np.full(3, np.nan), np.full(3, np.nan)]))
    shots = Shots(("a", "b", "c"), np.array(starts) - 0.001, np.array(starts) + 0.001)
    s2 = dataclasses.replace(session, ranges=ranges, shots=shots)
    ep = range_epochs(s2)
    res = process_drive(s2, DriveSmoothParams(), None, ("smoothed",), extra_idx=ep[0])
    out = geolocate_shots(s2, res.solutions["smoothed"], ep, sigma_r)
    for k, tgt in enumerate(targets):
        row = out.iloc[k]
        e = np.array([row.lat - tgt[0], row.lon - tgt[1]]) * np.radians(1.0) * 6.37e6
        e[1] *= np.cos(np.radians(tgt[0]))
        sd = np.array([row.sigma_n, row.sigma_e])
        assert np.all(np.abs(e) < 4.0 * sd)  # 4 sigma: 1 in 16 000 per component
        # paper 001 Eq. 17-30 first order: horizontal variance = observer position variance
        # + (d sigma_yaw)^2 across the beam + sigma_d^2 along it (level beam)
        sol = res.solutions["smoothed"]
        j = np.searchsorted(sol.idx, ep[0][k])
        P = sol.P9[j]
        var_att = d_m**2 * P[8, 8]  # yaw error phi_d rotates the beam about the vertical
        budget = np.trace(P[:2, :2]) + var_att + sigma_r**2
        np.testing.assert_allclose(row.sigma_n**2 + row.sigma_e**2, budget, rtol=0.05)  # pitch/roll terms < 5 %


def test_targets_parquet_from_simulated_roadside_shots(tmp_path):
    """`tpos simulate drive --shots` then `tpos process`: targets.parquet against the exact targets."""
    sim = simulate_drive(120.0, seed=3, outages=(), shots=4, shot_range_m=40.0)
    path = sim.write(tmp_path / "s")
    out = process_session(path, "drive-smooth", tmp_path / "run")
    tg = pd.read_parquet(out.run_dir / "targets.parquet")
    assert list(tg["id"]) == ["T1", "T2", "T3", "T4"] and (tg["solution"] == "smoothed").all()
    truth = sim.targets.lla
    e = lla_to_ned(tg[["lat", "lon", "h"]].to_numpy(), truth[0]) - lla_to_ned(truth, truth[0])
    sd = tg[["sigma_n", "sigma_e", "sigma_u"]].to_numpy()
    # 4 sigma per component (1 in 16 000) against the exact beam points
    assert np.all(np.abs(e) < 4.0 * sd), (e, sd)
    # the budget is the smoothed trajectory's, decimetres with 1.5 m GPS: not a vacuous bound
    assert np.all(sd[:, :2] < 0.6)
    summary = json.loads((out.run_dir / "summary.json").read_text())
    assert summary["counts"]["targets"] == 4


def test_innovations_table_columns(session_dir, tmp_path):
    _, path = session_dir
    out = process_session(path, "drive-smooth", tmp_path / "run")
    inn = pd.read_parquet(out.run_dir / "innovations.parquet")
    for c in ("t", "solution", "kind", "nis", "dof", "accepted"):
        assert c in inn.columns
    assert set(inn["solution"]) == {"forward", "backward"} and set(inn["kind"]) == {"gps_pos", "gps_vel"}
    assert (inn["dof"] == 3).all()
    # about one row per fix, run and kind (fixes before the first IMU sample are not processed)
    n_fix = json.loads((out.run_dir / "summary.json").read_text())["results"]["gps_fixes"]
    assert n_fix - 2 <= (inn["solution"].eq("forward") & inn["kind"].eq("gps_pos")).sum() <= n_fix


@pytest.mark.skipif(not (SHARED_DATA / "real" / "rtklibexplorer_walk_0827").exists(), reason="../shared not present")
def test_default_pipeline_on_a_real_walk(tmp_path):
    """A pedestrian never reaches a car's 3 m/s: the default pipeline must still align and track."""
    sdir = SHARED_DATA / "real" / "rtklibexplorer_walk_0827"
    out = process_session(sdir, None, tmp_path / "run")
    res = json.loads((out.run_dir / "summary.json").read_text())["results"]
    assert "yaw" in res["alignment"]["heading"] or "gps velocity" in res["alignment"]["heading"]
    traj = pd.read_parquet(out.run_dir / "trajectory.parquet")
    truth = pd.read_csv(sdir / "truth.csv")
    sm = traj[traj["solution"] == "smoothed"]
    lla = np.column_stack([np.interp(truth["t"], sm["t"], sm[c]) for c in ("lat", "lon", "h")])
    ref = truth[["lat", "lon", "h"]].to_numpy()
    e = lla_to_ned(lla, ref[0]) - lla_to_ned(ref, ref[0])
    # truth is the RTK solution the filter uses (floored to 0.3 m SD): smoothed within 0.3 m RMS
    assert np.sqrt(np.mean(np.hypot(e[:, 0], e[:, 1]) ** 2)) < 0.3
    # the walker stops: the NIS check also on the fixes at its stops and on those while moving (each fix in one)
    assert len(res["constraints"]["stop_intervals_s"]) == res["constraints"]["stops"] > 0
    for kind in ("gps_pos", "gps_vel"):
        chk = res["forward_nis_check"][kind]
        reg = chk["by_regime"]
        assert reg["standing"]["fixes"] > 0 and reg["moving"]["fixes"] > 0
        assert reg["standing"]["fixes"] + reg["moving"]["fixes"] == chk["fixes"]


def test_fixes_at_stops_are_classified_on_the_unrounded_stop_intervals():
    """The per-regime NIS check classes a fix as standing from the detected stops themselves, not the
    summary's copy rounded to 0.01 s: a fix 3 ms before a stop that starts at 12.004 s is moving
    (the rounded start, 12.00 s, took it in)."""
    from tpos_cli.chains.drive_smooth import _at_stops

    t = np.array([12.001, 12.004, 15.0, 20.0, 20.003, 30.0])
    got = _at_stops(t, np.array([[12.004, 20.0]]))
    assert got.tolist() == [False, True, True, True, False, False]
    assert _at_stops(t, np.zeros((0, 2))) is None and _at_stops(t, None) is None


def test_summary_stop_intervals_come_from_the_detected_stops_on_the_logger_clock():
    """summary.json's stops are written from `DriveResult.stop_intervals_s` (the one source): on the logger clock,
    rounded to 0.01 s, after "stops_from" as before; constraints without stops (or none) as they are."""
    from tpos_cli.chains.drive_smooth import _with_stop_intervals

    c = {"stops": 1, "stopped_s": 8.0, "stops_from": ["gps"], "platform": "car"}
    got = _with_stop_intervals(c, np.array([[12.004, 20.0]]), 1000.0)
    assert list(got) == ["stops", "stopped_s", "stops_from", "stop_intervals_s", "platform"]
    assert got["stop_intervals_s"] == [[1012.0, 1020.0]] and "stop_intervals_s" not in c
    assert _with_stop_intervals(c, np.zeros((0, 2)), 0.0)["stop_intervals_s"] == []
    assert _with_stop_intervals({}, np.zeros((0, 2)), 0.0) == {} and _with_stop_intervals(c, None, 0.0) is c


def test_summary_reports_gps_noise_nis_band_and_mounting(session_dir, tmp_path):
    """A correctly mounted simulated car: estimated GPS SDs = the simulated ones, no mounting warning."""
    _, path = session_dir
    out = process_session(path, "drive-smooth", tmp_path / "run")
    summary = json.loads((out.run_dir / "summary.json").read_text())
    res = summary["results"]
    g = res["alignment"]["gps_noise"]
    # the log's own SDs (1.5 m / 2.5 m) are consistent: the position scales stay 1
    assert g["sigma_pos_h_m"] == 1.5 and g["sigma_pos_v_m"] == 2.5
    # the pipeline's default 0.1 m/s is twice the simulated 0.05 m/s: found to 15% (~1000 components)
    assert g["sigma_vel_h_mps"] == pytest.approx(0.05, rel=0.15)
    assert res["forward_nis_check"]["gps_pos"]["inside"]
    m = res["mounting_check"]
    assert not m["warning"] and abs(m["course_minus_yaw_median_deg"]) < 2.0  # a car without sideslip
    assert not any(w.startswith("mounting") for w in summary["warnings"])


def test_imu_turned_90_deg_is_found_and_the_output_is_the_vehicle(tmp_path):
    """IMU x axis pointing to the car's right, no mounting in the session (issue 11 item 3): the
    travel direction gives the mounting (yaw +90 deg, the contract's convention), a trial pass
    with the non-holonomic constraint decides "car", and the trajectory's attitude is the car's:
    its yaw matches the truth, no mounting warning, positions as good as with an aligned IMU."""
    import dataclasses

    from tpos_cli.frames.rotation import euler_to_dcm

    sim = simulate_drive(150.0, seed=4, outages=())
    # the IMU frame is the car's body turned +90 deg about down: v_imu = C^T v_car
    C = euler_to_dcm(0.0, 0.0, np.radians(90.0))
    imu = dataclasses.replace(sim.imu, gyro_b_rps=sim.imu.gyro_b_rps @ C, acc_b_mps2=sim.imu.acc_b_mps2 @ C)
    path = dataclasses.replace(sim, imu=imu).write(tmp_path / "s")
    out = process_session(path, "drive-smooth", tmp_path / "run")
    summary = json.loads((out.run_dir / "summary.json").read_text())
    c = summary["results"]["constraints"]
    assert c["platform"] == "car" and c["mounting"]["source"].startswith("travel direction")
    rpy = np.array(c["mounting"]["mounting_rpy_deg"])
    assert np.all(np.abs(rpy - [0.0, 0.0, 90.0]) < 1.0), rpy  # 1 deg: the first pass's degree-level figure
    assert not summary["results"]["mounting_check"]["warning"]
    assert not [w for w in summary["warnings"] if w.startswith("mounting")]
    traj = pd.read_parquet(out.run_dir / "trajectory.parquet")
    sm = traj[traj["solution"] == "smoothed"]
    t_rel = sm["t"].to_numpy() - sim.t0_s
    yaw_true = np.degrees(np.interp(t_rel, sim.truth.t_s, np.unwrap(sim.truth.rpy_rad[:, 2])))
    dyaw = (sm["yaw"].to_numpy() - yaw_true + 180.0) % 360.0 - 180.0
    assert np.all(np.abs(dyaw) < 3.0 * sm["sigma_yaw"].to_numpy() + 0.05), np.abs(dyaw).max()
    truth_lla = np.column_stack([np.interp(t_rel, sim.truth.t_s, sim.truth.lla[:, i]) for i in range(3)])
    e = lla_to_ned(sm[["lat", "lon", "h"]].to_numpy(), truth_lla[0]) - lla_to_ned(truth_lla, truth_lla[0])
    assert np.sqrt(np.mean(np.hypot(e[:, 0], e[:, 1]) ** 2)) < 0.6  # the outside-outage budget


@pytest.mark.parametrize("d_s", [0.15, 0.0])
def test_gps_clock_offset_estimated_and_output_on_the_gps_clock(tmp_path, d_s):
    """A logger that stamps its GPS records d early (taken at IMU time t, stamped t - d): the
    filter's clock states find d within 3 SD, and when it is significant the trajectory's times
    move to the GPS clock, so a row at time T is the platform at IMU time T + d (issue 11)."""
    sim = simulate_drive(300.0, seed=21, outages=((150.0, 30.0),), gps_clock_offset_s=d_s, gps_sigma_h_m=0.1, gps_sigma_v_m=0.2)
    out = process_session(sim.write(tmp_path / "s"), "drive-smooth", tmp_path / "run")
    summary = json.loads((out.run_dir / "summary.json").read_text())
    c = summary["results"]["gps_clock_offset"]
    assert abs(c["estimate_s"] - d_s) < 3.0 * c["sigma_s"] and abs(c["velocity_estimate_s"] - d_s) < 3.0 * c["velocity_sigma_s"]
    assert c["sigma_s"] < 0.02  # 0.1 m fixes of a car turning and braking: the offset is observable
    assert c["output_clock"] == ("gps" if d_s else "imu")
    tr = pd.read_parquet(out.run_dir / "trajectory.parquet")
    s = tr[tr["solution"] == "smoothed"]
    t_imu = s["t"].to_numpy() + (d_s if c["output_clock"] == "gps" else 0.0)  # GPS time T is IMU time T + d
    lla = np.column_stack([np.interp(t_imu, sim.truth.t_s + sim.t0_s, sim.truth.lla[:, i]) for i in range(3)])
    e = lla_to_ned(s[["lat", "lon", "h"]].to_numpy(), lla[0]) - lla_to_ned(lla, lla[0])
    z = e[:, :2] / s[["sigma_n", "sigma_e"]].to_numpy()
    # 95 % of a consistent solution's rows lie inside 2 SD per axis (rows are correlated: 0.9 floor)
    assert np.mean(np.abs(z) < 2.0) > 0.9, np.mean(np.abs(z) < 2.0)
    if d_s:  # the GPS-clock rows against the truth at the same times would be metres off
        assert summary["quality"]["verdict"] == "suspect" and any("gps_offset_s = 0.1" in r for r in summary["quality"]["reasons"])


def test_a_car_log_as_real_ones_are(tmp_path):
    """What real car logs hold (issue 11 item 7), all at once and nothing of it in session.toml but
    the lever arm: the IMU turned (2 deg pitch, -4 deg yaw) on the car, the antenna 1.3 m away,
    30 mg of engine and road vibration, GPS stamped 0.08 s early, an odometer reading 2 % fast,
    RTK-like 0.1 m fixes. The default pipeline finds the mounting, the clock offset and the
    odometer scale, and the smoothed track and attitude are inside their own sigmas."""
    sim = simulate_drive(300.0, seed=5, outages=((150.0, 30.0),), gps_clock_offset_s=0.08, gps_sigma_h_m=0.1,
                         gps_sigma_v_m=0.2, mounting_rpy_deg=(0.0, 2.0, -4.0), lever_arm_m=(0.6, 0.0, -1.2),
                         vibration_mg=30.0, odometry_rate_hz=20.0, odometry_scale_error=0.02)
    out = process_session(sim.write(tmp_path / "s"), "drive-smooth", tmp_path / "run")
    summary = json.loads((out.run_dir / "summary.json").read_text())
    r = summary["results"]
    c = r["constraints"]
    assert c["platform"] == "car" and "odometry" in c
    # the first pass's mounting: 0.5 deg, the prior SD the filter's residual-misalignment states start from when given
    assert np.all(np.abs(np.array(c["mounting"]["mounting_rpy_deg"])[1:] - [2.0, -4.0]) < 0.5), c["mounting"]
    k = c["forward"]["odometer_scale_error"]
    assert abs(k["estimate"] - 0.02) < 3.0 * k["sigma"]
    clk = r["gps_clock_offset"]
    assert abs(clk["estimate_s"] - 0.08) < 3.0 * clk["sigma_s"] and clk["output_clock"] == "gps"
    assert any("gps_offset_s = 0.08" in s for s in summary["quality"]["reasons"])
    tr = pd.read_parquet(out.run_dir / "trajectory.parquet")
    s = tr[tr["solution"] == "smoothed"]
    t_imu = s["t"].to_numpy() + 0.08 - sim.t0_s  # GPS time T is IMU time T + d
    lla = np.column_stack([np.interp(t_imu, sim.truth.t_s, sim.truth.lla[:, i]) for i in range(3)])
    e = lla_to_ned(s[["lat", "lon", "h"]].to_numpy(), lla[0]) - lla_to_ned(lla, lla[0])
    inside = np.mean(np.abs(e[:, :2]) < 2.0 * s[["sigma_n", "sigma_e"]].to_numpy())
    assert inside > 0.9, inside  # 95 % for a consistent solution; rows are correlated: 0.9 floor
    yaw = np.degrees(np.interp(t_imu, sim.truth.t_s, np.unwrap(sim.truth.rpy_rad[:, 2])))
    dyaw = (s["yaw"].to_numpy() - yaw + 180.0) % 360.0 - 180.0  # the car's yaw, not the IMU's
    assert np.mean(np.abs(dyaw) < 2.0 * s["sigma_yaw"].to_numpy()) > 0.9


def test_a_lever_arm_the_session_does_not_state_is_estimated(tmp_path):
    """The antenna 0.8 m ahead of and 0.5 m right of the IMU, session.toml stating no lever arm (a
    user who never measured it), 2 cm RTK-like fixes. Unmodelled, that lever arm turns with the
    heading: the runs disagree at 22-40 % of epochs and the clock states take its forward part
    for a 0.05 s GPS clock offset (8 simulated drives). The default pipeline estimates the
    correction within 3 SD, flags at most the issue's 10 % of epochs, and blames no clock offset;
    the trajectory is at the stated point, here the antenna, its sigmas covering its errors
    (issue 11 item 4, issue 12)."""
    sim = simulate_drive(240.0, seed=3, outages=((150.0, 30.0),), gps_sigma_h_m=0.02, gps_sigma_v_m=0.03,
                         gps_sigma_vel_mps=0.02, lever_arm_m=(0.8, 0.5, 0.0))
    sdir = sim.write(tmp_path / "s")
    toml = (sdir / "session.toml").read_text()
    assert "lever_arm_m = [0.8, 0.5, 0.0]" in toml
    (sdir / "session.toml").write_text(toml.replace("lever_arm_m = [0.8, 0.5, 0.0]", "lever_arm_m = [0.0, 0.0, 0.0]"))
    out = process_session(sdir, "drive-smooth", tmp_path / "run")
    summary = json.loads((out.run_dir / "summary.json").read_text())
    r = summary["results"]
    la = r["lever_arm"]
    assert la["estimated"] and la["stated_m"] == [0.0, 0.0, 0.0], la
    est, sd = np.array(la["correction_forward_right_m"]), np.array(la["sigma_forward_right_m"])
    assert np.all(np.abs(est - [0.8, 0.5]) < 3.0 * sd) and np.all(sd < 0.1), la
    assert np.allclose(la["estimate_m"], [est[0], est[1], 0.0], atol=2e-3)  # no mounting: IMU axes = the car's
    assert r["flagged_fraction"] <= 0.10
    assert r["gps_clock_offset"]["output_clock"] == "imu"
    assert not any("gps_offset_s" in x for x in summary["quality"]["reasons"])
    tr = pd.read_parquet(out.run_dir / "trajectory.parquet")
    s = tr[tr["solution"] == "smoothed"]
    t = s["t"].to_numpy() - sim.t0_s
    lla = np.column_stack([np.interp(t, sim.truth.t_s, sim.truth.lla[:, i]) for i in range(3)])
    yaw = np.interp(t, sim.truth.t_s, np.unwrap(sim.truth.rpy_rad[:, 2]))
    antenna_ne = lla_to_ned(lla, lla[0])[:, :2] + np.column_stack([0.8 * np.cos(yaw) - 0.5 * np.sin(yaw),
                                                                   0.8 * np.sin(yaw) + 0.5 * np.cos(yaw)])
    e = lla_to_ned(s[["lat", "lon", "h"]].to_numpy(), lla[0])[:, :2] - antenna_ne
    o = s["outage"].to_numpy()
    # outside the outage the 2 cm fixes hold the antenna: the track is there, not at the IMU 0.94 m away
    assert np.sqrt(np.mean(np.sum(e[~o] ** 2, axis=1))) < 0.2
    # and the sigmas written with it cover its errors: 2 SD per axis holds 95 % of a consistent
    # solution's rows; 0.90 leaves room for the rows' correlation over one 240 s drive
    sd = s[["sigma_n", "sigma_e"]].to_numpy()
    k = t > 30.0  # after the yaw search
    assert np.mean(np.abs(e[k]) < 2.0 * sd[k]) >= 0.90


def test_fixes_without_sds_carry_their_stated_accuracy_in_the_sigmas(tmp_path, monkeypatch):
    """A receiver that logs no SDs and whose fixes wander (0.2 m white, 1 m common over 300 s): the
    reported position SDs add what the stated accuracy leaves beyond the matched white part, and
    no estimate moves (`drive_smooth.considered_fix_error`)."""
    import tpos_cli.chains.drive_smooth as ds
    from tpos_cli.config import DriveSmoothParams
    from tpos_cli.session import load_session

    sim = simulate_drive(240.0, seed=11, outages=((120.0, 30.0),), gps_sigma_h_m=0.2, gps_sigma_v_m=0.3,
                         gps_correlated_sigma_neu_m=(1.0, 1.0, 1.5), gps_correlated_tau_s=300.0)
    path = sim.write(tmp_path / "s")
    f = next(path.glob("gps.*"))
    d = pd.read_parquet(f) if f.suffix == ".parquet" else pd.read_csv(f)
    d = d.drop(columns=["sigma_n", "sigma_e", "sigma_u"])
    d.to_parquet(f, index=False) if f.suffix == ".parquet" else d.to_csv(f, index=False)
    session = load_session(path)
    p = DriveSmoothParams(gps_sigma_h_m=float(np.hypot(0.2, 1.0)), gps_sigma_v_m=float(np.hypot(0.3, 1.5)))
    res = ds.process_drive(session, p, None, names=("smoothed",))
    c = res.info["gps_considered_error"]
    white = ds.median_sigmas(res.fixes)
    assert c["sigma_h_m"] == pytest.approx(np.sqrt(p.gps_sigma_h_m**2 - white[0] ** 2), abs=1e-4)
    assert c["sigma_v_m"] == pytest.approx(np.sqrt(p.gps_sigma_v_m**2 - white[1] ** 2), abs=1e-4)
    monkeypatch.setattr(ds, "considered_fix_error", lambda *a: None)
    base = ds.process_drive(session, p, None, names=("smoothed",)).solutions["smoothed"]
    sol = res.solutions["smoothed"]
    np.testing.assert_array_equal(sol.nav, base.nav)
    added = np.diagonal(sol.P9, axis1=1, axis2=2)[:, :3] - np.diagonal(base.P9, axis1=1, axis2=2)[:, :3]
    np.testing.assert_allclose(added, np.broadcast_to([c["sigma_h_m"] ** 2] * 2 + [c["sigma_v_m"] ** 2], added.shape),
                               rtol=1e-3)
    # the common error is one draw per axis over this log: its 3-sigma bound holds with probability
    # 0.997 per axis; the white-only SDs (0.2 m) do not cover a 1 m wander
    e = sim.truth.navigation_errors(sol.idx, sol.nav, sol.C_nb)[:, :3]
    t = sim.truth.t_s[sol.idx]
    out = (t > 30.0) & ((t < 120.0) | (t >= 150.0))
    sd = np.sqrt(np.diagonal(sol.P9, axis1=1, axis2=2)[:, :3])
    sd0 = np.sqrt(np.diagonal(base.P9, axis1=1, axis2=2)[:, :3])
    assert np.mean(np.abs(e[out]) < 3.0 * sd[out]) > 0.99
    assert np.mean(np.abs(e[out]) < 3.0 * sd0[out]) < 0.5


def test_a_gps_table_without_any_fix_is_invalid_input(session_dir, tmp_path):
    """Every gps row empty: a one-line invalid-input error naming the file (exit 2), not a processing failure."""
    import shutil

    _, path = session_dir
    s = tmp_path / "s"
    shutil.copytree(path, s)
    f = next(s.glob("gps.*"))
    d = pd.read_parquet(f) if f.suffix == ".parquet" else pd.read_csv(f)
    d["lat"] = np.nan
    d.to_parquet(f, index=False) if f.suffix == ".parquet" else d.to_csv(f, index=False)
    with pytest.raises(InvalidInputError, match=rf"{f.name}: no row holds a position fix"):
        process_session(s, "drive-smooth", tmp_path / "run")
    assert not (tmp_path / "run").exists()


def test_unmodelled_errors_are_added_in_place_only_to_a_covariance_no_other_holds():
    """`owned_covariances`: a solution's P9 is added to in place only when it is its own array (not a
    view of a run's) and no other solution shares it (`smoothed` is `rts` renamed); the result is the
    same either way, and a P9 not owned is left as it was."""
    from tpos_cli.chains.drive_smooth import owned_covariances, with_unmodelled_errors
    from tpos_cli.trajectory import Solution

    rng = np.random.default_rng(1)
    k = 5
    C = np.tile(np.eye(3), (k, 1, 1))
    nav = np.zeros((k, 6))

    def sol(name, P9):
        return Solution(name, np.arange(k), nav, C, P9)

    held = rng.random((2 * k, 9, 9))
    rts = sol("rts", rng.random((k, 9, 9)))
    sols = {"forward": sol("forward", rng.random((k, 9, 9))), "rts": rts, "smoothed": rts.renamed("smoothed"),
            "backward": sol("backward", held[:k])}
    assert owned_covariances(sols) == {"forward": True, "rts": False, "smoothed": False, "backward": False}
    pos = np.array([1.0, 2.0, 3.0])
    vel = np.tile(np.diag([0.1, 0.2, 0.3]), (k, 1, 1))
    for name, s in sols.items():
        before = s.P9.copy()
        copied = with_unmodelled_errors(s, pos, vel)
        np.testing.assert_array_equal(s.P9, before)  # a copy: the input untouched
        if owned_covariances(sols)[name]:
            in_place = with_unmodelled_errors(s, pos, vel, owned=True)
            assert in_place.P9 is s.P9
            np.testing.assert_array_equal(in_place.P9, copied.P9)
    np.testing.assert_allclose(copied.P9[:, 3:6, 3:6] - held[:k, 3:6, 3:6], vel, rtol=0, atol=1e-15)  # rounding


@pytest.mark.parametrize("how", ["gps_clock", "offset"])
def test_gps_fixes_outside_the_imu_span_are_invalid_input(session_dir, tmp_path, how):
    """No fix within the IMU's time span (the GPS stamped on another clock, or a [time] gps_offset_s that
    moves it away): a one-line invalid-input error naming the file, the column and the likely cause
    (exit 2), before the run; the chain ran the whole log as dead reckoning, exit 0, verdict unreliable."""
    import shutil

    _, path = session_dir
    s = tmp_path / "s"
    shutil.copytree(path, s)
    f = next(s.glob("gps.*"))
    if how == "gps_clock":
        d = pd.read_parquet(f) if f.suffix == ".parquet" else pd.read_csv(f)
        d["t"] = d["t"] + 1.0e6
        d.to_parquet(f, index=False) if f.suffix == ".parquet" else d.to_csv(f, index=False)
    else:
        toml = s / "session.toml"
        assert "[time]" not in toml.read_text()
        toml.write_text(toml.read_text() + "\n[time]\ngps_offset_s = 1e9\n")
    with pytest.raises(InvalidInputError, match=rf"{f.name}: column 't', row 1: no position fix falls within the IMU's time "
                                                 r"span .*another clock \(the GPS clock, not the logger.s\) "
                                                 r"or \[time\] gps_offset_s is wrong"):
        process_session(s, "drive-smooth", tmp_path / "run")
    assert not (tmp_path / "run").exists()


def _stated_receiver(tmp_path, seed, white_h_m, white_v_m, correlated_m):
    """A simulated 180 s drive (40 s static start) whose receiver has a white error plus a
    Gauss-Markov one (tau 100 s, 1 Hz) and states their total in its sigma columns."""
    from tpos_cli.session import load_session

    sim = simulate_drive(180.0, seed=seed, outages=(), static_s=40.0, gps_sigma_h_m=white_h_m, gps_sigma_v_m=white_v_m,
                         gps_sigma_vel_mps=0.02, gps_correlated_sigma_neu_m=(correlated_m,) * 3, gps_correlated_tau_s=100.0)
    path = sim.write(tmp_path / f"s{seed}")
    f = next(path.glob("gps.*"))
    d = pd.read_parquet(f) if f.suffix == ".parquet" else pd.read_csv(f)
    d["sigma_n"] = d["sigma_e"] = np.hypot(white_h_m, correlated_m)
    d["sigma_u"] = np.hypot(white_v_m, correlated_m)
    d.to_parquet(f, index=False) if f.suffix == ".parquet" else d.to_csv(f, index=False)
    return sim, load_session(path)


def test_a_receiver_stating_its_correlated_error_gets_error_states_and_honest_sigmas_at_stops(tmp_path):
    """White 4 mm (h) / 6 mm (v) plus 9 mm correlated (tau 100 s), the receiver stating the total
    (9.8 / 10.8 mm): the default pipeline splits the stated SD (`gps_error_model = "stated_split"`)
    into the fixes' scatter at rest and error states. White fixes at the stated SD (the old default)
    let a stop's 40 fixes average the correlated part away: smoothed position SDs of 4.3-4.7 mm at
    the stops over a 9 mm error, NEES 4-6 (dof 3) there (4 drives)."""
    from scipy.stats import chi2

    import tpos_cli.chains.drive_smooth as ds
    from tpos_cli.config import DriveSmoothParams

    stop_nees, stop_k, move_nees, move_s = [], 0, [], 0.0
    for seed in range(1, 5):
        sim, session = _stated_receiver(tmp_path, seed, 0.004, 0.006, 0.009)
        res = ds.process_drive(session, DriveSmoothParams(gps_sigma_vel_mps=0.02), None, names=("smoothed",))
        s = res.info["gps_error_states"]
        # the white part from ~80 differences at rest: to about 10 % (1 / sqrt(2 n_eff)); 30 % allows the
        # correlated part's share of the differences; the budget leaves the rest to the states (~9 mm)
        assert s["white_h_m"] == pytest.approx(0.004, rel=0.3) and s["gm_h_m"] > 0.008 and s["gm_v_m"] > 0.008, s
        sol = res.solutions["smoothed"]
        t = sim.truth.t_s[sol.idx]
        e = sim.truth.navigation_errors(sol.idx, sol.nav, sol.C_nb)[:, :3]
        P = sol.P9[:, :3, :3]
        nees = np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])
        k = t > 30.0  # after the yaw search
        at_stop = np.zeros(t.size, bool)
        for a, b in res.stop_intervals_s:
            w = k & (t >= a) & (t <= b)
            if w.any():
                at_stop |= w
                stop_nees.append(nees[w].mean())
                stop_k += 1
            # a stop's fixes average their white part away, never their correlated one (common over a
            # stop shorter than tau): an SD under 9 mm there is overconfident; 10 % for the split's
            # estimate of that part from one stop's differences
            sd = np.sqrt(np.diagonal(P[w], axis1=1, axis2=2))
            assert np.all(sd >= 0.9 * 0.009), (seed, a, b, sd.min(axis=0))
        move_nees.append(nees[k & ~at_stop].mean())
        move_s += np.sum(k & ~at_stop) * float(np.median(np.diff(t)))
    # not overconfident: the correlated error is one draw per stop (a stop is shorter than tau), so the
    # mean of the stops' NEES is chi-square with 3 K d.o.f. over K; moving, one draw per 2 tau (200 s:
    # correlation e^-2) of moving time; each under its 99 % quantile
    assert np.mean(stop_nees) < chi2.ppf(0.99, 3 * stop_k) / stop_k, (stop_nees, stop_k)
    k_move = max(int(move_s // 200.0), 1)
    assert np.mean(move_nees) < chi2.ppf(0.99, 3 * k_move) / k_move, (move_nees, k_move)


def test_a_white_receiver_at_its_stated_sd_is_not_split(tmp_path):
    """The same drives with a white receiver stating its 9.8 / 10.8 mm: the fixes' scatter at rest is
    consistent with the stated SD (the split's chi-square test at 1 % per group), so no error states
    are added and the run is the white model's, bit for bit."""
    import tpos_cli.chains.drive_smooth as ds
    from tpos_cli.config import DriveSmoothParams

    for seed in range(1, 5):
        _, session = _stated_receiver(tmp_path, seed, float(np.hypot(0.004, 0.009)), float(np.hypot(0.006, 0.009)), 0.0)
        res = ds.process_drive(session, DriveSmoothParams(gps_sigma_vel_mps=0.02), None, names=("smoothed",))
        assert res.info["gps_error_states"]["gm_h_m"] == 0.0 and res.info["gps_error_states"]["gm_v_m"] == 0.0
        white = ds.process_drive(session, DriveSmoothParams(gps_sigma_vel_mps=0.02, gps_error_model="white"), None,
                                 names=("smoothed",))
        np.testing.assert_array_equal(res.solutions["smoothed"].nav, white.solutions["smoothed"].nav)
        np.testing.assert_array_equal(res.solutions["smoothed"].P9, white.solutions["smoothed"].P9)


def test_a_car_standing_with_an_unstated_lever_arm_has_fix_nis_in_band_at_its_stops(tmp_path):
    """A car (auto platform) standing 40 s at the start, its antenna 0.8 m ahead and 0.5 m right of the
    IMU and the session stating none, 2 cm fixes: at rest the heading is known to degrees and the
    lever-arm correction to its 1 m prior, and their second-order term (centimetres) is one constant
    over a stop. Counted at every fix it read the fixes' innovations as a fraction of their spread:
    mean NIS 1.77 at the stops (dof 3) over these 4 drives (c9aa0d1); taken once per stop it is in its
    band (2.66). (The moving fixes are as they were, 2.69-2.70, a hair under their own 99 % band for
    541 independent rows, [2.74, 3.28], before and after: not this test's subject.)"""
    from scipy.stats import chi2

    import tpos_cli.chains.drive_smooth as ds
    from tpos_cli.config import DriveSmoothParams
    from tpos_cli.session import load_session

    standing = []
    for seed in range(1, 5):
        sim = simulate_drive(180.0, seed=seed, outages=(), static_s=40.0, gps_sigma_h_m=0.02, gps_sigma_v_m=0.03,
                             gps_sigma_vel_mps=0.02, lever_arm_m=(0.8, 0.5, 0.0))
        sdir = sim.write(tmp_path / f"s{seed}")
        toml = (sdir / "session.toml").read_text()
        (sdir / "session.toml").write_text(toml.replace("lever_arm_m = [0.8, 0.5, 0.0]", "lever_arm_m = [0.0, 0.0, 0.0]"))
        res = ds.process_drive(load_session(sdir), DriveSmoothParams(), None, names=("smoothed",))
        assert res.info["constraints"]["platform"] == "car"
        gi = res.innovations("forward")
        ok = gi.accepted[:, 0] & np.isfinite(gi.nis[:, 0])
        ok[np.flatnonzero(ok)[:3]] = False  # the run's first fixes meet the prior (metres), not the model
        at_stop = ds._at_stops(res.fixes.t_s, res.stop_intervals_s)
        standing.append(gi.nis[ok & at_stop, 0])
    rows = np.concatenate(standing)
    # white simulated fixes: the rows of a consistent filter are independent draws of chi-square(3)
    lo, hi = chi2.ppf([0.005, 0.995], 3 * rows.size) / rows.size
    assert lo <= rows.mean() <= hi, (rows.mean(), rows.size, lo, hi)


def test_a_vibrating_car_without_zupt_has_fix_nis_in_band_at_its_stops(tmp_path):
    """Platform none (no ZUPT row at a stop), a car with 30 mg of engine vibration and a session that states
    no IMU noise: the run's white-noise figures are the moving car's vibration, which averages out over a
    second. At the stops the IMU's noise is the stop's own (`imu_noise.stop_noise_factors`, every
    platform); kept at the run's figures (b78f22b: wheeled platforms only) the velocity variance grew with
    the vibration between fixes and the GPS velocity rows at the stops sat under their band (mean NIS
    2.38 over these 4 drives, 99 % band [2.54, 3.51]; 3.20 with the stops' own noise). Such a still stop
    holds the attitude: the yaw x lever-arm second-order term is one constant there, as on a wheeled
    vehicle's stop; counted at every standing fix it took the position rows under (2.12; 3.09 without)."""
    import re

    from scipy.stats import chi2

    import tpos_cli.chains.drive_smooth as ds
    from tpos_cli.config import DriveSmoothParams
    from tpos_cli.session import load_session

    standing = {0: [], 1: []}
    for seed in range(1, 5):
        sim = simulate_drive(150.0, seed=seed, outages=(), static_s=40.0, gps_sigma_h_m=0.02, gps_sigma_v_m=0.03,
                             gps_sigma_vel_mps=0.02, vibration_mg=30.0)
        sdir = sim.write(tmp_path / f"s{seed}")
        toml = (sdir / "session.toml").read_text()
        (sdir / "session.toml").write_text(re.sub(r"^(gyro_noise_dps|acc_noise_mg) = .*\n", "", toml, flags=re.M))
        res = ds.process_drive(load_session(sdir), DriveSmoothParams(platform="none"), None, names=("smoothed",))
        assert res.info["imu_noise"]["acc_noise_mg"]["source"].startswith("measured from the log")
        gi = res.innovations("forward")
        at_stop = ds._at_stops(res.fixes.t_s, res.stop_intervals_s)
        for j in (0, 1):
            ok = gi.accepted[:, j] & np.isfinite(gi.nis[:, j])
            ok[np.flatnonzero(ok)[:3]] = False  # the run's first fixes meet the prior (metres), not the model
            standing[j].append(gi.nis[ok & at_stop, j])
    for j in (0, 1):  # position, velocity
        rows = np.concatenate(standing[j])
        # white simulated fixes: the rows of a consistent filter are independent draws of chi-square(3)
        lo, hi = chi2.ppf([0.005, 0.995], 3 * rows.size) / rows.size
        assert lo <= rows.mean() <= hi, (j, rows.mean(), rows.size, lo, hi)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_rtk_float_stretches_kept_with_their_offset_state_leave_the_runs_agreeing(tmp_path, seed):
    """An RTK receiver (`simulate_drive(gps_rtk=True)`, 4 Hz) falls back to float 3 times a minute: its stated
    SD rises 1.2-2.6 x while its fixes sit 15-25 cm off (a Gauss-Markov offset, tau 5 s). The pipeline keeps
    those fixes with the float offset state on their position rows (`fusion.rtk_float`): the forward and
    backward runs agree through the stretches. Taken as white at their stated SD (d7e0e10, or
    gps_float_sd_factor 0) each run follows them and the runs disagree on 2.9 / 3.3 / 13.6 % of the rows
    (seeds 3 / 2 / 1; 0.42 / 0 / 0 % with the state)."""
    import tpos_cli.chains.drive_smooth as ds
    from tpos_cli.config import DriveSmoothParams
    from tpos_cli.session import load_session
    from tpos_cli.timebase import in_intervals

    sim = simulate_drive(120.0, seed=seed, gps_rtk=True, gps_rate_hz=4.0, outages=(), gps_rtk_float_per_min=3.0,
                         gps_rtk_multipath_per_min=0.0, gps_rtk_float_offset_m=(0.15, 0.25))
    res = ds.process_drive(load_session(sim.write(tmp_path / "s")), DriveSmoothParams(), None, names=("smoothed",))
    rtk = sim.gps.rtk
    t_gps = sim.gps.t_s
    # no fixed epoch classed; every stretch raised past the class's 1.5 x floor classed whole (those raised 1.2-1.5 x
    # are within what geometry does to a fixed SD and stay white: `rtk_float.FLOAT_SD_FACTOR`)
    assert not in_intervals(t_gps[rtk.regime == 0], res.fixes.float_intervals_s, closed=True).any()
    loud = np.zeros(t_gps.size, dtype=bool)
    for (a, b), f in zip(rtk.float_s, rtk.float_sd_factor):
        loud |= (t_gps >= a) & (t_gps < b) & (f > 1.5)
    assert loud.any() and in_intervals(t_gps[loud], res.fixes.float_intervals_s, closed=True).all()
    # the disagreement flag tests at 99.9 %: a consistent pair flags ~0.1 % of rows; 1 %, ten times that, as
    # the rows are correlated over seconds (one chance episode is a few tenths of a per cent of 120 s)
    assert np.mean(res.flag) < 0.01, np.mean(res.flag)
