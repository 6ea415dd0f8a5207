"""Re-acquisition after gate rejections (`fusion.reacquire`, issue 11 item 6): a filter knocked off
re-acquires its fixes with a grown covariance; fixes that wander within their stated accuracy, jump
and scatter, or step away are not taken for a drift. Planted cases on an exactly simulated body at
rest (the IMU and the fixes are the truth's own, but for the planted knock and fix errors)."""

import functools
import itertools

import numpy as np
from numpy.testing import assert_allclose
from scipy.stats import chi2

from tpos_cli.frames.earth import normal_gravity_mps2
from tpos_cli.frames.geodetic import ned_to_lla
from tpos_cli.fusion.engine import FilterConfig, InitialState, Measurements, run_filter
from tpos_cli.fusion.measurements import Kind
from tpos_cli.fusion.reacquire import (
    N_INFLATED,
    anchor,
    anchors,
    drift_nis,
    drift_nis_from_anchor,
    inflate_to_fit,
    remember,
    ring,
)

LAT, LON, H = 45.0, 7.0, 100.0
SD_FIX_M = 0.02


def _still(seconds=30.0, dt=0.01):
    """The exact IMU of a body at rest, body = NED (gravity and the Earth's rate only)."""
    n = int(round(seconds / dt)) + 1
    lat = np.radians(LAT)
    t = np.arange(n) * dt
    acc = np.tile([0.0, 0.0, -normal_gravity_mps2(lat, H)], (n, 1))
    w_ie = 7.292115e-5
    gyro = np.tile([w_ie * np.cos(lat), 0.0, -w_ie * np.sin(lat)], (n, 1))
    return t, gyro, acc


def _fixes(t_s, offsets_ned_m, seed=0, noise_sd_m=SD_FIX_M):
    """GPS position rows at t_s: the truth (the start point) moved by offsets (M, 3) plus white noise
    of noise_sd_m (0: the truth's own fixes), R = SD_FIX_M^2 I."""
    rng = np.random.default_rng(seed)
    ned = np.asarray(offsets_ned_m, dtype=float) + rng.normal(0.0, noise_sd_m, (len(t_s), 3))
    lla = ned_to_lla(ned, np.array([LAT, LON, H]))
    z = np.column_stack([np.radians(lla[:, 0]), np.radians(lla[:, 1]), lla[:, 2]])
    R = np.tile(SD_FIX_M**2 * np.eye(3), (len(t_s), 1, 1))
    return Measurements.rows(t_s, Kind.GPS_POSITION, z, R, dim=3, gated=True, slot=0)


def _run(nav0, sd_pos_m, sd_vel_mps, meas, seconds=30.0, stated=1.0, knock=None, reacquire=True):
    """The filter at rest from nav0 with P0 of those SDs; `stated`: the fixes' stated accuracy over
    their R (`FilterConfig.stated_sd_factor`, position groups); knock (t0, t1, m/s^2): a north
    acceleration the IMU reports between t0 and t1 that the body never had (a planted jump)."""
    t, gyro, acc = _still(seconds)
    if knock is not None:
        acc[(t >= knock[0]) & (t < knock[1]), 0] += knock[2]
    P0 = np.diag(np.r_[np.full(3, sd_pos_m), np.full(3, sd_vel_mps), np.full(3, 1e-3), np.full(3, 1e-3),
                       np.full(3, 1e-5)] ** 2)
    cfg = FilterConfig(np.array([1e-6, 1e-10, 1e-12, 1e-14]), 0.0, 0.0, cov_step=10, gate_probability=0.9999,
                       reacquire=reacquire, stated_sd_factor=np.array([stated, stated, 1.0, 1.0]))
    return run_filter(t, gyro, acc, InitialState(nav0, np.eye(3), np.zeros(6), P0), cfg, meas)


def _nav(north_m=0.0, v_north_mps=0.0):
    lla = ned_to_lla(np.array([[north_m, 0.0, 0.0]]), np.array([LAT, LON, H]))[0]
    return np.array([np.radians(lla[0]), np.radians(lla[1]), lla[2], v_north_mps, 0.0, 0.0])


def _north_error_m(run):
    return (run.nav[:, 0] - np.radians(LAT)) * 6.37e6


def test_divided_difference_takes_out_a_polynomial_drift_and_sees_a_jump():
    t_ring, nu_ring, R_ring = ring(1)
    t = np.array([0.0, 1.0, 2.5, 3.0])  # uneven spacing
    R = 0.01**2 * np.eye(3)
    drift = np.column_stack([5.0 + 0.3 * t - 0.2 * t**2, -2.0 + 0.1 * t, 0.05 * t**2])  # any quadratic: exactly out
    for c in range(4):
        remember(t_ring, nu_ring, R_ring, 0, c, t[c], drift[c], R, 3)
    assert drift_nis(t_ring, nu_ring, R_ring, 0, 2, 2, 3) == -1.0  # three rejections: too few for degree 2
    assert drift_nis(t_ring, nu_ring, R_ring, 0, 3, 2, 3) < 1e-12
    jump = drift.copy()
    jump[2, 0] += 0.1  # ten fix SDs on one fix: a jump and back
    for c in range(4):
        remember(t_ring, nu_ring, R_ring, 0, c, t[c], jump[c], R, 3)
    assert drift_nis(t_ring, nu_ring, R_ring, 0, 3, 2, 3) > chi2.ppf(0.9999, 3)
    assert drift_nis(t_ring, nu_ring, R_ring, 0, 3, 2, 1) == -1.0  # scalars (one range) never agree
    # degree 1 (velocities): the last three; a ring that wrapped (rejection number 5 in slot 0)
    for c in range(4, 6):
        remember(t_ring, nu_ring, R_ring, 0, c, 3.0 + c, np.array([1.0 + 0.5 * c, 0.0, 0.0]), R, 3)
    remember(t_ring, nu_ring, R_ring, 0, 3, 6.0, np.array([2.5, 0.0, 0.0]), R, 3)
    assert drift_nis(t_ring, nu_ring, R_ring, 0, 5, 1, 3) < 1e-12


def test_inflation_fits_the_innovation_and_keeps_the_other_states():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(18, 18))
    P = A @ A.T * 1e-4
    H = np.zeros((3, 18))
    H[:, :3] = np.eye(3)
    H[:, 15:] = np.eye(3)  # a GPS error state beside the position
    R = 0.01**2 * np.eye(3)
    nu = np.array([3.0, -1.0, 0.5])
    k = N_INFLATED
    for target, jump in itertools.product((3.0, chi2.ppf(0.9999, 3)), (False, True)):  # moment fit, gate's edge
        P1 = P.copy()
        lam = inflate_to_fit(P1, H, R, nu, 3, target, jump)
        assert lam > 1.0
        assert_allclose(nu @ np.linalg.solve(H @ P1 @ H.T + R, nu), target, rtol=1e-9)
        assert_allclose(P1, P1.T, atol=0)
        assert np.all(np.linalg.eigvalsh(P1) > 0)
        assert_allclose(P1[k:, k:], P[k:, k:], rtol=0, atol=0)  # the other states as they were
        assert_allclose(P1[:k, :k], lam * P[:k, :k], rtol=1e-12)
        cross = 1.0 if jump else np.sqrt(lam)  # an independent jump keeps the cross terms; a drift scales them
        assert_allclose(P1[:k, k:], cross * P[:k, k:], rtol=1e-12)
    small = np.array([0.001, 0.0, 0.0])  # an innovation the covariance explains: nothing grown
    for jump in (False, True):
        P2 = P.copy()
        assert inflate_to_fit(P2, H, R, small, 3, 3.0, jump) == 1.0 and np.array_equal(P2, P)


def test_the_anchored_difference_tells_a_drift_from_a_step():
    """Through the last accepted row's post-fit residual (where the filter's error stood): a drift
    that starts there is a polynomial through it; fixes that stepped away agree with each other but
    not with it."""
    t_ring, nu_ring, R_ring = ring(1)
    anc = anchors(1)
    R = 0.01**2 * np.eye(3)
    assert drift_nis_from_anchor(t_ring, nu_ring, R_ring, *anc, 0, 2, 2, 3) == -1.0  # no anchor yet
    anchor(*anc, 0, 10.0, np.zeros(3), R, 3)
    t = np.array([11.0, 12.0, 13.0])
    drift = np.column_stack([0.4 * (t - 10.0) ** 2, 0.1 * (t - 10.0), np.zeros(3)])  # from the anchor on
    for c in range(3):
        remember(t_ring, nu_ring, R_ring, 0, c, t[c], drift[c], R, 3)
    assert drift_nis_from_anchor(t_ring, nu_ring, R_ring, *anc, 0, 1, 2, 3) == -1.0  # two rejections: too few
    assert drift_nis_from_anchor(t_ring, nu_ring, R_ring, *anc, 0, 2, 2, 3) < 1e-12
    step = np.tile([3.0, 0.0, 0.0], (3, 1))  # 3 m away from the anchor, constant: they agree among themselves
    for c in range(3):
        remember(t_ring, nu_ring, R_ring, 0, c, t[c], step[c], R, 3)
    assert drift_nis(t_ring, nu_ring, R_ring, 0, 2, 1, 3) < 1e-12  # (a constant passes the plain test)
    assert drift_nis_from_anchor(t_ring, nu_ring, R_ring, *anc, 0, 2, 2, 3) > chi2.ppf(0.9999, 3)


@functools.cache
def _knocked(reacquire=True):
    """At rest on the truth, consistent; at 20 s the IMU reports 1 s of 2 m/s^2 north that never
    happened; fixes stated at 0.2 m (10x their R)."""
    t_fix = np.arange(0.5, 60.0, 1.0)
    meas = _fixes(t_fix, np.zeros((t_fix.size, 3)))
    return _run(_nav(), 0.05, 0.01, meas, seconds=60.0, stated=10.0, knock=(20.0, 21.0, 2.0), reacquire=reacquire)


def test_a_filter_knocked_off_by_a_jump_reacquires_its_fixes():
    """The knock (`_knocked`): the filter runs off (1 m, then 2 m/s) with a covariance of
    centimetres. The fixes that follow continue that error from where the last accepted one left
    the filter, far beyond their stated accuracy: re-acquired (covariance grown) by the sixth. The
    old rule (the sixth in as it is, each sixth after) leaves it metres off for half a minute."""
    run = _knocked()
    acc, infl = run.ev_accepted, run.ev_inflation
    assert acc[:20].all() and not acc[20:23].any()
    j = 20 + np.flatnonzero(infl[20:, 0] > 1.0)
    assert j.size == 1 and j[0] <= 25 and acc[j[0]]  # re-acquired once, by the 6th rejected fix
    assert np.flatnonzero(run.ev_jump).tolist() == [j[0]]  # and read as a jump (the trial kept JUMP)
    assert np.all(infl[:, 1] == 1.0)  # nothing down-weighted
    old = _knocked(reacquire=False)
    assert np.max(np.abs(_north_error_m(old))[old.ep_idx[(old.t_s[old.ep_idx] >= 30.0)]]) > 3.0


def test_a_knocked_filter_reacquired_is_back_and_stays_back():
    """After the re-acquisition the filter is back within centimetres and stays there: no second
    drift (no later fix fails the gate). The next ten fixes favour the JUMP reading strongly (the
    DRIFT reading's grown cross terms let the fix turn the tilt by 0.56 mrad, a second drift of
    0.45 m): the cross terms are kept (`fusion.reacquire`, the trial)."""
    run = _knocked()
    acc, infl = run.ev_accepted, run.ev_inflation
    j = 20 + np.flatnonzero(infl[20:, 0] > 1.0)
    err = np.abs(_north_error_m(run))
    t_ep = run.t_s[run.ep_idx]
    # 0.05 m (set before the first run): 2.5 SDs of the 2 cm fixes (the filter without the knock reaches 0.034 m)
    assert np.max(err[run.ep_idx[(t_ep >= 30.0) & (t_ep < 35.0)]]) < 0.05  # back (metres off before)
    assert acc[j[0]:].all()  # no second drift: every later fix passes the gate


def test_fixes_wandering_within_their_stated_accuracy_are_not_taken_for_a_drift():
    """At rest on the truth; the fixes wander 0.5 m (a 40 s sine: a receiver's slowly varying error)
    with an R of 2 cm (matched to their fix-to-fix scatter) and a stated accuracy of 1.5 m. Runs of
    rejections come, and the rejected fixes agree with each other, but each is within its stated
    accuracy: no covariance is ever grown (the sixth goes in as it is, as before re-acquisition).
    Stated = R (factor 1), the same fixes would be taken for a drift and re-acquired."""
    t_fix = np.arange(0.5, 60.0, 1.0)
    off = np.zeros((t_fix.size, 3))
    off[:, 0] = 0.5 * np.sin(2.0 * np.pi * t_fix / 40.0)
    meas = _fixes(t_fix, off)
    run = _run(_nav(), 0.05, 0.01, meas, seconds=60.0, stated=75.0)
    assert (~run.ev_accepted).sum() >= 10  # runs of rejections
    assert np.all(run.ev_inflation == 1.0) and not run.ev_jump.any()  # never re-acquired nor down-weighted
    old = _run(_nav(), 0.05, 0.01, meas, seconds=60.0, reacquire=False)
    assert_allclose(run.ev_nis, old.ev_nis, rtol=0, atol=0)  # the old rule exactly
    tight = _run(_nav(), 0.05, 0.01, meas, seconds=60.0, stated=1.0)
    assert np.any(tight.ev_inflation[:, 0] > 1.0)


@functools.cache
def _started_off():
    """The nominal 5 m north of the truth, moving north at 0.2 m/s; P says 5 cm and 1 cm/s."""
    t_fix = np.arange(0.5, 30.0, 1.0)
    return _run(_nav(5.0, 0.2), 0.05, 0.01, _fixes(t_fix, np.zeros((t_fix.size, 3))))


def test_a_filter_that_starts_off_is_brought_back():
    """The nominal starts 5 m north of the truth, moving north at 0.2 m/s, with a covariance that
    says 5 cm and 1 cm/s: every fix fails the gate and no accepted row says where the filter's error
    stood: the sixth goes in down-weighted to the gate's edge; from that anchor on the rejected fixes
    continue the filter's error: re-acquired within three more."""
    run = _started_off()
    acc, infl = run.ev_accepted, run.ev_inflation
    assert not acc[:5].any() and acc[5] and infl[5, 1] > 1.0 and infl[5, 0] == 1.0
    j = np.flatnonzero(infl[:, 0] > 1.0)
    assert j.size >= 1 and j[0] <= 8 and acc[j[0]]
    assert np.all(np.delete(infl[:, 1], 5) == 1.0)


def test_a_filter_that_starts_off_is_back_to_decimetres():
    """After its re-acquisitions the started-off filter stays within decimetres from 12 s on (4 s after the first):
    read as a JUMP (under DRIFT each re-acquisition turned the tilt: later drifts, 0.44 m from 12 s)."""
    run = _started_off()
    err = np.abs(_north_error_m(run))
    # 0.3 m (set before the first run): decimetres, the 6 m drift taken out, not yet the fixes' 2 cm
    assert np.max(err[run.ep_idx[run.t_s[run.ep_idx] >= 12.0]]) < 0.3  # 6 m off before


def test_multipath_jumps_and_back_stay_rejected():
    """A consistent filter on the truth; fixes 6-13 jump 2-5 m north, scattering, then come back:
    no re-acquisition; the jumped fixes are rejected but the sixth of the run, which goes in
    down-weighted to the gate's edge (R grown ~10^4-fold, where the old rule applied it with its
    stated R), and the filter stays on the truth."""
    t_fix = np.arange(0.5, 30.0, 1.0)
    off = np.zeros((t_fix.size, 3))
    off[6:14, 0] = [3.0, 4.5, 2.0, 5.0, 2.5, 4.0, 3.0, 5.0]
    run = _run(_nav(), 0.05, 0.01, _fixes(t_fix, off))
    acc, infl = run.ev_accepted, run.ev_inflation
    assert acc[:6].all() and acc[14:].all()
    assert not acc[6:11].any() and acc[11] and not acc[12:14].any()
    assert np.all(infl[:, 0] == 1.0)  # never taken for a drifted filter
    assert infl[11, 1] > 1e3 and np.all(np.delete(infl[:, 1], 11) == 1.0)
    assert_allclose(run.ev_nis[11], chi2.ppf(0.9999, 3), rtol=1e-9)  # its influence: a fix at the gate's edge
    assert np.max(np.abs(_north_error_m(run))) < 0.5  # an 8 s coast's own drift, not the fixes' 2-5 m


def test_without_reacquisition_the_sixth_rejected_fix_goes_in_as_it_is():
    """`FilterConfig.reacquire` False (the drive pipeline's tuning passes): a drifted filter lets the
    sixth rejected fix in ungated, with its own R and the covariance as it was."""
    t_fix = np.arange(0.5, 30.0, 1.0)
    run = _run(_nav(5.0, 0.2), 0.05, 0.01, _fixes(t_fix, np.zeros((t_fix.size, 3))), reacquire=False)
    assert not run.ev_accepted[:5].any() and run.ev_accepted[5]
    assert np.all(run.ev_inflation == 1.0)
    assert run.ev_nis[5] > chi2.ppf(0.9999, 3)  # applied above the gate, as it came


def _slipped(blip_m, reacquire=True):
    """At rest, the truth's own fixes but fix 3, `blip_m` north; a prior velocity SD of 0.3 m/s
    (honest: the nominal's is exact), so that the blip's gain reaches the velocity."""
    t_fix = np.arange(0.5, 30.0, 1.0)
    off = np.zeros((t_fix.size, 3))
    off[3, 0] = blip_m
    return _run(_nav(), 0.05, 0.3, _fixes(t_fix, off, noise_sd_m=0.0), reacquire=reacquire)


def test_a_fix_that_slipped_under_the_gate_is_revised_when_the_next_fails_it():
    """Fix 3 is 0.15 m off (7.5 SD; NIS 14.5 under the gate's 21.1: taken): its pull on the velocity
    makes the next, exact fix fail the gate, and without the revision the filter drifts 0.28 m on
    exact fixes (the rule before: navego's first minute). With it the stretch is run again without
    fix 3, the next fix passes, and fix 3 is the one rejected."""
    old = _slipped(0.15, reacquire=False)
    assert old.ev_accepted[3] and old.ev_nis[3] < chi2.ppf(0.9999, 3) and not old.ev_accepted[4]
    assert np.max(np.abs(_north_error_m(old))) > 0.2  # 10 SD of the fixes
    run = _slipped(0.15)
    assert not run.ev_accepted[3] and np.delete(run.ev_accepted, 3).all()
    assert_allclose(run.ev_nis[3], old.ev_nis[3], rtol=1e-9)  # judged from the same state as before
    # exact IMU and fixes but the one left out: the filter on the truth (1 cm: half the fixes' SD)
    assert np.max(np.abs(_north_error_m(run))) < 0.01


def test_a_wild_fix_after_good_ones_is_the_one_rejected():
    """Fix 3 is 0.5 m off (beyond the gate from either state): the revision keeps the reading as it
    went: fix 3 rejected, the fixes before and after it taken, the filter on the truth."""
    run = _slipped(0.5)
    assert not run.ev_accepted[3] and np.delete(run.ev_accepted, 3).all()
    assert np.all(run.ev_inflation == 1.0)
    assert np.max(np.abs(_north_error_m(run))) < 0.01  # as above
