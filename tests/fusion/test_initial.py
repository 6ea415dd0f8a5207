"""Initial heading: the yaw-hypothesis search recovers a wrong course, slow platforms get a course."""

import numpy as np
import pytest

from tpos_cli.chains.drive_smooth import decimate_times, fixes_from_session, process_drive
from tpos_cli.config import DriveSmoothParams
from tpos_cli.frames.geodetic import lla_to_ned, ned_to_lla
from tpos_cli.frames.rotation import dcm_to_euler, wrap_angle_rad
from tpos_cli.fusion.initial import _gps_heading, robust_nis_score, with_yaw
from tpos_cli.fusion.insgps import GpsFixes
from tpos_cli.session import load_session
from tpos_cli.sim.drive import simulate_drive


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    sim = simulate_drive(120.0, seed=4, outages=())
    return sim, load_session(sim.write(tmp_path_factory.mktemp("drive") / "s"))


def test_yaw_search_recovers_a_heading_wrong_by_120_deg(session, monkeypatch):
    sim, s = session
    import tpos_cli.chains.drive_smooth as ds

    true_yaw = float(dcm_to_euler(sim.truth.C_nb[0])[2])
    real_align = ds.align_vehicle

    def wrong_course(*a, **k):  # a magnetometer near a car, or a sideways-mounted IMU
        init, info = real_align(*a, **k)
        return with_yaw(init, true_yaw + np.radians(120.0), np.radians(3.0)), info

    monkeypatch.setattr(ds, "align_vehicle", wrong_course)
    res = process_drive(s, DriveSmoothParams(), None, names=("forward",))
    assert res.info["heading"].startswith("yaw search")
    yaw0 = float(dcm_to_euler(res.forward.C_nb[0])[2])
    # the winning hypothesis is within half the 30 deg grid spacing of the truth
    assert abs(np.degrees(wrap_angle_rad(yaw0 - true_yaw))) < 15.0
    # and the filter then converges: heading error after a minute of driving below 1 deg
    i = np.searchsorted(sim.truth.t_s, 90.0)
    yaw_f = float(dcm_to_euler(res.forward.C_nb[res.forward.rows(i)])[2])  # the runs keep the output rows
    assert abs(np.degrees(wrap_angle_rad(yaw_f - float(dcm_to_euler(sim.truth.C_nb[i])[2])))) < 1.0


def test_yaw_search_keeps_a_good_course(session):
    sim, s = session
    res = process_drive(s, DriveSmoothParams(), None, names=("forward",))
    assert res.info["heading"].startswith("gps velocity") and "confirmed" in res.info["heading"]
    sc = np.array(res.info["yaw_search"]["score"])
    assert np.argmin(sc) == 0  # the course (hypothesis 0) has the best score outright


def _rtk_float_fixes_at_a_standstill(seed, tmp_path):
    """A 90 s RTK sim (4 Hz fixes at the 1 cm floor; its own float stretches and multipath off) with,
    before the car moves (static 15 s): the fixes at 4-6 s left out (the gap a screened float stretch
    leaves) and those at 9-11 s moved 0.2 m north, 0.1 m west under their 1 cm SD (a float stretch
    the screen keeps: NIS in the hundreds)."""
    import dataclasses

    sim = simulate_drive(90.0, seed=seed, gps_rtk=True, gps_rate_hz=4.0, outages=(), gps_rtk_float_per_min=0.0,
                         gps_rtk_multipath_per_min=0.0)
    s = load_session(sim.write(tmp_path / "s"))
    g = s.gps
    lla = g.lla.copy()
    off = (g.t_s >= 9.0) & (g.t_s < 11.0)
    lla[off] = ned_to_lla(lla_to_ned(lla[off], lla[0]) + [0.2, -0.1, 0.0], lla[0])
    keep = ~((g.t_s >= 4.0) & (g.t_s < 6.0))
    g = dataclasses.replace(g, lla=lla)
    g = dataclasses.replace(g, **{f.name: getattr(g, f.name)[keep] for f in dataclasses.fields(g)})
    return sim, dataclasses.replace(s, gps=g)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_yaw_search_keeps_the_course_despite_float_fixes_at_a_standstill(seed, tmp_path):
    """72c66ed's search (ungated, summed NIS) lost the course here on seeds 1 and 3 (hypotheses -60 and
    +30 deg off won by 114 and 61), as on the lead's RTK sim seed 2 (session 19): the float rows pulled
    every run's state and their NIS in the hundreds decided the winner."""
    sim, s = _rtk_float_fixes_at_a_standstill(seed, tmp_path)
    res = process_drive(s, DriveSmoothParams(), None, names=("forward",))
    assert "confirmed" in res.info["heading"], res.info["heading"]
    yaw0 = float(dcm_to_euler(res.forward.C_nb[0])[2])
    true_yaw = float(dcm_to_euler(sim.truth.C_nb[0])[2])
    # the course from the GPS velocity: within a few deg (half the 30 deg grid spacing bounds a grid pick)
    assert abs(np.degrees(wrap_angle_rad(yaw0 - true_yaw))) < 15.0


def test_robust_nis_score_caps_each_row_at_its_gate():
    # gate 0.9999: chi2 quantiles 15.14 (1 dof), 18.42 (2), 21.11 (3); NaN (not processed) rows skipped
    nis = np.array([1.0, 400.0, np.nan, 2.0, 50.0])
    dim = np.array([3, 3, 3, 2, 2])
    assert robust_nis_score(nis, dim, 0.9999) == pytest.approx(1.0 + 21.108 + 2.0 + 18.421, abs=1e-3)


def test_slow_platform_gets_a_course_from_10_s_of_positions():
    """A rover at 0.4 m/s heading 60 deg, 1 Hz positions with 0.3 m noise, no velocity."""
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 120.0)
    yaw = np.radians(60.0)
    d = np.where(t > 20.0, 0.4 * (t - 20.0), 0.0)
    n_m = d * np.cos(yaw) + 0.3 * rng.standard_normal(t.size)
    e_m = d * np.sin(yaw) + 0.3 * rng.standard_normal(t.size)
    lla = np.column_stack([45.0 + np.degrees(n_m / 6.37e6), 7.0 + np.degrees(e_m / (6.37e6 * np.cos(np.radians(45.0)))),
                           np.full(t.size, 100.0)])
    fx = GpsFixes(t, lla, np.full((t.size, 3), np.nan), np.full((t.size, 3), 0.3), np.full((t.size, 3), 0.1))
    hd = _gps_heading(fx, 3.0)
    assert hd is not None and "positions over 10 s" in hd.how
    # 0.3 m noise on both ends of a >= 3 m baseline: course within atan(0.6 / 3) = 11 deg
    assert abs(np.degrees(hd.yaw_rad - yaw)) < 11.0
    assert hd.t_s > 10.0  # not before it moves (10 s baseline centred)


def test_decimate_times_keeps_one_fix_per_interval():
    t = np.arange(0.0, 10.0, 0.05) + 0.001 * np.sin(np.arange(200))  # 20 Hz with jitter
    k = decimate_times(t, 1.0)
    assert k.size == 10 and np.all(np.diff(t[k]) > 0.98)
    t1 = np.arange(0.0, 10.0) + 0.02 * np.sin(np.arange(10))  # 1 Hz with jitter: all kept
    assert decimate_times(t1, 1.0).size == 10
    assert decimate_times(t, 0.0).size == t.size


def test_horizontal_velocity_without_vd_is_a_2_dof_update(session):
    import dataclasses

    _, s = session
    gps = s.gps
    vel = gps.vel_ned_mps.copy()
    vel[:, 2] = np.nan  # a speed/course receiver
    s2 = dataclasses.replace(s, gps=dataclasses.replace(gps, vel_ned_mps=vel))
    fx = fixes_from_session(s2, DriveSmoothParams())
    assert np.isfinite(fx.vel_ned_mps[:, :2]).all() and np.isnan(fx.vel_ned_mps[:, 2]).all()
    # the simulated receiver's velocity SD (0.05 m/s) is the filter's
    res = process_drive(s2, DriveSmoothParams(heading_hypotheses=0, gps_sigma_vel_mps=0.05), None, names=("forward",))
    gi = res.innovations()
    nu = gi.innovation
    ok = np.isfinite(gi.nis[:, 1])
    assert ok.sum() > 100 and np.isfinite(nu[ok, 3:5]).all() and np.isnan(nu[ok, 5]).all()
    # chi2(2) mean 2: 4 SD of the mean of ~110 draws is 0.54
    assert abs(np.mean(gi.nis[ok, 1][20:]) - 2.0) < 0.6
