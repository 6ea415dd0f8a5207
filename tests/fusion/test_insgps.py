"""The INS/GPS filter on a simulated MEMS drive: consistency (NEES), outage bridging, backward run."""

import tempfile
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from tpos_cli.chains.drive_smooth import process_drive
from tpos_cli.config import DriveSmoothParams
from tpos_cli.session import load_session
from tpos_cli.sim.drive import simulate_drive

OUTAGE = (100.0, 30.0)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    sim = simulate_drive(240.0, seed=3, outages=(OUTAGE,))
    path = sim.write(tmp_path_factory.mktemp("drive") / "s")
    session = load_session(path)
    # the simulated receiver's velocity SD (0.05 m/s) is the filter's measurement SD
    p = DriveSmoothParams(gps_sigma_vel_mps=0.05)
    res = process_drive(session, p, None, names=("forward", "backward", "rts", "two_filter", "simplified"))
    return sim, res


def _errors(sim, sol):
    """(K, 9) errors [NED m, NED m/s, phi rad] of a solution against the exact truth."""
    return sim.truth.navigation_errors(sol.idx, sol.nav, sol.C_nb)


def _in_outage(sim, sol):
    t = sim.truth.t_s[sol.idx]
    return (t >= OUTAGE[0]) & (t < OUTAGE[0] + OUTAGE[1])


def _nees(e, P):
    return np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])


@pytest.mark.parametrize("name", ["forward", "backward", "rts"])
def test_nees_inside_chi2_bounds(drive, name):
    sim, res = drive
    sol = res.solutions[name]
    e = _errors(sim, sol)
    keep = sim.truth.t_s[sol.idx] > 30.0  # after the heading is observable (vehicle moving, turns)
    nees = _nees(e[keep], sol.P9[keep])
    # a consistent filter keeps ~95 % of epochs under the 95 % bound; errors are correlated in
    # time, so one run is allowed down to 85 %, and a mean NEES within [0.3, 1.5] x dof
    assert np.mean(nees < chi2.ppf(0.95, 9)) > 0.85
    assert 0.3 * 9 < np.mean(nees) < 1.5 * 9


def test_outage_bridging(drive):
    sim, res = drive
    rms = {}
    for name, sol in res.solutions.items():
        e = _errors(sim, sol)
        eh = np.hypot(e[:, 0], e[:, 1])
        m = _in_outage(sim, sol)
        rms[name] = (np.sqrt(np.mean(eh[m] ** 2)), np.sqrt(np.mean(eh[~m] ** 2)))
    # issue 4 goals for a 30 s outage with 1.5 m GPS noise (the car's motion constraints on: the
    # forward coast itself is already within a few decimetres, issue 11)
    assert rms["rts"][0] < 0.5 and rms["rts"][0] < rms["forward"][0]
    assert rms["two_filter"][0] < 0.5 and rms["two_filter"][0] < rms["forward"][0]
    assert rms["rts"][1] < 0.6
    # the forward filter is not a weak strawman: its outside-outage RMS is below the GPS noise
    assert rms["forward"][1] < 1.0
    assert rms["rts"][0] < rms["simplified"][0]


@pytest.fixture(scope="module")
def drive_unconstrained(drive):
    """The same drive without motion constraints (`platform = "none"`): paper 003's smoothers alone."""
    sim, _ = drive
    with tempfile.TemporaryDirectory() as tmp:
        session = load_session(sim.write(Path(tmp) / "s"))
    p = DriveSmoothParams(gps_sigma_vel_mps=0.05, platform="none")
    return sim, process_drive(session, p, None, names=("forward", "rts", "two_filter", "simplified"))


def test_outage_bridging_without_constraints(drive_unconstrained):
    """Issue 4 goals: the smoothers bridge a 30 s outage at a third of the free forward coast."""
    sim, res = drive_unconstrained
    rms = {}
    for name, sol in res.solutions.items():
        e = _errors(sim, sol)
        m = _in_outage(sim, sol)
        rms[name] = np.sqrt(np.mean(np.hypot(e[m, 0], e[m, 1]) ** 2))
    assert rms["rts"] < 0.5 and rms["rts"] < 0.35 * rms["forward"]
    assert rms["two_filter"] < 0.5 and rms["two_filter"] < 0.35 * rms["forward"]
    # paper 003's simplified smoother bridges worse than the optimal ones but better than forward
    assert rms["rts"] < rms["simplified"] < rms["forward"]


def test_backward_run_on_reversed_log(drive):
    """The backward filter (same kernel, reversed time) reaches the start of the log accurately."""
    sim, res = drive
    sol = res.solutions["backward"]
    e = _errors(sim, sol)
    assert np.hypot(e[0, 0], e[0, 1]) < 1.5  # at t = 0, after 240 s of backward filtering: GPS noise level
    assert np.abs(e[0, 3:6]).max() < 0.1
    fwd = res.forward
    # the forward filter's gyro bias estimate at the end agrees with the truth (sensor errors known)
    b_true = sim.imu.errors.gyro_bias_rps[-1]
    sd = np.sqrt(np.diagonal(fwd.ep_P[-1])[12:15])
    assert np.all(np.abs(fwd.bias[-1, 3:6] - b_true) < 4 * sd)


def test_flags_and_rejections_quiet_on_clean_data(drive):
    _, res = drive
    assert res.flag.mean() < 0.01  # forward and backward agree on a clean simulated drive
    gi = res.innovations()
    acc, nis = gi.accepted, gi.nis
    assert (~acc & np.isfinite(nis)).sum() <= 2  # 0.9999 gate on ~210 fixes x (position, velocity)


def test_nis_per_kind_is_chi2_with_3_dof(drive):
    """Position and velocity NIS, each 3 d.o.f., average about 3 on white simulated GPS."""
    _, res = drive
    nis = res.innovations().nis
    for j in range(2):
        a = nis[np.isfinite(nis[:, j]) & (np.arange(nis.shape[0]) > 30), j]
        # mean of ~180 chi2(3) draws: SD sqrt(6/180) = 0.18; 4 SD, plus the slightly cautious
        # constant-bias model (the simulator's bias is constant + Gauss-Markov)
        assert 3.0 - 0.8 < np.mean(a) < 3.0 + 0.8, (j, np.mean(a))


def test_each_fix_gives_its_velocity_row_before_its_position_row():
    """The position row's clock column is the nominal velocity (`measurements.measure`): after a
    coast that is metres per second off until the fix's own velocity row has corrected it, so each
    fix's velocity row goes first, forward and backward (comma2k19 without constraints, 15 s coast:
    clock offset +0.06 +- 0.02 s against the log's -0.08 s with the position row first)."""
    from tpos_cli.fusion.insgps import GpsFixes, gps_measurements
    from tpos_cli.fusion.measurements import Kind

    t = np.arange(5.0)
    lla = np.column_stack([np.full(5, 45.0), np.full(5, -75.0), np.zeros(5)])
    vel = np.tile([10.0, 0.0, 0.0], (5, 1))
    vel[2] = np.nan  # a fix without velocity keeps its position row alone
    fixes = GpsFixes(t, lla, vel, np.full((5, 3), 0.1), np.full((5, 3), 0.05))
    for backward in (False, True):
        t_run = -t[::-1] if backward else t
        m = gps_measurements(fixes, t_run, backward=backward, gap_s=0.0)
        assert list(m.par) == [0, 0, 1, 1, 2, 3, 3, 4, 4]
        kinds = [Kind(k) for k in m.kind]
        assert kinds == [Kind.GPS_VELOCITY, Kind.GPS_POSITION] * 2 + [Kind.GPS_POSITION] + [Kind.GPS_VELOCITY, Kind.GPS_POSITION] * 2
