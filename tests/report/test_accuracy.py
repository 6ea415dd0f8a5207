"""Accuracy tables of synthetic runs whose errors are chosen by hand (see tests/report/synth.py)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from scipy import stats

from tests.report import synth
from tpos_cli.frames.rotation import euler_to_dcm
from tpos_cli.report.build import make_report

GEO_ATOL_M = 1e-6  # placement by ned_to_lla and recovery through ECEF agree to ~1e-9 m
ANG_ATOL_DEG = 1e-9  # Euler/rotation round trips in float64


def stat(table, solution, segment, quantity, name, target=""):
    table = table.to_pandas()  # the report's accuracy table (io.columns.Columns), as a DataFrame
    m = (table.solution == solution) & (table.segment == segment) & (table.quantity == quantity) & (table.target == target)
    assert m.sum() == 1, (solution, segment, quantity, target)
    return float(table.loc[m, name].iloc[0])


@pytest.fixture(scope="module")
def drive_report(tmp_path_factory):
    d = tmp_path_factory.mktemp("drive")
    s = synth.write_session(d / "s", movement=True)
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)  # 10 Hz: between truth samples, interpolation is exercised
    t1 = np.arange(0.0, 21.0)
    fwd = synth.trajectory_rows("forward", t10, [3.0, 4.0, 0.0], (0.5, -0.3, 2.0), sigma=(1.0, 1.0, 1.0))
    bwd = synth.trajectory_rows("backward", t1, np.column_stack([0 * t1, 0 * t1, -t1]), sigma=(1.0, 1.0, 1.0))  # up error = t
    r = synth.write_run(d / "r", s, pd.concat([fwd, bwd]), gps_outages=[[1003.0, 1006.0]])
    return make_report(r, pdf=False)


def test_constant_offset_interpolated(drive_report):
    t = drive_report.accuracy.table
    assert stat(t, "forward", "all", "pos_h_m", "n") == 201
    for q, v in (("pos_h_m", 5.0), ("pos_3d_m", 5.0), ("pos_n_m", 3.0), ("pos_e_m", 4.0)):
        for name in ("mean", "rms", "max", "p95"):
            assert_allclose(stat(t, "forward", "all", q, name), v, rtol=0, atol=GEO_ATOL_M)
    assert_allclose(stat(t, "forward", "all", "pos_h_m", "cep"), 5.0, rtol=0, atol=GEO_ATOL_M)


def test_wrap_aware_attitude_errors(drive_report):
    t = drive_report.accuracy.table  # truth yaw crosses north at t = 10 s
    for q, v in (("roll_deg", 0.5), ("pitch_deg", -0.3), ("yaw_deg", 2.0)):
        assert_allclose(stat(t, "forward", "all", q, "mean"), v, atol=ANG_ATOL_DEG)
        assert_allclose(stat(t, "forward", "all", q, "sd"), 0.0, atol=ANG_ATOL_DEG)


def test_vertical_ramp_hand_computed(drive_report):
    t = drive_report.accuracy.table  # up error 0, 1, ..., 20 m
    assert_allclose(stat(t, "backward", "all", "pos_v_m", "mean"), 10.0, atol=GEO_ATOL_M)
    assert_allclose(stat(t, "backward", "all", "pos_v_m", "sd"), np.sqrt((21**2 - 1) / 12), atol=GEO_ATOL_M)
    assert_allclose(stat(t, "backward", "all", "pos_v_m", "rms"), np.sqrt(20 * 41 / 6), atol=GEO_ATOL_M)
    assert_allclose(stat(t, "backward", "all", "pos_v_m", "p95"), 19.0, atol=GEO_ATOL_M)
    assert_allclose(stat(t, "backward", "all", "pos_h_m", "max"), 0.0, atol=GEO_ATOL_M)


def test_outage_segments_and_paper003_table(drive_report):
    t = drive_report.accuracy.table
    # outage [1003, 1006): 1 Hz epochs 3, 4, 5 (up errors 3, 4, 5); 10 Hz epochs 3.0 .. 5.9
    assert stat(t, "backward", "outage", "pos_v_m", "n") == 3
    assert_allclose(stat(t, "backward", "outage_1", "pos_v_m", "rms"), np.sqrt(50 / 3), atol=GEO_ATOL_M)
    assert stat(t, "forward", "outage", "pos_h_m", "n") == 30
    assert stat(t, "backward", "gps", "pos_v_m", "n") == 18
    p3 = drive_report.accuracy.paper_tables["paper003_outages"].to_pandas()
    row = p3[p3.solution == "backward"].iloc[0]
    assert_allclose([row.rms_v_m, row.max_3d_m, row.duration_s], [np.sqrt(50 / 3), 5.0, 3.0], atol=GEO_ATOL_M)


def test_movement_segment(drive_report):
    # movement = truth t >= 5 s: 10 Hz epochs 5.0 .. 20.0
    assert stat(drive_report.accuracy.table, "forward", "movement", "yaw_deg", "n") == 151


def test_forward_backward_disagreement(drive_report):
    dis = drive_report.health.disagreement.to_pandas().iloc[0]
    assert (dis.a, dis.b, dis.n) == ("forward", "backward", 201)
    # forward - backward = (3, 4, t) m with sigma 1 m each: d'd/2 > 11.34 at every epoch
    assert dis.n_flagged == 201
    assert_allclose(dis.max_m, np.sqrt(25 + 400), atol=1e-5)  # 1e-5: backward interpolated between 1 Hz points


def test_truth_dropout_excluded(tmp_path):
    s = synth.write_session(tmp_path / "s", truth_nan_rows=(5, 6, 7))
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)
    r = synth.write_run(tmp_path / "r", s, synth.trajectory_rows("forward", t10, [1.0, 0.0, 0.0]))
    t = make_report(r, pdf=False).accuracy.table
    # valid truth at 4 s and 8 s are 4 s apart (> 2.5 s): epochs 4.1 .. 7.9 (39) have no truth
    assert stat(t, "forward", "all", "pos_h_m", "n") == 201 - 39
    assert_allclose(stat(t, "forward", "all", "pos_h_m", "max"), 1.0, atol=GEO_ATOL_M)


def _target_session(tmp_path, kind="target"):
    tgts = [
        ("T1", synth.truth_lla(np.array([30.0]))[0], "truth"),
        ("T2", synth.truth_lla(np.array([40.0]))[0], "truth"),
        ("R1", synth.truth_lla(np.array([50.0]))[0], "reference"),
    ]
    s = synth.write_session(tmp_path / "s", kind=kind, truth=False, targets=tgts)
    rows = []
    offsets = {
        ("lf1", "T1"): [0.3, -0.2, 0.1],
        ("lf1", "T2"): [0.3, -0.2, 0.1],
        ("fkf", "T1"): [0.3, 0.4, 0.0],
        ("fkf", "T2"): [0.6, 0.8, 0.0],
        ("fkf", "R1"): [9.0, 9.0, 9.0],
    }
    lut = {n: p for n, p, _ in tgts}
    for (sol, tid), off in offsets.items():
        lla = synth.displaced(lut[tid][None, :], np.array([off]))[0]
        rows.append(
            dict(
                id=tid,
                t_start=1005.0,
                t_end=1006.0,
                range_m=9.42,
                lat=lla[0],
                lon=lla[1],
                h=lla[2],
                solution=sol,
                sigma_n=0.2,
                sigma_e=0.2,
                sigma_u=0.3,
            )
        )
    return s, pd.DataFrame(rows)


def test_targets_against_surveyed_truth(tmp_path):
    s, tg = _target_session(tmp_path)
    res = make_report(synth.write_run(tmp_path / "r", s, None, tg), pdf=False)
    t = res.accuracy.table
    assert_allclose(stat(t, "lf1", "all", "pos_3d_m", "mean", "all"), np.sqrt(0.14), atol=GEO_ATOL_M)
    assert_allclose(stat(t, "fkf", "all", "pos_h_m", "mean", "all"), 0.75, atol=GEO_ATOL_M)
    assert_allclose(stat(t, "fkf", "all", "pos_h_m", "sd", "all"), 0.25, atol=GEO_ATOL_M)
    assert_allclose(stat(t, "fkf", "all", "pos_h_m", "cep", "all"), 0.75, atol=GEO_ATOL_M)  # median of 0.5, 1.0
    assert_allclose(stat(t, "fkf", "all", "pos_h_m", "ce90", "all"), 0.95, atol=GEO_ATOL_M)
    assert stat(t, "fkf", "all", "pos_h_m", "n", "all") == 2  # R1 is a reference point, not truth
    p0 = res.accuracy.paper_tables["paper000_table4"].to_pandas()
    assert p0.solution.tolist() == ["lf1", "fkf"]  # paper order: gyro, lf1, lf2, fkf
    assert_allclose(p0.mean_m, [np.sqrt(0.14), 0.75], atol=GEO_ATOL_M)
    # predicted CEP of a circular 0.2 m SD: 0.2 sqrt(2 ln 2)
    assert_allclose(res.accuracy.targets.cep_pred_m, 0.2 * np.sqrt(2 * np.log(2)), rtol=1e-9)


def test_gps_truth_with_lever_arm_and_withheld(tmp_path):
    lever = np.array([0.0, 0.0, -1.0])  # antenna 1 m above the IMU (FRD)
    s = synth.write_session(tmp_path / "s", truth=False, gps_lever_m=lever)
    t1 = np.arange(0.0, 21.0)
    C = euler_to_dcm(*np.radians(synth.truth_rpy_deg(t1)).T)
    antenna = synth.displaced(synth.truth_lla(t1), C @ lever)
    gps = pd.DataFrame({"t": synth.T0 + t1, "lat": antenna[:, 0], "lon": antenna[:, 1], "h": antenna[:, 2], "fix": 2})
    gps.to_csv(s / "gps.csv", index=False)
    withheld = gps[(gps.t >= 1005.0) & (gps.t <= 1008.0)]
    r = synth.write_run(
        tmp_path / "r", s, synth.trajectory_rows("forward", t1, [0.0, 0.0, 0.0]), mask_gps=[[1005.0, 1008.0]], withheld=withheld
    )
    res = make_report(r, pdf=False)
    assert res.truth.trajectory.source == "gps"
    assert "withheld" in res.truth.trajectory.description
    t = res.accuracy.table
    # the solution is the true IMU point: with the lever arm applied the antenna errors vanish (1 m without)
    assert_allclose(stat(t, "forward", "all", "pos_3d_m", "max"), 0.0, atol=GEO_ATOL_M)
    assert stat(t, "forward", "withheld", "pos_3d_m", "n") == 4  # the fixes at 5, 6, 7, 8 s


def test_paper002_table_for_ranging(tmp_path):
    s = synth.write_session(tmp_path / "s", kind="ranging")
    t1 = np.arange(0.0, 21.0)
    off = np.column_stack([np.where(t1 < 10, 0.1, -0.2), np.where(t1 < 10, -0.05, 0.25), 0 * t1])
    res = make_report(synth.write_run(tmp_path / "r", s, synth.trajectory_rows("fatci", t1, off)), pdf=False)
    row = res.accuracy.paper_tables["paper002_table1"].to_pandas().iloc[0]
    assert_allclose([row.x_min_m, row.x_max_m, row.y_min_m, row.y_max_m], [-0.05, 0.25, -0.2, 0.1], atol=GEO_ATOL_M)
    e, n = off[:, 1], off[:, 0]
    assert_allclose([row.x_var_m2, row.y_var_m2], [e.var(), n.var()], atol=GEO_ATOL_M)
    assert_allclose([row.max_m, row.average_m], [np.hypot(0.2, 0.25), np.hypot(e, n).mean()], atol=GEO_ATOL_M)


def test_no_truth_is_a_quality_control_report(tmp_path):
    s = synth.write_session(tmp_path / "s", truth=False)
    r = synth.write_run(tmp_path / "r", s, synth.trajectory_rows("forward", np.arange(0.0, 21.0), [0.0, 0.0, 0.0], sigma=(0.3, 0.4, 1.0)))
    res = make_report(r, pdf=False)
    assert len(res.accuracy.table) == 0 and res.summary["headline"] == [] and res.summary["truth"] is None
    est = res.summary["estimated"][0]
    # circular-enough: the 95 % ellipse semi-major axis is sqrt(chi2_2(0.95)) sigma_max; vertical 1.96 sigma
    assert_allclose(est["h95_median_m"], np.sqrt(stats.chi2.ppf(0.95, 2)) * 0.4, rtol=1e-9)
    assert_allclose(est["v95_median_m"], stats.norm.ppf(0.975) * 1.0, rtol=1e-9)


def test_solutions_sharing_positions_share_nothing_else(tmp_path):
    # three solutions at the same epochs: a and b at the same positions (their position errors and
    # statistics are computed once), c elsewhere; every row equals that of a run of the solution alone
    s = synth.write_session(tmp_path / "s", movement=True)
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)
    rows = {
        "a": synth.trajectory_rows("a", t10, [3.0, 4.0, -1.0], (0.5, -0.3, 2.0)),
        "b": synth.trajectory_rows("b", t10, [3.0, 4.0, -1.0], (0.1, 0.2, -1.0)),
        "c": synth.trajectory_rows("c", t10, [1.0, -2.0, 0.5], (0.5, -0.3, 2.0)),
    }
    outages = [[1003.0, 1006.0]]
    together = make_report(synth.write_run(tmp_path / "all", s, pd.concat(rows.values()), gps_outages=outages), pdf=False)
    t = together.accuracy.table.to_pandas().set_index(["solution", "target", "segment", "quantity"]).sort_index()
    for name, df in rows.items():
        alone = make_report(synth.write_run(tmp_path / name, s, df, gps_outages=outages), pdf=False).accuracy.table
        alone = alone.to_pandas().set_index(["solution", "target", "segment", "quantity"]).sort_index()
        pd.testing.assert_frame_equal(t.loc[[name]], alone, check_exact=False, rtol=1e-12, atol=1e-12)
    a, b = (next(se for se in together.accuracy.solutions if se.solution == n) for n in "ab")
    assert a.err_ned_m is b.err_ned_m  # shared, not recomputed
    assert not np.allclose(a.att_err_deg["yaw_deg"], b.att_err_deg["yaw_deg"])
