"""The filter wrapper (`fusion.engine`): measurement rows, validation, covariance-epoch lookup, and
a backward run that ends where the forward run started."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from tpos_cli.frames.earth import normal_gravity_mps2
from tpos_cli.fusion._kernels import LoopState, _copy_state
from tpos_cli.fusion.engine import (
    ENDS_ONLY,
    FilterConfig,
    FilterRun,
    InitialState,
    Measurements,
    SymmetricStack,
    backward_start,
    epoch_of,
    run_filter,
)
from tpos_cli.fusion.measurements import Kind


def test_merge_sorts_by_time_and_shifts_the_fix_sensitivity_rows():
    a = Measurements.rows([2.0, 4.0], Kind.FIX_NE, np.zeros((2, 2)), np.tile(np.eye(2), (2, 1, 1)), dim=2, gated=True,
                          par=[0, 1], sens=np.arange(2 * 2 * 3, dtype=float).reshape(2, 2, 3))
    b = Measurements.rows([3.0, 1.0], Kind.FIX_NE, np.zeros((2, 2)), np.tile(np.eye(2), (2, 1, 1)), dim=2, gated=True,
                          par=[1, 0], sens=100 + np.arange(2 * 2 * 3, dtype=float).reshape(2, 2, 3))
    z = Measurements.rows([2.5], Kind.ZUPT, np.zeros((1, 3)), np.eye(3)[None], dim=3, gated=False)
    m = Measurements.merge(a, z, b)
    assert_allclose(m.t_s, [1.0, 2.0, 2.5, 3.0, 4.0])
    assert list(m.kind) == [Kind.FIX_NE, Kind.FIX_NE, Kind.ZUPT, Kind.FIX_NE, Kind.FIX_NE]
    # each fix still points at its own sensitivity rows
    assert m.sens[m.par[0], 0, 0] == 100 and m.sens[m.par[3], 0, 0] == 106
    assert m.sens[m.par[1], 0, 0] == 0 and m.sens[m.par[4], 0, 0] == 6
    assert m.R[2, 2, 2] == 1.0 and m.dim[2] == 3 and not m.gated[2]


def test_copy_state_copies_every_array_of_the_loop_state_exactly():
    """The re-acquisition's checkpoint and rewind (`_kernels._copy_state`, written by elements): every
    array, of each dtype and dimension the loop holds, equal bit for bit to its source afterwards."""
    rng = np.random.default_rng(3)
    n, s, w = 17, 2, 5
    shapes = [(n, n), (6,), (3, 3), (8,), (n,), (3,), (3,), (s,), (s, w), (s, w, 3), (s, w, 3, 3), (s,), (s, 3),
              (s, 3, 3), (s,)]
    src = LoopState(*[rng.normal(size=shape) for shape in shapes])
    src = src._replace(consecutive=rng.integers(0, 9, s), anc_ok=np.array([True, False]))
    dst = LoopState(*[np.zeros_like(a) for a in src])
    _copy_state(src, dst)
    for name, a, b in zip(LoopState._fields, src, dst):
        assert a.dtype == b.dtype and np.array_equal(a, b), name


def _still(n=2001, dt=0.01):
    lat = np.radians(45.0)
    t = np.arange(n) * dt
    acc = np.tile([0.0, 0.0, -normal_gravity_mps2(lat, 100.0)], (n, 1))
    w_ie = 7.292115e-5
    gyro = np.tile([w_ie * np.cos(lat), 0.0, -w_ie * np.sin(lat)], (n, 1))  # body = NED, at rest
    nav = np.array([lat, np.radians(7.0), 100.0, 0.0, 0.0, 0.0])
    P0 = np.diag(np.r_[np.full(3, 1.0), np.full(3, 0.1), np.full(3, 1e-3), np.full(3, 1e-3), np.full(3, 1e-5)] ** 2)
    cfg = FilterConfig(np.array([1e-4, 1e-8, 1e-12, 1e-14]), 0.0, 0.0, cov_step=10)
    return t, gyro, acc, InitialState(nav, np.eye(3), np.zeros(6), P0), cfg


def test_backward_run_at_rest_returns_to_the_start_with_forward_time_signs():
    t, gyro, acc, init, cfg = _still()
    zupt = Measurements.rows(np.arange(0.05, 20.0, 0.5), Kind.ZUPT, np.zeros((40, 3)), np.tile(1e-4 * np.eye(3), (40, 1, 1)),
                             dim=3, gated=False)
    fwd = run_filter(t, gyro, acc, init, cfg, zupt)
    bwd = run_filter(t, gyro, acc, backward_start(fwd, init.P0), cfg, zupt, backward=True)
    assert isinstance(bwd, FilterRun) and bwd.backward and bwd.ep_dx is None and bwd.ep_Phi is None
    # exact IMU of a body at rest: both runs stay put (mm, mm/s; the normal-gravity model is the truth)
    for run in (fwd, bwd):
        assert_allclose(run.nav[:, 3:], 0.0, atol=1e-3)
        assert_allclose((run.nav[:, 2] - 100.0), 0.0, atol=1e-2)
    assert np.all(np.diff(bwd.ep_idx) > 0) and bwd.ep_idx[-1] == t.size - 1
    # covariances in forward order: the backward run is most certain near its start, the end of the log
    assert bwd.ep_P[-1, 0, 0] < bwd.ep_P[0, 0, 0]
    assert np.all(np.isfinite(fwd.ev_nis)) and fwd.ev_accepted.all()


def test_nominal_kept_at_chosen_samples_equals_the_full_history():
    """`FilterConfig.nominal_idx`: the runs store the nominal at those samples (and the ends) only,
    the same numbers as a run that stores every sample; covariances and residuals unchanged."""
    t, gyro, acc, init, cfg = _still(n=501)
    acc = acc + 0.01 * np.sin(np.arange(t.size) / 7.0)[:, None]  # not at rest: the nominal moves
    zupt = Measurements.rows(np.arange(0.05, 5.0, 0.5), Kind.ZUPT, np.zeros((10, 3)), np.tile(1e-4 * np.eye(3), (10, 1, 1)),
                             dim=3, gated=False)
    keep = np.array([3, 40, 41, 250, 333])
    cfg_k = FilterConfig(cfg.q, cfg.tau_acc_s, cfg.tau_gyro_s, cfg.cov_step, nominal_idx=keep)
    for backward in (False, True):
        start = init if not backward else backward_start(run_filter(t, gyro, acc, init, cfg, zupt), init.P0)
        full = run_filter(t, gyro, acc, start, cfg, zupt, backward=backward)
        part = run_filter(t, gyro, acc, start, cfg_k, zupt, backward=backward)
        idx = np.r_[0, keep, t.size - 1]
        assert list(part.idx) == list(idx) and list(part.rows(keep)) == [1, 2, 3, 4, 5]
        for a in ("nav", "C_nb", "bias"):
            np.testing.assert_array_equal(getattr(part, a), getattr(full, a)[idx])
        np.testing.assert_array_equal(part.ep_P.tril, full.ep_P.tril)
        np.testing.assert_array_equal(part.ev_nu, full.ev_nu)
        with pytest.raises(ValueError, match="nominal_idx"):
            part.rows([5])
        # a tuning pass's run: the ends only, the same measurement results and end state
        ends = run_filter(t, gyro, acc, start, FilterConfig(cfg.q, cfg.tau_acc_s, cfg.tau_gyro_s, cfg.cov_step,
                                                            nominal_idx=ENDS_ONLY), zupt, backward=backward)
        assert list(ends.idx) == [0, t.size - 1]
        np.testing.assert_array_equal(ends.nav, full.nav[[0, -1]])
        np.testing.assert_array_equal(ends.ev_nis, full.ev_nis)
        np.testing.assert_array_equal(ends.ep_P.tril, full.ep_P.tril)


def test_backward_run_into_the_spent_rts_history_gives_the_same_numbers():
    """`run_filter(reuse=)`: the backward run written into the forward run's RTS history (no longer
    read after the smoother) holds the same numbers as one in fresh arrays, in that memory."""
    t, gyro, acc, init, cfg = _still(n=501)
    acc = acc + 0.01 * np.sin(np.arange(t.size) / 7.0)[:, None]
    zupt = Measurements.rows(np.arange(0.05, 5.0, 0.5), Kind.ZUPT, np.zeros((10, 3)), np.tile(1e-4 * np.eye(3), (10, 1, 1)),
                             dim=3, gated=False)
    fwd = run_filter(t, gyro, acc, init, cfg, zupt)
    start = backward_start(fwd, init.P0)
    fresh = run_filter(t, gyro, acc, start, cfg, zupt, backward=True)
    spent = (fwd.ep_Phi, fwd.ep_Ppred)
    fwd.ep_Phi[...] = np.nan  # whatever the smoother left there
    fwd.ep_Ppred[...] = np.nan
    into = run_filter(t, gyro, acc, start, cfg, zupt, backward=True, reuse=spent)
    assert np.shares_memory(into.ep_P.tril, fwd.ep_Phi) or np.shares_memory(into.ep_P.tril, fwd.ep_Ppred)
    for a in ("nav", "C_nb", "bias", "ep_idx", "ev_nu", "ev_pvar", "ev_nis", "ev_accepted"):
        np.testing.assert_array_equal(getattr(into, a), getattr(fresh, a))
    np.testing.assert_array_equal(into.ep_P.tril, fresh.ep_P.tril)


def test_reused_carves_views_first_fit_and_falls_back_to_new_arrays():
    from tpos_cli.fusion.engine import _reused

    a, b = np.zeros((4, 5)), np.zeros(7)
    x, y, z, w = _reused((a, None, np.zeros(50, dtype=np.int64), np.zeros((9, 9))[:, :3], b), (3, 5), (2, 3), (5,), (4,))
    assert x.shape == (3, 5) and np.shares_memory(x, a)
    assert y.shape == (2, 3) and np.shares_memory(y, b)  # a has 5 left: the next with room
    assert z.shape == (5,) and np.shares_memory(z, a) and not np.shares_memory(z, x)
    assert w.shape == (4,) and not any(np.shares_memory(w, v) for v in (a, b))  # none has room left: a new array
    assert all(v.flags.c_contiguous and v.dtype == np.float64 for v in (x, y, z, w))


@pytest.mark.parametrize("idx", [[0, 5, 9], [5], [3, 4], [9, 0], [2, 2, 3], [], [0, 9], [1, 8]])
def test_nominal_rows_are_sorted_unique_with_both_ends(idx):
    from tpos_cli.fusion.engine import _nominal_idx

    got = _nominal_idx(np.array(idx, dtype=np.int64), 10)
    np.testing.assert_array_equal(got, np.union1d(np.array(idx, dtype=np.int64), [0, 9]))
    assert got.dtype == np.int64


def test_symmetric_stack_indexes_like_the_full_array():
    rng = np.random.default_rng(0)
    E, n = 50, 7
    A = rng.standard_normal((E, n, n))
    P = A @ A.transpose(0, 2, 1)
    i, j = np.tril_indices(n)
    S = SymmetricStack(np.ascontiguousarray(P[:, i, j]), n)
    e = rng.integers(0, E, 30)
    keys = [3, -1, (slice(None), 3, 3), (slice(2, 9), slice(None, 4), slice(None, 4)), (e,), (e, slice(None, 5), slice(None, 5)),
            (e, 6, 6), (e, slice(None, 3), 6), (rng.random(E) > 0.5, 2, slice(None)), (e, 4), (5, slice(1, 3), 0)]
    for k in keys:
        np.testing.assert_array_equal(S[k], P[k])
    assert S.shape == P.shape and S.take(np.array([0, E - 1]))[1].tolist() == P[-1].tolist()
    np.testing.assert_array_equal(S.leading(4)[:], P[:, :4, :4])


def test_epoch_of_takes_the_data_side():
    t, gyro, acc, init, cfg = _still(n=101)
    fwd = run_filter(t, gyro, acc, init, cfg, Measurements.rows([], Kind.ZUPT, [], [], dim=3, gated=False))
    assert list(fwd.ep_idx) == [0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100]
    assert list(epoch_of(fwd, np.array([0, 5, 10, 99, 100]))) == [0, 0, 1, 9, 10]
    bwd = run_filter(t, gyro, acc, backward_start(fwd, init.P0), cfg, fwd.measurements, backward=True)
    e = epoch_of(bwd, np.array([0, 5, 10, 99, 100]))
    assert list(bwd.ep_idx[e]) == [0, 10, 10, 100, 100]


def test_wrapper_names_what_is_wrong():
    t, gyro, acc, init, cfg = _still(n=11)
    m = Measurements.rows([0.05], Kind.RANGE, [3.0], [0.01], dim=1, gated=True)
    with pytest.raises(ValueError, match="origin_lla"):
        run_filter(t, gyro, acc, init, cfg, m)
    with pytest.raises(ValueError, match="`q`"):
        run_filter(t, gyro, acc, init, FilterConfig(np.array([1.0, -1.0, 0.0, 0.0]), 0.0, 0.0), m)
    with pytest.raises(ValueError, match="`gyro_b_rps`"):
        run_filter(t, gyro[:, :2], acc, init, cfg, m)


def _fixes_at_rest(t_run, nav, C_true, dl_true_m, sd_h_m, sd_v_m, rng):
    """GPS position rows at 1 Hz of an antenna at C_true (dl, 0) from a standing IMU at nav, white
    noise of SDs sd_h_m, sd_v_m: (Measurements, n rows)."""
    from tpos_cli.frames.earth import ned_rate_to_lla_rate

    tf = np.arange(0.5, t_run[-1], 1.0)
    ant = C_true @ np.array([dl_true_m[0], dl_true_m[1], 0.0])
    e = rng.standard_normal((tf.size, 3)) * [sd_h_m, sd_h_m, sd_v_m]
    lla = np.tile(nav[:3], (tf.size, 1))
    lla += ned_rate_to_lla_rate(lla[:, 0], lla[:, 2], ant + e)
    R = np.diag([sd_h_m**2, sd_h_m**2, sd_v_m**2])
    return Measurements.rows(tf, Kind.GPS_POSITION, lla, np.tile(R, (tf.size, 1, 1)), dim=3, gated=False), tf.size


def test_fixes_at_rest_after_a_stops_first_carry_no_yaw_lever_second_order_variance():
    """A standing vehicle whose heading is known to 3 deg (nothing observes it at rest) and whose
    lever-arm correction has its 1 m prior: the yaw x lever-arm second-order term (5 cm) is one
    constant over the stop, absorbed by the position at the stop's first fix. With the stop stated
    (`FilterConfig.rest_intervals_s`) the later fixes' NIS is chi-square with their dof (4 mm fixes,
    an IMU whose noise is the filter's q); counted at every fix, the fixes read 5 cm and the mean
    NIS falls under its band (the old behaviour, part 1's starting stop: 0.2 of 3)."""
    from scipy.stats import chi2

    from tpos_cli.frames.rotation import euler_to_dcm
    from tpos_cli.fusion.layout import StateLayout, lever_arm_block

    t, gyro, acc, init, cfg = _still(n=6001)
    dt = t[1] - t[0]
    P0 = init.P0.copy()
    P0[8, 8] = np.radians(3.0) ** 2
    lay = StateLayout((lever_arm_block(1.0),))
    nis = {True: [], False: []}
    for seed in range(4):
        rng = np.random.default_rng(seed)
        g = gyro + rng.standard_normal(gyro.shape) * np.sqrt(cfg.q[1] / dt)  # the noise the filter's q states
        a = acc + rng.standard_normal(acc.shape) * np.sqrt(cfg.q[0] / dt)
        yaw_err = rng.standard_normal() * np.radians(3.0)  # the nominal's heading error, drawn from its prior
        C_true = euler_to_dcm(0.0, 0.0, yaw_err)
        meas, n = _fixes_at_rest(t, init.nav, C_true, rng.standard_normal(2) * 0.3, 0.004, 0.01, rng)
        for stated in (True, False):
            c = FilterConfig(cfg.q, 0.0, 0.0, cov_step=10, layout=lay,
                             rest_intervals_s=np.array([[-1.0, t[-1] + 1.0]]) if stated else None)
            run = run_filter(t, g, a, InitialState(init.nav, np.eye(3), init.bias, P0), c, meas)
            nis[stated].append(run.ev_nis[3:])  # after the first fixes (the prior's 1 m)
    for stated, rows in nis.items():
        v = np.concatenate(rows)
        lo, hi = chi2.ppf([0.005, 0.995], 3 * v.size) / v.size  # rows of a consistent filter: independent
        if stated:
            assert lo <= v.mean() <= hi, (v.mean(), lo, hi)
        else:
            assert v.mean() < lo, (v.mean(), lo)


def test_velocity_rows_at_a_stop_leave_yaw_alone_forward_and_backward():
    """Heading is not observable at a standstill, but 3 mm/s GPS velocity rows (at-rest R) over a
    20 s stop gyrocompass a MEMS-grade gyro through the INS error dynamics: the yaw SD falls 15 ->
    ~5 deg and the nominal's 10 deg yaw error is pulled (the walk log's opening stop; notes nis20
    job 3). With the stop stated (`FilterConfig.standstill_intervals_s`) those rows' gain leaves yaw alone
    (`filters.kalman.update_holding`): the yaw and its SD stay the run's without the rows (to
    0.1 %: the rows still correct tilt and gyro bias, which the yaw's propagation shares), while the
    tilt is learned as before."""
    from tpos_cli.frames.rotation import euler_to_dcm

    t, gyro, acc, init, _ = _still()
    dt = t[1] - t[0]
    P0 = init.P0.copy()
    P0[6, 6] = P0[7, 7] = np.radians(0.5) ** 2
    P0[8, 8] = np.radians(15.0) ** 2
    P0[9:12, 9:12] = np.eye(3) * np.radians(0.05) ** 2
    q = np.array([1e-4, 1e-6, 1e-12, 1e-12])  # a MEMS gyro's angle random walk
    rng = np.random.default_rng(0)
    g = gyro + rng.standard_normal(gyro.shape) * np.sqrt(q[1] / dt)
    a = acc + rng.standard_normal(acc.shape) * np.sqrt(q[0] / dt)
    tv = np.arange(0.1, 19.9, 0.25)
    sd = 0.003
    vel = Measurements.rows(tv, Kind.GPS_VELOCITY, rng.standard_normal((tv.size, 3)) * sd,
                            np.tile(sd**2 * np.eye(3), (tv.size, 1, 1)), dim=3, gated=False)
    none = Measurements.rows([], Kind.ZUPT, np.zeros((0, 3)), np.zeros((0, 3, 3)), dim=3, gated=False)
    start = InitialState(init.nav, euler_to_dcm(0.0, 0.0, np.radians(10.0)), init.bias, P0)

    def run(meas, stop, backward):
        c = FilterConfig(q, 0.0, 0.0, cov_step=10, standstill_intervals_s=np.array([[-1.0, 30.0]]) if stop else None)
        r = run_filter(t, g, a, start, c, meas, backward=backward)
        j = 0 if backward else -1  # the run's last epoch
        C = r.C_nb[j]
        return np.degrees(np.arctan2(C[1, 0], C[0, 0])), np.degrees(np.sqrt(r.ep_P[j][8, 8])), np.sqrt(r.ep_P[j][6, 6])

    for backward in (False, True):
        yaw0, sd0, tilt0 = run(none, False, backward)
        yaw_old, sd_old, _ = run(vel, False, backward)
        yaw_held, sd_held, tilt_held = run(vel, True, backward)
        assert sd_old < 0.5 * sd0 and abs(yaw_old - yaw0) > 2.0, (sd_old, sd0, yaw_old, yaw0)  # the old behaviour
        assert abs(sd_held / sd0 - 1.0) < 1e-3 and abs(yaw_held - yaw0) < 0.01, (sd_held, sd0, yaw_held, yaw0)
        assert tilt_held < 0.5 * tilt0  # the rows still level the platform


def test_white_noise_inside_a_stop_is_scaled_by_its_factors_forward_and_backward():
    """`FilterConfig.q_stops`: over a stop the velocity and attitude white PSDs are the run's times
    the stop's factors (the kernel's `stop_process_noise`); before it the run is the plain one. A
    stop covering the whole run equals a run with the PSDs scaled, in both directions."""
    t, gyro, acc, init, cfg = _still()
    none = Measurements.rows([], Kind.ZUPT, np.zeros((0, 3)), np.zeros((0, 3, 3)), dim=3, gated=False)
    f = np.array([0.04, 0.25])
    whole = FilterConfig(cfg.q, 0.0, 0.0, cov_step=10, q_stops=np.array([[-1.0, 30.0, *f]]))
    scaled = FilterConfig(cfg.q * np.r_[f, 1.0, 1.0], 0.0, 0.0, cov_step=10)
    for backward in (False, True):
        a = run_filter(t, gyro, acc, init, whole, none, backward=backward)
        b = run_filter(t, gyro, acc, init, scaled, none, backward=backward)
        assert_allclose(a.ep_P.tril, b.ep_P.tril, rtol=1e-9, atol=1e-30)
    # a stop over [10, 30] s (the run ends at 20 s): the plain run before it; over it the velocity
    # variance grows less by the PSDs taken away, (1 - f_a) q_a T + (1 - f_g) q_g g^2 T^3 / 3 (the
    # tilt's share), to 5 % (discrete covariance steps)
    part = FilterConfig(cfg.q, 0.0, 0.0, cov_step=10, q_stops=np.array([[10.0, 30.0, *f]]))
    p, o = run_filter(t, gyro, acc, init, part, none), run_filter(t, gyro, acc, init, cfg, none)
    before = t[p.ep_idx] <= 10.0
    assert_allclose(p.ep_P.tril[before], o.ep_P.tril[before], rtol=1e-12)
    T, g = t[-1] - 10.0, acc[0, 2]
    taken = (1 - f[0]) * cfg.q[0] * T + (1 - f[1]) * cfg.q[1] * g**2 * T**3 / 3
    assert_allclose(o.ep_P[-1, 3, 3] - p.ep_P[-1, 3, 3], taken, rtol=0.05)
