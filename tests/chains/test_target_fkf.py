import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from typer.testing import CliRunner

from tpos_cli.cli import app
from tpos_cli.frames import geodetic
from tpos_cli.pipeline import process_session
from tpos_cli.sim.target import simulate_target
from tpos_cli.sim.writer import write_session

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"


def _errors(sim, run_dir):
    tg = pd.read_parquet(run_dir / "targets.parquet")
    truth = dict(zip(sim.targets.ids, sim.targets.lla))
    tg = tg[tg.id.isin(truth)]
    e = [float(np.linalg.norm(geodetic.lla_to_ned(np.array([r.lat, r.lon, r.h]), truth[r.id]))) for r in tg.itertuples()]
    return tg.assign(err=e).groupby("solution").err.mean()


@pytest.mark.parametrize("dist_ut", [0.0, 50.0])
def test_sim_target_session_meets_issue_goals(tmp_path, dist_ut):
    sim = simulate_target(90.0, seed=3, mag_disturbance_ut=dist_ut, mag_disturbance_start_s=10.0)
    d = write_session(sim, tmp_path / "s", overwrite=True)
    rs = process_session(d, "target-fkf", tmp_path / "run")
    traj = pd.read_parquet(rs.run_dir / "trajectory.parquet")
    assert set(traj.solution) == {"gyro", "lf1", "lf2", "fkf", "fkf_raw", "fkf_cal"}
    assert {"sigma_roll", "sigma_pitch", "sigma_yaw"} <= set(traj.columns)
    pairs = pd.read_parquet(rs.run_dir / "targets_pairs.parquet")
    assert (pairs.slant_range_m > 0).all()
    e = _errors(sim, rs.run_dir)
    if dist_ut == 0.0:
        assert e["fkf"] <= 0.02  # issue goal (3-D mean, targets 10-15 m)
    else:
        assert e["fkf"] <= 0.03 and e["fkf"] <= max(1.2 * e["lf2"], e["lf2"] + 0.005)  # issue goals


def test_real_marg_log_without_ranges_gives_attitude_only(tmp_path):
    d = REAL / "broad_02_undisturbed_slow_rotation_B"
    if not d.exists():
        pytest.skip("shared real logs not present")
    rs = process_session(d, "target-fkf", tmp_path / "run")
    traj = pd.read_parquet(rs.run_dir / "trajectory.parquet")
    assert set(traj.solution) == {"gyro", "lf1", "fkf"}
    assert any("LF2 needs the three rangefinders" in w for w in rs.summary["warnings"])


@pytest.mark.parametrize("roll_deg", [20.0, -35.0])
def test_full_model_handles_a_rolled_swaying_device(tmp_path, roll_deg):
    # a hand-held device held at a roll with a 0.5 deg sway (7 s period; slow enough to align)
    sim = simulate_target(90.0, seed=3, roll_deg=roll_deg, roll_sway_deg=0.5)
    d = write_session(sim, tmp_path / "s", overwrite=True)
    rs = process_session(d, "target-fkf", tmp_path / "run")
    e = _errors(sim, rs.run_dir)
    # the issue's goal holds at any roll; measured 0.0200 m (roll 20) and 0.0180 m (-35) from d381ca7 to 325b0d6,
    # when the alignments levelled the sway's mean attitude and called it the window's edge sample (0.1-0.4 deg
    # off); 0.0035 / 0.0053 m since they level the edge sample (`alignment.held_at`, notes marg12.md)
    assert e["fkf"] <= 0.02
    assert abs(rs.summary["results"]["alignment"]["roll_deg"] - roll_deg) < 0.6  # levelling within the sway


def test_paper8_model_through_the_chain(tmp_path):
    sim = simulate_target(90.0, seed=3)  # the paper's zero-roll tripod setting
    d = write_session(sim, tmp_path / "s", overwrite=True)
    rs = process_session(d, "target-fkf", tmp_path / "run", overrides={"target_fkf.model": "paper8"})
    assert rs.summary["results"]["model"] == "paper8"
    e = _errors(sim, rs.run_dir)
    assert e["fkf"] <= 0.02 and e["lf2"] <= 0.02  # same goal as the full model at zero roll (~0.009 m)


def test_shots_detected_without_shots_csv(tmp_path):
    # windows where the 0.5 s mean rate is below shot_gyro_tol_dps with LR1 returns, >= shot_min_s
    sim = simulate_target(90.0, seed=3)
    d = write_session(dataclasses.replace(sim, shots=None), tmp_path / "s", overwrite=True)
    assert not any(p.name.startswith("shots") for p in d.iterdir())
    rs = process_session(d, "target-fkf", tmp_path / "run")
    tg = pd.read_parquet(rs.run_dir / "targets.parquet")
    fkf = tg[tg.solution == "fkf"]
    assert len(fkf) == len(sim.shots.ids)  # one detected window per hold
    for r in fkf.itertuples():
        assert r.id.startswith("auto_")
        # each detected window starts within 0.3 s of a true hold (the smoothstep slews end with rates
        # below the 0.5 deg/s threshold) and covers it (t on the logger clock, t0 = 0 here)
        assert any(abs(r.t_start - a) < 0.3 and r.t_end > b - 0.3 for a, b in zip(sim.shots.t_start_s, sim.shots.t_end_s))
        e = min(np.linalg.norm(geodetic.lla_to_ned(np.array([r.lat, r.lon, r.h]), p)) for p in sim.targets.lla)
        assert e < 0.03  # lands on a simulated target (fkf accuracy ~0.01 m)


def test_cli_writes_contract_columns(tmp_path):
    sim = simulate_target(60.0, seed=4)
    d = write_session(sim, tmp_path / "s", overwrite=True)
    res = CliRunner().invoke(app, ["process", str(d), "-o", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    tg = pd.read_parquet(tmp_path / "run" / "targets.parquet")
    assert list(tg.columns) == ["id", "t_start", "t_end", "range_m", "lat", "lon", "h", "solution",
                                "sigma_n", "sigma_e", "sigma_u", "cov_ne_m2", "cov_nu_m2", "cov_eu_m2"]
    assert set(tg.solution) == {"gyro", "lf1", "lf2", "fkf", "fkf_raw", "fkf_cal"}
    assert (tg[["sigma_n", "sigma_e", "sigma_u"]] > 0).all().all()
    # the full covariance of each target (north, east, up) is a covariance: symmetric positive definite
    for r in tg.itertuples():
        P = np.array([[r.sigma_n**2, r.cov_ne_m2, r.cov_nu_m2], [r.cov_ne_m2, r.sigma_e**2, r.cov_eu_m2],
                      [r.cov_nu_m2, r.cov_eu_m2, r.sigma_u**2]])
        assert np.all(np.linalg.eigvalsh(P) > 0), r
    pairs = pd.read_parquet(tmp_path / "run" / "targets_pairs.parquet")
    assert list(pairs.columns) == ["id_1", "id_2", "solution", "slant_range_m", "dh_m", "horizontal_m",
                                   "sigma_slant_m", "sigma_dh_m"]
    n = tg[tg.solution == "fkf"].id.nunique()
    assert (pairs.solution == "fkf").sum() == n * (n - 1) // 2


def test_an_hour_long_imu_gap_is_refused_with_a_one_line_message(tmp_path):
    # the gyro did not record the turns made during the gap: no attitude after it can be honest
    sim = simulate_target(60.0, seed=4)
    d = write_session(sim, tmp_path / "s", overwrite=True)
    imu = pd.read_parquet(d / "imu.parquet")
    tcol = imu.columns[0]
    k = len(imu) // 2
    imu.loc[k:, tcol] = imu.loc[k:, tcol] + 3600.0
    imu.to_parquet(d / "imu.parquet", index=False)
    res = CliRunner().invoke(app, ["process", str(d), "-o", str(tmp_path / "run")])
    assert res.exit_code == 2, res.output
    msg = res.output.strip().splitlines()
    assert any("imu: a gap of 3600.0 s" in m and "split the log" in m for m in msg), res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "run").exists()  # no partial output


def _target_nees(tmp_path, seeds, solution, grade="mems"):
    from scipy.stats import chi2
    nees = []
    for seed in seeds:
        sim = simulate_target(90.0, seed=seed, grade=grade)
        d = write_session(sim, tmp_path / f"s{seed}", overwrite=True)
        rs = process_session(d, "target-fkf", tmp_path / f"run{seed}")
        tg = pd.read_parquet(rs.run_dir / "targets.parquet")
        truth = dict(zip(sim.targets.ids, sim.targets.lla))
        for r in tg[(tg.solution == solution) & tg.id.isin(truth)].itertuples():
            e = geodetic.lla_to_ned(np.array([r.lat, r.lon, r.h]), truth[r.id])
            P = np.array([[r.sigma_n**2, r.cov_ne_m2, -r.cov_nu_m2], [r.cov_ne_m2, r.sigma_e**2, -r.cov_eu_m2],
                          [-r.cov_nu_m2, -r.cov_eu_m2, r.sigma_u**2]])
            nees.append(float(e @ np.linalg.solve(P, e)))
    nees = np.array(nees)
    return np.mean(nees < chi2.ppf(0.95, 3)), nees.mean() / 3


@pytest.mark.parametrize("grade", ["mems", "paper"])
@pytest.mark.parametrize("solution", ["fkf", "fkf_cal"])
def test_target_sigmas_match_their_errors(tmp_path, solution, grade):
    # issue 12: consumer-MEMS sessions (10 mg accelerometer bias: half a degree of levelling error and,
    # through the dip, about a degree and a half of magnetic heading, of which the filters learn part
    # as the device turns) give 0.1-0.5 m target errors; each target's own covariance (targets.parquet,
    # full 3x3) must match them: >= 80 % inside the 95 % ellipsoid and mean NEES per dof within [0.3, 2]
    # (the issue's criterion, neither over-confident nor conservative), 3 sessions, 21 targets; the same
    # on the paper grade (0.1 mg: millimetre errors from the gyro, range noise and the alignment)
    inside, nees_dof = _target_nees(tmp_path, (31, 32, 33), solution, grade)
    assert inside >= 0.8 and 0.3 <= nees_dof <= 2.0, (inside, nees_dof)


def test_carried_attitude_of_a_still_device_stays_put():
    # the backward run's fallback start (`_align_at_end`) carries the start alignment by the gyro: a still
    # device's gyro reads the bias and the Earth rate (15 deg/h, 0.27 deg of heading over 90 s at 45 deg
    # latitude, which the carry used to keep), so the carried attitude must not move
    from tpos_cli.chains.target_fkf import _carry
    from tpos_cli.frames import earth
    from tpos_cli.frames.rotation import dcm_to_rotvec, euler_to_dcm

    lat = np.radians(45.5)
    w_ie = earth.earth_rate_ned_rps(lat)
    C0 = euler_to_dcm(0.1, -0.2, 0.7)
    bias = np.radians([5.0, -3.0, 4.0]) / 3600.0
    t = np.arange(0.0, 90.0, 0.01)
    gyro = np.tile(C0.T @ w_ie + bias, (t.size, 1))
    C = _carry(C0, bias, t, gyro, 0, t.size - 1, w_ie)
    assert np.degrees(np.linalg.norm(dcm_to_rotvec(C @ C0.T))) < 1e-6
    back = _carry(C, bias, t, gyro, t.size - 1, 0, w_ie)
    assert np.degrees(np.linalg.norm(dcm_to_rotvec(back @ C0.T))) < 1e-6


def test_heading_with_the_field_unused_on_most_samples_takes_the_refused_fields_disagreement():
    # a solution whose runs used the field on 20 % of the samples only, while the refused field puts the
    # heading 10 deg off: its heading variance gains (10 deg)^2 and the run says so; at 60 % used nothing changes
    from tpos_cli.attitude.local import AttitudeSolution
    from tpos_cli.attitude.magfield import reference_field_ned
    from tpos_cli.chains.context import RunContext
    from tpos_cli.chains.target_fkf import unsupported_heading
    from tpos_cli.frames.rotation import euler_to_dcm

    n = 100
    C = euler_to_dcm(np.zeros(n), np.zeros(n), np.linspace(0.0, 3.0, n))
    m_b = np.einsum("nji,j->ni", C, reference_field_ned(48.0, np.radians(65.0), np.radians(10.0)))
    P = np.tile(np.eye(3) * 1e-6, (n, 1, 1))
    for used, grows in ((0.2, True), (0.6, False)):
        sol = AttitudeSolution("lf1", np.arange(n, dtype=float), C, P, mag_any=np.arange(n) < used * n)
        ctx, summary = RunContext(), {}
        out = unsupported_heading({"lf1": sol}, m_b, 0.0, ctx, summary)["lf1"]
        assert summary["magnetometer_unused_share"] == pytest.approx(1.0 - used)
        added = out.P_att[:, 2, 2] - P[:, 2, 2]
        assert np.allclose(added, np.radians(10.0) ** 2 if grows else 0.0, rtol=1e-9, atol=1e-15)
        assert np.allclose(out.P_att[:, :2, :2], P[:, :2, :2])
        assert bool(ctx.warnings) == grows
        if grows:  # one sentence for the console warning and the verdict's reason (quality.unsupported_heading_text)
            from tpos_cli.quality import magnetometer_support_findings

            assert list(ctx.warnings) == [f.reason for f in magnetometer_support_findings(summary)]


def test_heading_of_an_alignment_whose_field_may_hold_an_offset_takes_that_offset():
    # the survey separated a 15 uT offset whose field left is not the reference (magnet present from the start):
    # lf1's heading variance gains (15 / H)^2; a start window the survey masked as disturbed gains its gap at least
    from types import SimpleNamespace

    from tpos_cli.attitude.local import AttitudeSolution
    from tpos_cli.attitude.magfield import FieldSurvey, FieldWindow
    from tpos_cli.chains.context import RunContext
    from tpos_cli.chains.target_fkf import unresolved_offset_heading

    n = 10
    sol = AttitudeSolution("lf1", np.arange(n, dtype=float), np.tile(np.eye(3), (n, 1, 1)), np.tile(np.eye(3) * 1e-6, (n, 1, 1)))
    off = np.array([9.0, -7.2, 9.6])
    body = [FieldWindow(0, n, 2.0, 0.3, off, 0.1, True, 45.0, 1.15) for _ in range(3)]
    still = [FieldWindow(0, n, 0.3, 0.3, np.zeros(3), 5.0, False, 57.0, 1.2) for _ in range(5)]
    start = SimpleNamespace(window=SimpleNamespace(i0=0, i1=4))
    mag = np.tile([20.0, 0.0, 52.0], (n, 1))
    session = SimpleNamespace(imu=SimpleNamespace(mag_b_ut=mag))
    dip = 1.2
    h = 57.0 * np.cos(dip)
    fs = FieldSurvey(mag, 57.0, dip, 1.5, np.zeros(n, dtype=bool), tuple(body + still))
    ctx, summary = RunContext(), {}
    out = unresolved_offset_heading({"lf1": sol}, fs, session, start, ctx, summary)["lf1"]
    assert np.allclose(out.P_att[:, 2, 2] - 1e-6, (15.0 / h) ** 2) and ctx.warnings
    from tpos_cli.quality import magnetometer_support_findings  # one sentence for the warning and the verdict

    assert list(ctx.warnings) == [f.reason for f in magnetometer_support_findings(summary)]
    assert f"up to {np.degrees(15.0 / h):.0f} deg" in ctx.warnings[0]
    clean = FieldSurvey(mag, 45.0, dip, 1.5, np.zeros(n, dtype=bool), tuple(body))
    assert unresolved_offset_heading({"lf1": sol}, clean, session, start, RunContext(), {})["lf1"] is sol
    masked = FieldSurvey(mag, 45.0, dip, 1.5, np.arange(n) < 3, tuple(body))  # 3 of the window's 4 samples
    out = unresolved_offset_heading({"lf1": sol}, masked, session, start, RunContext(), {})["lf1"]
    gap = abs(np.linalg.norm([20.0, 0.0, 52.0]) - 45.0)
    assert np.allclose(out.P_att[:, 2, 2] - 1e-6, (max(15.0, gap) / (45.0 * np.cos(dip))) ** 2)


def test_fkf_cal_drift_takes_the_pipelines_constant_gyro_scale_figure():
    """attitude_change_variance: a still-biased gyro turned 90 deg about down since the reference
    shot adds (white^2 + constant^2) * turn^2, the constant from `[target_fkf] gyro_scale_const_ppm`
    (through FilterNoise.gyro_scale_const_sd); 0 ppm leaves the white part only."""
    from tpos_cli.attitude.local import AttitudeSolution, FilterNoise
    from tpos_cli.chains.target_fkf import attitude_change_variance
    from tpos_cli.config import TargetFkfParams
    from tpos_cli.frames.rotation import euler_to_dcm

    assert TargetFkfParams().gyro_scale_const_ppm == 1000.0
    t = np.linspace(0.0, 10.0, 11)
    C = np.stack([euler_to_dcm(0.0, 0.0, np.radians(9.0 * k)) for k in range(t.size)])  # 90 deg at t = 10 s
    sol = AttitudeSolution("fkf", t, C, np.tile(np.eye(3), (t.size, 1, 1)))  # P large: no cap
    base = dict(gyro_noise_rps=0.0, gyro_bias_rps=0.0, gyro_bias_rw_rps_rts=0.0, acc_noise_mps2=0.0, mag_noise_ut=0.0,
                range_sigma_m=0.0, gyro_scale_sd=3e-4)
    turn = np.radians(9.0 * np.arange(t.size))
    for ppm in (0.0, 1000.0):
        var = attitude_change_variance(sol, [0.0], FilterNoise(**base, gyro_scale_const_sd=ppm * 1e-6), rate_hz=1.0)
        assert np.allclose(var, (3e-4**2 + (ppm * 1e-6) ** 2) * turn**2, rtol=1e-9, atol=1e-18)


def test_the_magnetometer_update_holds_the_surveys_field_departure(tmp_path, monkeypatch):
    # the filters' magnetometer R (the kernel's r_mag = mag_noise_ut^2) is the white noise and the survey's
    # field departure in quadrature, both runs, and summary.json reports the figure beside the noise figures
    from tpos_cli.attitude import magfield
    from tpos_cli.chains import target_fkf

    survey = magfield.survey
    monkeypatch.setattr(magfield, "survey", lambda *a, **k: dataclasses.replace(survey(*a, **k), field_sd_ut=0.4))
    seen = {}

    class Stop(Exception):
        pass

    def capture(session, p, setups, field, beams, ends, noise, decl, ctx, summary, still, fb_diff_cov=None):
        seen.update(setups=setups, noise=noise, summary=summary)
        raise Stop

    monkeypatch.setattr(target_fkf, "local_filters", capture)
    sim = simulate_target(40.0, seed=3)
    d = write_session(sim, tmp_path / "s", overwrite=True)
    with pytest.raises(Stop):
        process_session(d, "target-fkf", tmp_path / "run")
    white = seen["noise"].mag_noise_ut
    for s in (seen["setups"].forward, seen["setups"].backward):
        assert s.noise.mag_noise_ut == pytest.approx(np.hypot(white, 0.4), rel=1e-12)
        # the NIS gate's threshold on the innovation's power stays the white noise's (default ratio 3)
        assert s.mag_nis_ratio * s.noise.mag_noise_ut**2 == pytest.approx(3.0 * white**2, rel=1e-12)
    assert seen["summary"]["imu_noise"]["mag_update_sd_ut"]["value"] == pytest.approx(np.hypot(white, 0.4), abs=1e-6)
    assert seen["summary"]["magnetic_survey"]["field_sd_ut"] == 0.4


def test_the_hand_models_nis_is_split_into_still_and_moving():
    # in a still period the oscillator's bound (q T) dwarfs what the accelerometer shows (BROAD: NIS ~0.01 per dof
    # over ~40 % of the updates): one mean over both would read ~1 where the moving updates alone read 1.6-2.9
    from types import SimpleNamespace

    from tpos_cli.chains.target_fkf import innovations_table

    t = np.arange(6, dtype=float)
    nis = {"acc": np.array([0.03, np.nan, 6.0, 0.02, 9.0, np.nan]), "mag": np.full(6, 3.0)}
    sol = SimpleNamespace(t_s=t, nis=nis, nis_backward=None)
    still = np.array([True, True, False, True, False, False])
    tab = innovations_table({"lf1": sol}, 0.0, 1.0, still, 100.0)
    hand = tab[tab.solution.eq("lf1_forward") & tab.kind.str.startswith("hand")]
    assert hand.kind.tolist() == ["hand_still", "hand", "hand_still", "hand"]
    assert hand.t.tolist() == [100.0, 102.0, 103.0, 104.0] and set(hand.dof) == {3}
    assert (tab.kind == "mag").sum() == 6
    # without the hand model the accelerometer's updates are gravity's
    assert set(innovations_table({"lf1": sol}, 0.0, 1.0, None, 0.0).kind) == {"acc", "mag"}


def test_a_clean_mems_sessions_hand_and_range_nis_count_the_accelerometer_bias(tmp_path):
    # a consumer-MEMS accelerometer bias (10 mg: ~0.6 deg of levelling tilt) is carried as a sensitivity outside the
    # filters' P (`_kernels.Init.S0`); the recorded NIS must count it (`_kernels.consider_innovation_cov`), else the
    # hand model's and the beams' NIS read 1.2-1.5 times their expectation on a clean session and the fault detector
    # drops LF2 for a quarter of it. Band: the quality check's own (level ok); LF2 kept >= 95 % of the log
    sim = simulate_target(90.0, seed=31, grade="mems")
    d = write_session(sim, tmp_path / "s", overwrite=True)
    rs = process_session(d, "target-fkf", tmp_path / "run")
    checks = rs.summary["quality"]["checks"]
    for k in [f"nis.lf{i}_{r}.hand" for i in (1, 2) for r in ("forward", "backward")] + \
             [f"nis.lf2_{r}.range" for r in ("forward", "backward")]:
        assert checks[k].get("level", "ok") == "ok", (k, checks[k])
    assert rs.summary["results"]["faults"]["lf2"]["excluded_fraction"] <= 0.05, rs.summary["results"]["faults"]
