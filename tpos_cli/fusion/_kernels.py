"""The compiled INS error-state loop: mechanize every IMU sample, predict at covariance epochs,
update at measurements, feed back (closed loop, paper 003 Fig. 1).

One kernel serves every filter of the package (INS/GPS, INS/anchor ranges; forward, and backward
on reversed arrays with earth_sign = -1) and stores what every smoother needs. Its inputs are a
few named tuples of float64 arrays (numba compiles NamedTuples of arrays and scalars); the
documented wrapper that builds and validates them is `tpos_cli.fusion.engine.run_filter`.
Measurement kinds are dispatched by `fusion.measurements.measure`; extra states by
`fusion.layout` offsets.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from tpos_cli.filters.kalman import innovation_statistics, predict_trapezoid, transition_into, update_holding
from tpos_cli.fusion.layout import ATT, N_NAV, VEL, Block
from tpos_cli.fusion.measurements import Kind, measure
from tpos_cli.fusion.nav_errors import (
    apply_feedback,
    corrected_increments,
    error_dynamics,
    process_noise,
    window_acceleration_ned,
    window_rate_b,
    window_vibration_velocity_b,
)
from tpos_cli.fusion.reacquire import (
    DRIFT,
    JUMP,
    JUMP_LOG_ODDS,
    TRIAL_ROWS,
    anchor,
    anchors,
    deweight_to_fit,
    drift_degree,
    drift_nis_from_anchor,
    inflate_to_fit,
    nis_at_stated,
    remember,
    revision_favoured,
    ring,
    stated_factors,
    stated_R,
)
from tpos_cli.ins._kernels import mech_step

_NO_TRIAL, _FIRST, _SECOND, _REPLAY = 0, 1, 2, 3  # a re-acquisition's trial (`fusion.reacquire`): none; JUMP tried;
# DRIFT tried; JUMP chosen and its stretch run once more

# error_model="numpy" on every kernel: no zero-divisor test at each division (`tpos_cli.filters.kalman`).


class ImuArrays(NamedTuple):
    """t (N,) s, gyro (N, 3) rad/s, acc (N, 3) m/s^2: body-frame (FRD) mean rates over (t_{k-1}, t_k]."""

    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray


class Nominal(NamedTuple):
    """Nominal state: nav (6,) [lat rad, lon rad, h m, vn, ve, vd m/s], C (3, 3) C_nb, bias
    (6 + n_extra,) [acc m/s^2 (3), gyro rad/s (3), nominal of the extra states]."""

    nav: np.ndarray
    C: np.ndarray
    bias: np.ndarray


class Settings(NamedTuple):
    """q (4,) IMU PSDs [acc white, gyro white, acc-bias drive, gyro-bias drive] (SI); bias time
    constants (<= 0: random walk); earth_sign (-1 backward); cov_step (IMU samples per covariance
    epoch); extra_tau_s, extra_q (n_extra,) dynamics of the extra states; layout (N_BLOCKS,) int64
    offsets (`StateLayout.offsets`); gate (4,) chi-square thresholds by dimension; max_reject: 0
    applies every row of a slot (no gate), else the rejections of a slot after which the next
    rejected row goes in: as it is, or with reacquire as `fusion.reacquire` decides, against the
    GPS fixes' stated accuracy over their R, stated_sd_factor (4,) (`FilterConfig.stated_sd_factor`); store_rts; reverse_out:
    the nominal of sample k is stored at row N-1-k (a backward run's history in forward order,
    without a reversed copy of the run's largest arrays)."""

    q: np.ndarray
    tau_acc_s: float
    tau_gyro_s: float
    earth_sign: float
    cov_step: int
    extra_tau_s: np.ndarray
    extra_q: np.ndarray
    layout: np.ndarray
    gate: np.ndarray
    max_reject: int
    reacquire: bool
    stated_sd_factor: np.ndarray
    store_rts: bool
    reverse_out: bool
    q_stops: np.ndarray  # (K, 4) [t0, t1, acc factor, gyro factor] in the run's own time (`FilterConfig.q_stops`)


@njit(cache=True)
def stop_process_noise(q, q_stops, t_a, t_b, Qc):
    """The white-noise PSDs of Qc over [t_a, t_b]: q's, times each stop's factors over the share of
    the interval it covers (`FilterConfig.q_stops`)."""
    fa, fg = 1.0, 1.0
    span = t_b - t_a
    if span > 0.0:
        for j in range(q_stops.shape[0]):
            ov = min(t_b, q_stops[j, 1]) - max(t_a, q_stops[j, 0])
            if ov > 0.0:
                fa += (q_stops[j, 2] - 1.0) * ov / span
                fg += (q_stops[j, 3] - 1.0) * ov / span
    for i in range(3):
        Qc[VEL + i, VEL + i] = q[0] * fa
        Qc[ATT + i, ATT + i] = q[1] * fg


class EventArrays(NamedTuple):
    """Measurements sorted by k (the sample at which each is processed, >= 1): lag (s, t_k minus
    the measurement time, in the run's time direction), kind (`Kind`), dim (1-3), z (E, 3),
    R (E, 3, 3), gated (E,) bool, slot (E,) int64 (counter of consecutive rejections, -1 none),
    par (E,) int64 (per-kind parameter: anchor index, sens row), second_order (E,) the share of the
    lever arm's second-order variance a GPS row carries (`measurements._lever_second_order`; 1, or 0
    for a row at rest after its stop's first: `fusion.lever_arm.second_order_shares`), float_row (E,)
    bool: a GPS position row of an RTK float epoch, whose error holds the float offset state
    (`fusion.rtk_float.float_rows`), yaw_held (E,) bool: a velocity row (GPS, ZUPT) at a standstill, whose
    gain leaves yaw alone (`fusion.lever_arm.yaw_held_rows`)."""

    k: np.ndarray
    lag: np.ndarray
    kind: np.ndarray
    dim: np.ndarray
    z: np.ndarray
    R: np.ndarray
    gated: np.ndarray
    slot: np.ndarray
    par: np.ndarray
    second_order: np.ndarray
    float_row: np.ndarray
    yaw_held: np.ndarray


class Aiding(NamedTuple):
    """Per-kind parameters: lever_b (3,) antenna in body (m), zero3 (3,) zeros, anchors_ned (A, 3)
    local NED (m), r0_e (3,) ECEF origin of that frame, C_ne0 (3, 3) its ECEF->NED DCM, sens
    (S, 2, 1 + A) sensitivity rows of the least-squares fixes to the floor and calibration states,
    C_vb (3, 3) IMU body to vehicle axes (non-holonomic constraints), earth_sign (-1 backward)."""

    lever_b: np.ndarray
    zero3: np.ndarray
    anchors_ned: np.ndarray
    r0_e: np.ndarray
    C_ne0: np.ndarray
    sens: np.ndarray
    C_vb: np.ndarray
    earth_sign: float


class History(NamedTuple):
    """Outputs, preallocated: nominal after feedback (nav, C, bias) at the samples `rows` (K,)
    (increasing, in the run's own time; row r holds rows[r], row K-1-r with `Settings.reverse_out`) and per
    covariance epoch ep_idx, ep_P (after the updates; exactly symmetric, stored as its lower triangle
    by rows, `store_tril`), ep_dx (correction fed back), and with
    store_rts the transition from the previous epoch, which is block diagonal (the extra states
    have their own scalar dynamics): ep_Phi (E, 15, 15) its navigation block and ep_phi_extra
    (E, n_extra) its diagonal beyond, and ep_Ppred (E, n (n + 1) / 2) the predicted covariance
    (exactly symmetric, `filters.kalman.predict_trapezoid`) as its lower triangle by rows (`store_tril`)."""

    nav: np.ndarray
    C: np.ndarray
    bias: np.ndarray
    rows: np.ndarray
    ep_idx: np.ndarray
    ep_Phi: np.ndarray
    ep_phi_extra: np.ndarray
    ep_Ppred: np.ndarray
    ep_P: np.ndarray
    ep_dx: np.ndarray


class EventResults(NamedTuple):
    """Per measurement (kernel order): nu (E, 3) residual about the nominal, pvar (E, 3) diagonal
    of H P- H^T, nis (E,), logdet (E,) log det S, accepted (E,), inflation (E, 2) the factors
    a re-acquisition grew the navigation covariance by and a long-rejected scattering row's R was
    grown by before the update (1: none; pvar, nis and logdet are then those the update used),
    jump (E,) a re-acquired row read as a jump of the filter's position/velocity (`fusion.reacquire`:
    the trial kept JUMP; False where it kept DRIFT or nothing was re-acquired)."""

    nu: np.ndarray
    pvar: np.ndarray
    nis: np.ndarray
    logdet: np.ndarray
    accepted: np.ndarray
    inflation: np.ndarray
    jump: np.ndarray


@njit(cache=True, error_model="numpy")
def _store(dst, k, src):
    """dst[k] = src for dst (N, n) and src (n,), by elements (an array assignment compiles a
    formatted shape-mismatch error with it, 2 s of the first run)."""
    for i in range(src.shape[0]):
        dst[k, i] = src[i]


@njit(cache=True, error_model="numpy")
def _store2(dst, k, src):
    """dst[k] = src for dst (N, n, m) and src (n, m), by elements."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[k, i, j] = src[i, j]


@njit(cache=True, error_model="numpy")
def store_tril(dst, k, S):
    """dst[k] = the lower triangle of S (n, n) by rows (S[0, 0], S[1, 0], S[1, 1], S[2, 0], ...:
    numpy's `tril_indices` order), dst (E, n (n + 1) / 2)."""
    c = 0
    for i in range(S.shape[0]):
        for j in range(i + 1):
            dst[k, c] = S[i, j]
            c += 1


@njit(cache=True, error_model="numpy")
def _store_transition(out, k, Phi):
    """The RTS history's transition at epoch k: Phi's navigation block and its extra diagonal."""
    for i in range(N_NAV):
        for j in range(N_NAV):
            out.ep_Phi[k, i, j] = Phi[i, j]
    for i in range(Phi.shape[0] - N_NAV):
        out.ep_phi_extra[k, i] = Phi[N_NAV + i, N_NAV + i]


class LoopState(NamedTuple):
    """The filter loop's state within a sample that a re-acquisition's trial checkpoints and rewinds
    to (`fusion.reacquire`: the trial): the loop's own arrays (changed in place, never rebound), or a
    second set of the same shapes holding the checkpoint."""

    P: np.ndarray  # (n, n) error-state covariance
    nav: np.ndarray  # nominal position, velocity
    C: np.ndarray  # (3, 3) nominal attitude
    bias: np.ndarray  # accelerometer and gyro biases
    dx_sum: np.ndarray  # (n,) the covariance epoch's summed corrections
    dth_prev: np.ndarray  # (3,) the last angle increment, rad
    dv_prev: np.ndarray  # (3,) the last velocity increment, m/s
    consecutive: np.ndarray  # (slots,) int64: each slot's rejections in a row
    ring_t: np.ndarray  # each slot's last rejections (`fusion.reacquire.ring`)
    ring_nu: np.ndarray
    ring_R: np.ndarray
    anc_t: np.ndarray  # each slot's last accepted row, after its update (`fusion.reacquire.anchors`)
    anc_nu: np.ndarray
    anc_R: np.ndarray
    anc_ok: np.ndarray


@njit(cache=True, error_model="numpy", nogil=True)
def _copy1(src, dst):
    """dst[:] = src for 1-d arrays of one length, by elements (`_copy_state`)."""
    for i in range(src.shape[0]):
        dst[i] = src[i]


@njit(cache=True, error_model="numpy", nogil=True)
def _copy2(src, dst):
    """dst[:] = src for 2-d arrays of one shape, by elements."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@njit(cache=True, error_model="numpy", nogil=True)
def _copy3(src, dst):
    """dst[:] = src for 3-d arrays of one shape, by elements."""
    for i in range(src.shape[0]):
        _copy2(src[i], dst[i])


@njit(cache=True, error_model="numpy", nogil=True)
def _copy4(src, dst):
    """dst[:] = src for 4-d arrays of one shape, by elements."""
    for i in range(src.shape[0]):
        _copy3(src[i], dst[i])


@njit(cache=True, error_model="numpy", nogil=True)
def _copy_state(src, dst):
    """Every array of LoopState `src` copied into `dst`'s: a re-acquisition's checkpoint, or the
    rewind to it (`fusion.reacquire`). (By elements: array assignments `dst.P[:] = src.P` compiled
    numba's formatted shape-mismatch error for each array type, 28 % of the cached kernel's code and
    ~190 of the 790 symbols numba walks when it loads the kernel at every run.)"""
    _copy2(src.P, dst.P)
    _copy1(src.nav, dst.nav)
    _copy2(src.C, dst.C)
    _copy1(src.bias, dst.bias)
    _copy1(src.dx_sum, dst.dx_sum)
    _copy1(src.dth_prev, dst.dth_prev)
    _copy1(src.dv_prev, dst.dv_prev)
    _copy1(src.consecutive, dst.consecutive)
    _copy2(src.ring_t, dst.ring_t)
    _copy3(src.ring_nu, dst.ring_nu)
    _copy4(src.ring_R, dst.ring_R)
    _copy1(src.anc_t, dst.anc_t)
    _copy2(src.anc_nu, dst.anc_nu)
    _copy3(src.anc_R, dst.anc_R)
    _copy1(src.anc_ok, dst.anc_ok)


@njit(cache=True, error_model="numpy", nogil=True)
def _blank_state(like, n_slots):
    """A LoopState of the shapes of `like` (uninitialized): a checkpoint's storage."""
    ring_t, ring_nu, ring_R = ring(n_slots)
    anc_t, anc_nu, anc_R, anc_ok = anchors(n_slots)
    return LoopState(np.empty_like(like.P), np.empty_like(like.nav), np.empty_like(like.C), np.empty_like(like.bias),
                     np.empty_like(like.dx_sum), np.empty(3), np.empty(3), np.empty(n_slots, np.int64), ring_t, ring_nu, ring_R,
                     anc_t, anc_nu, anc_R, anc_ok)


@njit(cache=True, error_model="numpy", nogil=True)
def _rewind(saved, live, res, e_from, e_to, t, k, w_ib, f_sum):
    """Back to a checkpoint (`fusion.reacquire`: the trial and the revision run a stretch again): rows
    e_from..e_to-1 lose the marks their first run gave them (inflation, jump), `live` takes `saved`, and
    the rows' body rate and the epoch's specific-force sum restart at its sample k."""
    for i in range(e_from, e_to):
        res.inflation[i, 0] = 1.0
        res.inflation[i, 1] = 1.0
        res.jump[i] = False
    _copy_state(saved, live)
    for i in range(3):
        w_ib[i] = live.dth_prev[i] / (t[k] - t[k - 1])  # (the rows' body rate at sample k)
    f_sum[:] = 0.0


@njit(cache=True, error_model="numpy", nogil=True)
def error_state_kernel(imu, start, P0, st, ev, aid, ranging, out, res):
    """Closed-loop error-state filter over the whole (possibly reversed) arrays, from sample 0.

    Per IMU sample: bias-corrected increments, a strapdown step (`ins._kernels.mech_step`), the
    specific force summed over the covariance interval. Every `cov_step` samples, at every sample with
    a measurement and at the last one, a covariance epoch: F from the mean specific force over the
    interval, Phi (`filters.kalman.transition_into`), predict with the trapezoidal Qd
    (`filters.kalman.predict_trapezoid`); the nominal of the Gauss-Markov
    extra states decays by exp(-dt / tau); then each measurement of the sample in turn: residual
    and rows (`measurements.measure`), NIS, gate (NIS above gate[m] rejects it, unless not
    `gated` or `max_reject` is 0; after `max_reject` rejections of its slot the next rejected row
    goes in as it is, or with `reacquire` as `fusion.reacquire` decides: a drift of the filter from
    where its last accepted row left it, beyond the row's stated accuracy, is re-acquired (the
    position/velocity covariance grown until the row passes the gate, under the reading of the
    error the next rows favour: `fusion.reacquire`, the trial); after `max_reject`
    rejections a row beyond its stated accuracy goes in down-weighted to the gate's edge, one within
    it as it is; with reacquire, a GPS row that fails the gate right after its slot's previous row
    was accepted first has the stretch from before that row run again without it, and the likelier
    reading stands: `fusion.reacquire`, the revision), Joseph update and feedback into
    the nominal (the error state is reset to 0 after each, so each measurement is linearized
    about the latest nominal). ep_dx of the epoch is the sum of the corrections fed back.

    Returns (n_epochs, status): status 0 ok, else 1 + the sample index where an innovation
    covariance lost positive definiteness.
    """
    n_t = imu.t.shape[0]
    n = P0.shape[0]
    n_extra = n - N_NAV
    nav = start.nav.copy()
    C = start.C.copy()
    bias = start.bias.copy()
    x = np.zeros(n)
    P = P0.copy()
    F = np.zeros((n, n))
    Qc = np.zeros((n, n))
    process_noise(st.q, Qc)
    for i in range(n_extra):  # error_dynamics writes only F[:15, :15]
        if st.extra_tau_s[i] > 0.0:
            F[N_NAV + i, N_NAV + i] = -1.0 / st.extra_tau_s[i]
        Qc[N_NAV + i, N_NAV + i] = st.extra_q[i]
    Phi = np.empty((n, n))
    T = np.empty((n, n))  # predict_trapezoid's scratch
    Tt = np.empty((n, n))
    H1, H2, H3 = np.zeros((1, n)), np.zeros((2, n)), np.zeros((3, n))
    z1, z2, z3 = np.zeros(1), np.zeros(2), np.zeros(3)
    R1, R2, R3 = np.zeros((1, 1)), np.zeros((2, 2)), np.zeros((3, 3))
    f_n = np.empty(3)
    f_sum = np.zeros(3)
    f_mean = np.empty(3)
    acc_ned = np.zeros(3)  # the clock columns' acceleration (`window_acceleration_ned`)
    dth = np.empty(3)
    dv = np.empty(3)
    dth_prev = np.zeros(3)
    dv_prev = np.zeros(3)
    w_ib = np.zeros(3)
    w_gps = np.zeros(3)  # the GPS rows' body rate (`window_rate_b`)
    vib_b = np.zeros(3)
    vib_ned = np.zeros(3)  # the IMU's vibration velocity at a GPS velocity row (`window_vibration_velocity_b`)
    dx_sum = np.zeros(n)
    R_fb = np.empty((3, 3))  # apply_feedback's scratch
    work = np.empty((3, 3, 3))  # mech_step's
    n_ev = ev.k.shape[0]
    n_slots = 1
    for e in range(n_ev):
        n_slots = max(n_slots, ev.slot[e] + 1)
    consecutive = np.zeros(n_slots, np.int64)
    ring_t, ring_nu, ring_R = ring(n_slots)  # each slot's last rejections (`fusion.reacquire`)
    anc_t, anc_nu, anc_R, anc_ok = anchors(n_slots)  # each slot's last accepted row, after its update
    f_stated = np.ones(3)  # a row's factors from R to its stated accuracy (`fusion.reacquire.stated_factors`)
    # the re-acquisition's trial of its two readings (`fusion.reacquire`: the trial): the loop's state at the re-acquired row
    live = LoopState(P, nav, C, bias, dx_sum, dth_prev, dv_prev, consecutive, ring_t, ring_nu, ring_R, anc_t, anc_nu,
                     anc_R, anc_ok)
    ck = _blank_state(live, n_slots)
    # the revision (`fusion.reacquire`): the loop's state before the last accepted row of each GPS slot
    # (positions, velocities: `fusion.insgps` slots 0, 1), where it was, and the cost of the rows since
    rv0, rv1 = _blank_state(live, n_slots), _blank_state(live, n_slots)
    rv_at = np.zeros((2, 5), np.int64)  # per GPS slot: k, e, ep, r, last of its checkpoint
    rv_ok = np.zeros(2, np.bool_)
    rv_cost = np.zeros(2)  # sum of min(NIS, gate) + log det S over the rows since (its own included)
    revising = -1  # the row whose rejection is under revision: the replay skips its slot's previous row
    rv_skip = -1  # that previous row
    cost_kept = 0.0  # the stretch's cost as it went (the rejected row at the gate's edge)
    cost_revised = 0.0  # the replay's (the skipped row at the gate's edge)
    no_revision = -1  # the last row whose revision lost: the replay rejects it, and the rows before it, as before
    rewind_slot = -1  # set in the row loop: rewind to that slot's checkpoint
    ck_k, ck_e, ck_ep, ck_r, ck_last = 0, 0, 0, 0, 0
    trial = _NO_TRIAL  # _NO_TRIAL, _FIRST (JUMP tried), _SECOND (DRIFT tried), _REPLAY (JUMP chosen, re-run)
    reading = DRIFT
    trial_slot = -1
    trial_seen = 0  # rows of trial_slot after the re-acquired one
    score = 0.0  # the stretch's log-likelihood under the reading tried
    score_first = 0.0
    # covariance epoch 0 is the prior at sample 0 (what the smoothers start from)
    ep = 0  # (indexed by `ep`, not by the literal 0: numba would compile the stores once more for it)
    out.ep_idx[ep] = 0
    store_tril(out.ep_P, ep, P)
    out.ep_dx[ep] = 0.0
    if st.store_rts:
        out.ep_Phi[ep] = 0.0
        for i in range(N_NAV):
            out.ep_Phi[ep, i, i] = 1.0
        out.ep_phi_extra[ep] = 1.0
        store_tril(out.ep_Ppred, ep, P)
    rows = out.rows
    n_rows = rows.shape[0]
    every = n_rows == n_t  # every sample's nominal (rows = 0..n_t-1)
    r = 0  # the next row of the nominal history
    if n_rows > 0 and rows[0] == 0:
        row = n_rows - 1 if st.reverse_out else 0
        _store(out.nav, row, nav)
        _store2(out.C, row, C)
        _store(out.bias, row, bias)
        r += 1
    e = 0
    while e < n_ev and ev.k[e] < 1:  # measurements at or before the first sample are not used
        e += 1
    last = 0
    o_clock = st.layout[Block.CLOCK]
    dt_sum = 0.0
    k = 1
    resume = False  # rewound to a re-acquired row (`fusion.reacquire`: the trial): its sample's mechanization and predict are done
    while k < n_t:
        if not resume:
            dt = imu.t[k] - imu.t[k - 1]  # (written out: a helper inlined by numba (inline="always") cost 13 % of a run)
            corrected_increments(imu.gyro, imu.acc, k, bias, dt, dth, dv)
            mech_step(nav, C, dth, dv, dth_prev, dv_prev, dt, st.earth_sign, f_n, work)
            for i in range(3):
                dth_prev[i] = dth[i]
                dv_prev[i] = dv[i]
                f_sum[i] += f_n[i] * dt
            for i in range(3):
                w_ib[i] = dth[i] / dt
            dt_sum += dt
        has_ev = e < n_ev and ev.k[e] == k
        if resume or has_ev or k - last >= st.cov_step or k == n_t - 1:
            if not resume:
                for i in range(3):
                    f_mean[i] = f_sum[i] / dt_sum  # the mean specific force over the interval
                error_dynamics(nav, C, f_mean, st.earth_sign, st.tau_acc_s, st.tau_gyro_s, F)
                transition_into(F, dt_sum, Phi)
                if st.q_stops.shape[0]:
                    stop_process_noise(st.q, st.q_stops, imu.t[k] - dt_sum, imu.t[k], Qc)
                predict_trapezoid(x, P, Phi, Qc, dt_sum, T, Tt)  # P <- Phi P Phi^T + Qd, Qd trapezoidal
                ep += 1
                out.ep_idx[ep] = k
                if st.store_rts:
                    _store_transition(out, ep, Phi)
                    store_tril(out.ep_Ppred, ep, P)
                for i in range(n_extra):
                    if st.extra_tau_s[i] > 0.0:  # the nominal of a Gauss-Markov state follows its mean
                        bias[6 + i] *= np.exp(-dt_sum / st.extra_tau_s[i])
            resume = False
            while e < n_ev and ev.k[e] == k:
                m = ev.dim[e]
                is_gps = ev.kind[e] == Kind.GPS_POSITION or ev.kind[e] == Kind.GPS_VELOCITY
                if is_gps:  # the lever-arm terms: the platform's rate over a window, not one vibrating sample
                    window_rate_b(imu.t, imu.gyro, k, bias, w_gps)
                if ev.kind[e] == Kind.GPS_VELOCITY:
                    window_vibration_velocity_b(imu.t, imu.acc, k, vib_b)
                    for i in range(3):
                        vib_ned[i] = C[i, 0] * vib_b[0] + C[i, 1] * vib_b[1] + C[i, 2] * vib_b[2]
                if o_clock >= 0 and is_gps:
                    # the clock columns: the platform's mean acceleration over the window of its offset
                    oc = o_clock + 1 if ev.kind[e] == Kind.GPS_VELOCITY else o_clock
                    window_acceleration_ned(imu.t, imu.acc, k, C, bias, bias[6 + oc - N_NAV], acc_ned)
                if m == 1:
                    z, H, R = z1, H1, R1
                elif m == 2:
                    z, H, R = z2, H2, R2
                else:
                    z, H, R = z3, H3, R3
                measure(e, ev, aid, ranging, nav, C, bias, w_gps if is_gps else w_ib, acc_ned, vib_ned, st.layout, P, z, H, R)
                s, logdet = innovation_statistics(x, P, z, H, R, res.pvar[e])
                for i in range(m):
                    res.nu[e, i] = z[i]
                res.nis[e] = s
                res.logdet[e] = logdet
                slot = ev.slot[e]
                if trial != _NO_TRIAL and e > ck_e:  # the stretch scoring the reading under trial (`fusion.reacquire`: the trial)
                    score -= 0.5 * (min(s, st.gate[m]) + logdet)
                    if slot == trial_slot:
                        trial_seen += 1
                accept = (not ev.gated[e]) or s <= st.gate[m] or (slot >= 0 and st.max_reject <= 0)
                term = min(s, st.gate[m]) + logdet  # the row's cost (`fusion.reacquire`: the revision)
                revisable = st.reacquire and is_gps and m > 1 and ev.gated[e] and 0 <= slot < 2
                passed = s <= st.gate[m]  # (before any re-acquisition or down-weighting changes s)
                for i in range(2):
                    if rv_ok[i]:
                        rv_cost[i] += term
                if revising >= 0:  # the replay without the skipped row
                    if e == rv_skip:  # rejected: a rejection of its slot's run like any other
                        accept = False
                        cost_revised += st.gate[m] + logdet
                        remember(ring_t, ring_nu, ring_R, slot, consecutive[slot], imu.t[k] - ev.lag[e], z, R, m)
                    else:
                        cost_revised += term
                    if e == revising:
                        revising, rv_skip = -1, -1
                        if not revision_favoured(cost_revised, cost_kept):  # the row was the outlier: as it went
                            no_revision, rewind_slot = e, slot
                            break
                elif (revisable and not accept and consecutive[slot] == 0 and rv_ok[slot] and trial == _NO_TRIAL
                      and e > no_revision):  # this row or the slot's previous one wrong? (`fusion.reacquire`: the revision)
                    cost_kept = rv_cost[slot] - term + st.gate[m] + logdet
                    cost_revised = 0.0
                    revising, rv_skip, rewind_slot = e, rv_at[slot, 1], slot
                    break
                if not accept and slot >= 0 and e != rv_skip:
                    last_chance = consecutive[slot] >= st.max_reject
                    if not st.reacquire:  # the old rule: the row after max_reject rejections goes in as it is
                        accept = last_chance
                    else:  # filter or fixes wrong? (`fusion.reacquire`)
                        remember(ring_t, ring_nu, ring_R, slot, consecutive[slot], imu.t[k] - ev.lag[e], z, R, m)
                        stated_factors(ev.kind[e], st.stated_sd_factor, f_stated)
                        beyond = not (0.0 <= nis_at_stated(P, H, R, z, m, f_stated) <= st.gate[m])
                        a = drift_nis_from_anchor(ring_t, ring_nu, ring_R, anc_t, anc_nu, anc_R, anc_ok, slot,
                                                  consecutive[slot], drift_degree(ev.kind[e] == Kind.GPS_VELOCITY), m)
                        if beyond and 0.0 <= a <= st.gate[m]:  # a drift from the last accepted row, beyond the
                            stated_R(R, f_stated, m)  # stated accuracy: the filter drifted; the row at that accuracy,
                            if trial == _NO_TRIAL and revising < 0:  # the loop's state here, to try each reading
                                # from (`fusion.reacquire`: the trial; none in a revision's replay)
                                trial, reading, trial_slot, trial_seen, score = _FIRST, JUMP, slot, 0, 0.0
                                ck_k, ck_e, ck_ep, ck_r, ck_last = k, e, ep, r, last
                                _copy_state(live, ck)
                            res.inflation[e, 0] = inflate_to_fit(P, H, R, z, m, st.gate[m], reading == JUMP)  # P grown
                            res.jump[e] = reading == JUMP
                            accept = True
                        elif last_chance and beyond:  # not a drift: wrong fixes, in at the gate's edge
                            res.inflation[e, 1] = deweight_to_fit(P, H, R, z, m, st.gate[m])
                            accept = True
                        elif last_chance:  # within its stated accuracy: in as it is (its pull is bounded by it)
                            accept = True
                        if res.inflation[e, 0] != 1.0 or res.inflation[e, 1] != 1.0:
                            s, logdet = innovation_statistics(x, P, z, H, R, res.pvar[e])
                            res.nis[e] = s
                            res.logdet[e] = logdet
                if accept and revisable:  # the revision's checkpoint, or none for a row taken beyond the gate
                    rv_ok[slot] = passed and trial == _NO_TRIAL
                    if rv_ok[slot]:
                        _copy_state(live, rv0 if slot == 0 else rv1)
                        rv_at[slot, 0], rv_at[slot, 1], rv_at[slot, 2], rv_at[slot, 3], rv_at[slot, 4] = k, e, ep, r, last
                        rv_cost[slot] = term
                if accept:
                    # a velocity row at a standstill does not correct yaw (`fusion.lever_arm.yaw_held_rows`)
                    if update_holding(x, P, z, H, R, ATT + 2 if ev.yaw_held[e] else -1) < 0.0:
                        return ep + 1, 1 + k
                    apply_feedback(nav, C, bias, x, R_fb)
                    for i in range(n):
                        dx_sum[i] += x[i]
                        x[i] = 0.0
                    if st.reacquire and slot >= 0 and m > 1:  # the anchor: where the filter's error now stands
                        measure(e, ev, aid, ranging, nav, C, bias, w_gps if is_gps else w_ib, acc_ned, vib_ned, st.layout,
                                P, z, H, R)
                        anchor(anc_t, anc_nu, anc_R, anc_ok, slot, imu.t[k] - ev.lag[e], z, R, m)
                if slot >= 0:
                    consecutive[slot] = 0 if accept else consecutive[slot] + 1
                res.accepted[e] = accept
                e += 1
            if rewind_slot >= 0:  # to the slot's checkpoint, the stretch run again (`fusion.reacquire`: the revision)
                at = rv_at[rewind_slot]
                _rewind(rv0 if rewind_slot == 0 else rv1, live, res, at[1], e + 1, imu.t, at[0], w_ib, f_sum)
                k, e, ep, r, last = at[0], at[1], at[2], at[3], at[4]
                rv_ok[:] = False  # (the replay takes them again)
                rewind_slot = -1
                dt_sum = 0.0
                resume = True
                continue
            _store(out.ep_dx, ep, dx_sum)  # x stays 0 between epochs (closed loop: Phi 0 = 0)
            dx_sum[:] = 0.0
            store_tril(out.ep_P, ep, P)
            last = k
            f_sum[:] = 0.0
            dt_sum = 0.0
        if every or (r < n_rows and rows[r] == k):  # (stores inline: a helper taking the arrays cost 8 % of a run)
            row = n_rows - 1 - r if st.reverse_out else r
            _store(out.nav, row, nav)
            _store2(out.C, row, C)
            _store(out.bias, row, bias)
            r += 1
        if trial != _NO_TRIAL and (trial_seen >= TRIAL_ROWS or k == n_t - 1):  # the stretch is over (`fusion.reacquire`: the trial)
            rewind = False
            if trial == _FIRST:
                trial, reading, score_first, rewind = _SECOND, DRIFT, score, True
            elif trial == _SECOND and score_first - score > JUMP_LOG_ODDS:  # JUMP favoured: its stretch once more
                trial, reading, rewind = _REPLAY, JUMP, True
            else:
                trial, reading = _NO_TRIAL, DRIFT
            if rewind:
                _rewind(ck, live, res, ck_e, e, imu.t, ck_k, w_ib, f_sum)
                k, e, ep, r, last = ck_k, ck_e, ck_ep, ck_r, ck_last
                rv_ok[:] = False  # checkpoints of the stretch run again: taken again
                dt_sum = 0.0
                trial_seen, score, resume = 0, 0.0, True
                continue
        k += 1
    return ep + 1, 0
