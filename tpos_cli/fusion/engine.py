"""Runs of the INS error-state filter: settings, initial state, measurements in, one `FilterRun` out.

`run_filter` is the documented wrapper of the compiled loop `fusion._kernels.error_state_kernel`:
it validates shapes, reverses the arrays for a backward run (paper 003's reversed time: IMU
through `ins.reverse_imu`, negated nominal velocity, earth_sign = -1), places each measurement
at the first IMU sample at or after its time, and returns the run in forward time order with the
backward run's velocity, gyro bias and covariances in forward-time signs (`layout.backward_sign`).
Every chain's filters (`fusion.insgps` for GPS, `ranging.filter` for anchor ranges) and every
smoother (`tpos_cli.smoothing`) work on this one `FilterRun`.

Also here, once: the start of a backward run (`backward_start`) and the covariance epoch that
holds the covariance of a sample (`epoch_of`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tpos_cli.errors import ProcessingError
from tpos_cli.filters.gating import chi2_threshold
from tpos_cli.frames import geodetic
from tpos_cli.fusion._kernels import (
    Aiding,
    EventArrays,
    EventResults,
    History,
    ImuArrays,
    Nominal,
    Settings,
    error_state_kernel,
)
from tpos_cli.fusion.layout import N_NAV, Block, StateLayout, backward_sign
from tpos_cli.fusion.lever_arm import second_order_shares, yaw_held_rows
from tpos_cli.fusion.measurements import Kind
from tpos_cli.fusion.rtk_float import float_rows
from tpos_cli.ins.mechanization import reverse_imu

# residuals odd in time (velocities, rates): their measured value and residual flip sign in reversed time
_VELOCITY_KINDS = (Kind.GPS_VELOCITY, Kind.ZUPT, Kind.NHC, Kind.ZARU, Kind.ODOMETER)
# `FilterConfig.nominal_idx` of a run whose nominal history nobody reads (tuning passes: their
# measurement results and the end state serve): its first and last samples only
ENDS_ONLY = np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class FilterConfig:
    """SI settings of one filter. q (4,): white-noise PSDs [acc (m/s^2)^2 s, gyro rad^2/s,
    acc-bias drive (m/s^3)^2 s, gyro-bias drive (rad/s^2)^2 s]; tau <= 0: random-walk biases;
    cov_step: IMU samples per covariance epoch between measurements; gate_probability:
    chi-square gate; max_consecutive_rejections: 0 = no gating of rows with a slot, else after
    this many rejections in a row the next rejected one goes in (as it is, without `reacquire`);
    reacquire: `fusion.reacquire`'s rule instead (a drift of the filter re-acquired, the covariance
    grown; wrong fixes down-weighted; a GPS row that slipped under the gate revised when the next
    one fails it), judged against stated_sd_factor (4,): the GPS fixes' stated
    accuracy over their SDs here per group (pos_h, pos_v, vel_h, vel_v; > 1 where matching made
    them smaller); lever_arm_b_m
    (3,): GPS antenna in the body frame; ungated_after_gap_s > 0:
    the first GPS fix after a longer gap between fixes is not gated (`fusion.insgps`);
    layout: the states beyond the 15 navigation errors (`fusion.layout`); nominal_idx: the
    run-local samples whose nominal a run stores (None: every sample; the run's first and last
    samples are always stored): a smoother that needs the nominal at its output rows only keeps
    a tenth of the largest arrays of a run (`FilterRun.rows`); rest_intervals_s (K, 2) session
    seconds: stops where the platform's attitude does not change (a wheeled vehicle's; on another
    platform its still stops, `drive_smooth.motion_constraints`), inside which
    GPS rows after a stop's first carry no yaw x lever-arm second-order variance
    (`fusion.lever_arm.second_order_shares`; None: every row carries it)."""

    q: np.ndarray
    tau_acc_s: float
    tau_gyro_s: float
    cov_step: int = 10
    gate_probability: float = 0.9999
    max_consecutive_rejections: int = 5
    lever_arm_b_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ungated_after_gap_s: float = 0.0
    layout: StateLayout = field(default_factory=StateLayout)
    C_vb: np.ndarray = field(default_factory=lambda: np.eye(3))  # IMU body -> vehicle axes (NHC rows)
    nominal_idx: np.ndarray | None = None
    reacquire: bool = False
    stated_sd_factor: np.ndarray = field(default_factory=lambda: np.ones(4))
    rest_intervals_s: np.ndarray | None = None
    q_stops: np.ndarray | None = None  # (K, 4) [t0, t1, acc factor, gyro factor]: white PSDs scaled inside stops
    float_intervals_s: np.ndarray | None = None  # (K, 2) session s: RTK float stretches, whose position rows
    # see the layout's float offset state (`fusion.rtk_float`; None: none)
    standstill_intervals_s: np.ndarray | None = None  # (K, 2) session s: the platform's detected stops (any
    # platform), whose velocity rows (GPS, ZUPT) leave yaw uncorrected (`fusion.lever_arm.yaw_held_rows`; None: none)

    @property
    def n_states(self) -> int:
        return self.layout.n_states


@dataclass(frozen=True)
class InitialState:
    """Nominal state at the run's first sample `k0` (forward-time signs; for a backward run: at
    the last sample): nav (6,) [lat_rad, lon_rad, h_m, vn, ve, vd], C_nb (3,3), bias (6,)
    [acc m/s^2, gyro rad/s] (or 6 + n_extra with the extra states' nominal), P0 (15,15) prior of
    the navigation errors (the extra states' prior comes from `FilterConfig.layout`)."""

    nav: np.ndarray
    C_nb: np.ndarray
    bias: np.ndarray
    P0: np.ndarray
    k0: int = 0


@dataclass(frozen=True)
class Measurements:
    """Aiding measurements, one row each, in any order: t_s (E,) session seconds, kind (E,)
    (`fusion.measurements.Kind`), z (E, 3), R (E, 3, 3), dim (E,) size of z, gated (E,), slot (E,)
    (counter of consecutive rejections, -1 none), par (E,) (anchor index of a range, sens row of
    a fix, fix index of a GPS row). Per-kind parameters: anchors_ned_m (A, 3) and origin_lla (3,)
    of the local frame, sens (S, 2, 1 + A) the fixes' sensitivities (`ranging.filter.fix_events`)."""

    t_s: np.ndarray
    kind: np.ndarray
    z: np.ndarray
    R: np.ndarray
    dim: np.ndarray
    gated: np.ndarray
    slot: np.ndarray
    par: np.ndarray
    anchors_ned_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    origin_lla: np.ndarray | None = None
    sens: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t_s.size)

    @staticmethod
    def rows(t_s, kind, z, R, *, dim, gated, slot=-1, par=-1, **params) -> Measurements:
        """Rows of one kind: z (E, <=3) and R (E, dim, dim) are padded to 3; scalars broadcast."""
        t = np.asarray(t_s, dtype=float)
        n = t.size
        z3 = np.zeros((n, 3))
        R3 = np.zeros((n, 3, 3))
        if n:
            zz = np.asarray(z, dtype=float).reshape(n, -1)
            z3[:, : zz.shape[1]] = zz
            RR = np.asarray(R, dtype=float)
            RR = RR.reshape(n, 1, 1) if RR.ndim == 1 else RR
            R3[:, : RR.shape[1], : RR.shape[2]] = RR

        def full(v, dt):
            return np.broadcast_to(np.asarray(v, dtype=dt), (n,)).copy()

        return Measurements(t, full(kind, np.int64), z3, R3, full(dim, np.int64), full(gated, bool),
                            full(slot, np.int64), full(par, np.int64), **params)

    @staticmethod
    def merge(*parts: Measurements) -> Measurements:
        """The rows of all parts, time sorted (stable: rows of one time keep their order); the fix
        sensitivities are concatenated and their row indices shifted."""
        parts = tuple(p for p in parts if p is not None)
        t = np.concatenate([p.t_s for p in parts])
        order = np.argsort(t, kind="stable")
        par = []
        sens = []
        n_sens = 0
        for p in parts:
            pp = p.par.copy()
            if p.sens is not None:
                fx = p.kind == Kind.FIX_NE
                pp[fx] += n_sens
                sens.append(p.sens)
                n_sens += p.sens.shape[0]
            par.append(pp)
        cols = {f: np.concatenate([getattr(p, f) for p in parts])[order]
                for f in ("t_s", "kind", "dim", "z", "R", "gated", "slot")}
        base = next((p for p in parts if p.origin_lla is not None), parts[0])
        return Measurements(**cols, par=np.concatenate(par)[order], anchors_ned_m=base.anchors_ned_m,
                            origin_lla=base.origin_lla, sens=np.concatenate(sens) if sens else None)

    def select(self, mask) -> Measurements:
        """The rows where mask is True (parameters kept whole)."""
        return self.take(np.flatnonzero(np.asarray(mask, dtype=bool)))

    def take(self, rows) -> Measurements:
        """The rows `rows` (indices, in that order; parameters kept whole)."""
        r = np.asarray(rows, dtype=np.int64)
        return Measurements(self.t_s[r], self.kind[r], self.z[r], self.R[r], self.dim[r], self.gated[r],
                            self.slot[r], self.par[r], self.anchors_ned_m, self.origin_lla, self.sens)


class SymmetricStack:
    """A stack of symmetric matrices (E, n, n) stored as their lower triangles by rows, tril
    (E, n (n + 1) / 2) (numpy's `tril_indices` order): a run's covariances are exactly symmetric
    (`filters.kalman`), so the triangle loses nothing and halves the largest array of a run.
    Indexed like the full array (`P[e]`, `P[e, :9, :9]`, `P[:, 3, 3]`, e an index, a slice or
    an index array): only the entries asked for are gathered."""

    def __init__(self, tril: np.ndarray, n: int):
        self.tril = tril
        self.n = int(n)
        i, j = np.tril_indices(self.n)
        at = np.empty((self.n, self.n), dtype=np.int64)
        at[i, j] = at[j, i] = np.arange(i.size)
        self._at = at  # position of entry (i, j) in a triangle

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.tril.shape[0], self.n, self.n)

    def __len__(self) -> int:
        return self.tril.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        key = key if isinstance(key, tuple) else (key,)
        e, at = key[0], np.asarray(self._at[key[1:]])
        m = int(at.max()) + 1  # the entries asked for lie in the first m of each triangle
        if 2 * at.size >= m:  # a leading block (e.g. [:9, :9]: a prefix of the rows), or most of them
            return np.take(self.tril[e, :m], at, axis=-1)
        if isinstance(e, slice) or np.ndim(e) == 0:  # a few entries
            return self.tril[e][..., at]
        e = np.asarray(e)
        e = np.flatnonzero(e) if e.dtype == bool else e
        return self.tril[e.reshape(e.shape + (1,) * at.ndim), at]

    def take(self, e) -> SymmetricStack:
        """The matrices e (indices), still stored as triangles."""
        return SymmetricStack(self.tril[e], self.n)

    def leading(self, m: int) -> SymmetricStack:
        """The leading (m, m) blocks (a view: their triangles are the first m (m + 1) / 2 entries)."""
        return SymmetricStack(self.tril[:, : m * (m + 1) // 2], m)


@dataclass(frozen=True)
class FilterRun:
    """One filter run over the IMU samples k0..N-1, in forward time order (run-local index j = k - k0).

    t_s (N-k0,) session seconds; nav (K, 6), C_nb (K, 3, 3), bias (K, 6 + n_extra): the nominal
    after feedback (`Nominal`; the extra states' nominal after the IMU biases) at the run-local
    samples idx (K,) (increasing, the first and last sample included; None: every sample, K = N-k0);
    `rows` maps samples to rows. ep_idx (E,) run-local sample of each covariance epoch, increasing;
    ep_P (E, n, n) the covariance after the updates there, forward-time signs (a `SymmetricStack`:
    lower triangles, indexed like the full array); forward runs also hold ep_dx (E, n)
    (correction fed back at the epoch) and, stored for RTS, the transition from the previous
    epoch, block diagonal: ep_Phi (E, 15, 15) its navigation block, ep_phi_extra (E, n - 15) its
    diagonal beyond, and the predicted covariance ep_Ppred (E, n (n + 1) / 2) as its lower
    triangle by rows (numpy's `tril_indices` order; it is exactly symmetric).
    Per measurement (rows of `measurements`, the caller's order): ev_nu (E, 3) residual (NaN past
    dim or when not processed), ev_pvar (E, 3) diagonal of H P- H^T (R excluded), ev_nis (E,) (NaN
    when not processed, e.g. outside the run), ev_logdet (E,) log det S, ev_accepted (E,),
    ev_inflation (E, 2) the factors a re-acquisition grew the navigation covariance by and a
    long-rejected scattering row's R was grown by (1: none; `fusion.reacquire`), ev_jump (E,) the
    re-acquired rows read as a jump of the filter's position/velocity (its trial kept JUMP).
    """

    backward: bool
    k0: int
    t_s: np.ndarray
    nav: np.ndarray
    C_nb: np.ndarray
    bias: np.ndarray
    ep_idx: np.ndarray
    ep_P: SymmetricStack
    ep_Phi: np.ndarray | None
    ep_Ppred: np.ndarray | None
    ep_dx: np.ndarray | None
    layout: StateLayout
    measurements: Measurements
    ev_nu: np.ndarray
    ev_pvar: np.ndarray
    ev_nis: np.ndarray
    ev_logdet: np.ndarray
    ev_accepted: np.ndarray
    ep_phi_extra: np.ndarray | None = None
    idx: np.ndarray | None = None
    ev_inflation: np.ndarray | None = None  # (E, 2) [P, R] factors of re-acquired / down-weighted rows (1: none)
    ev_jump: np.ndarray | None = None  # (E,) re-acquired rows read as a jump (the trial kept JUMP; `fusion.reacquire`)

    def rows(self, idx) -> np.ndarray:
        """Rows of nav, C_nb and bias that hold the run-local samples idx (which the run must have
        stored: `FilterConfig.nominal_idx`)."""
        i = np.asarray(idx, dtype=np.int64)
        if self.idx is None:
            return i
        r = np.minimum(np.searchsorted(self.idx, i), self.idx.size - 1)
        if not np.array_equal(self.idx[r], i):
            raise ValueError("the run did not store the nominal at every requested sample (`FilterConfig.nominal_idx`)")
        return r

    def extra(self, block: Block, idx=None) -> np.ndarray:
        """Nominal of an extra block at the run-local samples idx (None: every stored row), (K, size);
        (K, 0) when absent."""
        r = slice(None) if idx is None else self.rows(idx)
        o = self.layout.offset(block)
        if o < 0:
            return np.zeros((self.bias[r].shape[0], 0))
        size = next(b.size for b in self.layout.blocks if b.block == block)
        return self.bias[r, 6 + o - N_NAV: 6 + o - N_NAV + size]


def run_filter(t_s, gyro_b_rps, acc_b_mps2, init: InitialState, cfg: FilterConfig, meas: Measurements, *,
               backward: bool = False, store_rts: bool | None = None, reuse=()) -> FilterRun:
    """Run the closed-loop filter over the IMU samples init.k0..N-1, forward or backward in time.

    t_s (N,) s, gyro_b_rps, acc_b_mps2 (N, 3) FRD; `init` the state at sample k0 (backward: at
    the last sample, forward-time signs); `meas` the aiding. `store_rts` (default: forward runs)
    keeps the RTS history. `reuse`: float64 arrays nobody reads any more (a forward run's RTS
    history after `smoothing.rts`: ep_Phi, ep_Ppred) that this run overwrites where it fits
    (`_reused`): its history (kept by the result) goes into the first, a backward run's reversed
    IMU (dropped on return) into the others; the hour's backward run then writes into memory the
    process has touched already instead of fresh pages. Raises ProcessingError when an innovation covariance loses positive
    definiteness or the nominal diverges.
    """
    k0 = int(init.k0)
    t = np.ascontiguousarray(t_s[k0:], dtype=float)
    gyro = np.ascontiguousarray(gyro_b_rps[k0:], dtype=float)
    acc = np.ascontiguousarray(acc_b_mps2[k0:], dtype=float)
    n = t.size
    if n < 2:
        raise ProcessingError("filter: fewer than two IMU samples to run over")
    if gyro.shape != (n, 3) or acc.shape != (n, 3):
        raise ValueError(f"`gyro_b_rps` and `acc_b_mps2` must have shape ({n + k0}, 3), got {np.shape(gyro_b_rps)}, {np.shape(acc_b_mps2)}")
    if store_rts is None:
        store_rts = not backward
    lay = cfg.layout
    ns = lay.n_states
    nb = 6 + lay.n_extra
    sign = backward_sign(ns, lay)
    odd = sign[N_NAV:] < 0  # time-odd extra states (a clock offset): their nominal flips in reversed time
    nav0 = np.array(init.nav, dtype=float)
    bias0 = np.zeros(nb)
    m_b = min(nb, np.size(init.bias))
    bias0[:m_b] = np.asarray(init.bias, dtype=float)[:m_b]
    P0 = np.zeros((ns, ns))
    P0[:N_NAV, :N_NAV] = np.asarray(init.P0, dtype=float)[:N_NAV, :N_NAV]
    P0[N_NAV:, N_NAV:] = lay.extra_P0()
    if nav0.shape != (6,) or np.shape(init.C_nb) != (3, 3) or P0.shape != (ns, ns):
        raise ValueError("`init`: nav must be (6,), C_nb (3, 3), P0 (15, 15)")
    _check(cfg, meas)
    t_ev = np.asarray(meas.t_s, dtype=float)
    z = np.array(meas.z, dtype=float)
    if backward:
        z[np.isin(meas.kind, _VELOCITY_KINDS)] *= -1.0  # velocities in reversed time
        t, gyro, acc = reverse_imu(t, gyro, acc, out=_reused(reuse[1:], (n,), (n, 3), (n, 3)))
        nav0[3:] *= -1.0
        bias0[3:6] *= -1.0
        bias0[6:][odd] *= -1.0
        P0 = P0 * np.outer(sign, sign)
        t_ev = -t_ev
    k_ev = np.searchsorted(t, t_ev, side="left")
    inside = np.flatnonzero((k_ev >= 1) & (k_ev < n))
    order = inside[np.argsort(k_ev[inside], kind="stable")]  # the kernel walks measurements by sample
    k_o = k_ev[order].astype(np.int64)
    ev = EventArrays(k_o, t[k_o] - t_ev[order], meas.kind[order].astype(np.int64), meas.dim[order].astype(np.int64),
                     np.ascontiguousarray(z[order]), np.ascontiguousarray(meas.R[order], dtype=float),
                     meas.gated[order].astype(np.bool_), meas.slot[order].astype(np.int64),
                     meas.par[order].astype(np.int64),
                     second_order_shares(np.asarray(meas.t_s, dtype=float)[order], meas.kind[order], cfg.rest_intervals_s),
                     float_rows(np.asarray(meas.t_s, dtype=float)[order], meas.kind[order], cfg.float_intervals_s),
                     yaw_held_rows(np.asarray(meas.t_s, dtype=float)[order], meas.kind[order], cfg.standstill_intervals_s))
    aid = _aiding(cfg, meas, backward)
    k_distinct = k_o[np.flatnonzero(np.diff(k_o, prepend=-1))]  # k_o is sorted: np.unique's values without its hashing
    n_ep = epoch_count(n, int(max(cfg.cov_step, 1)), k_distinct)
    nr = n_ep if store_rts else 1
    keep = _nominal_idx(cfg.nominal_idx, n)
    rows = np.arange(n) if keep is None else (n - 1 - keep[::-1] if backward else keep)  # in the run's own time
    K = rows.size
    ep_P, nav_o, C_o, bias_o, dx_o = _reused(reuse[:1], (n_ep, ns * (ns + 1) // 2), (K, 6), (K, 3, 3), (K, nb), (n_ep, ns))
    out = History(nav_o, C_o, bias_o, rows, np.zeros(n_ep, np.int64),
                  np.empty((nr, N_NAV, N_NAV)), np.empty((nr, ns - N_NAV)), np.empty((nr, ns * (ns + 1) // 2)),
                  ep_P, dx_o)
    m = order.size
    res = EventResults(np.full((m, 3), np.nan), np.full((m, 3), np.nan), np.full(m, np.nan), np.full(m, np.nan),
                       np.zeros(m, np.bool_), np.ones((m, 2)), np.zeros(m, np.bool_))
    st = Settings(np.asarray(cfg.q, dtype=float), float(cfg.tau_acc_s), float(cfg.tau_gyro_s), -1.0 if backward else 1.0,
                  int(max(cfg.cov_step, 1)), lay.extra_tau_s(), lay.extra_q(), lay.offsets(),
                  chi2_threshold(cfg.gate_probability, 3), int(cfg.max_consecutive_rejections), bool(cfg.reacquire),
                  np.asarray(cfg.stated_sd_factor, dtype=float), bool(store_rts),
                  bool(backward), _q_stops(cfg.q_stops, backward))
    start = Nominal(nav0, np.ascontiguousarray(init.C_nb, dtype=float), bias0)
    # None when no row needs the ranging models: numba then compiles the kernel without them
    ranging = True if np.isin(meas.kind, [Kind.RANGE, Kind.FIX_NE, Kind.FLOOR]).any() else None
    n_used, status = error_state_kernel(ImuArrays(t, gyro, acc), start, P0, st, ev, aid, ranging, out, res)
    if status == 0 and n_used != n_ep:
        raise AssertionError(f"covariance epochs: {n_used} used, {n_ep} allocated")
    if status != 0:
        tk = t[status - 1] * (-1.0 if backward else 1.0)
        raise ProcessingError(f"filter: innovation covariance not positive definite at t_s = {tk:.3f}")
    # per measurement, back to the caller's order
    E = len(meas)
    nu, pvar = np.full((E, 3), np.nan), np.full((E, 3), np.nan)
    nis, logdet, accepted, inflation = np.full(E, np.nan), np.full(E, np.nan), np.zeros(E, dtype=bool), np.ones((E, 2))
    jump = np.zeros(E, dtype=bool)
    nu[order], pvar[order], nis[order], logdet[order], accepted[order], inflation[order], jump[order] = res
    ep_idx, ep_P, ep_dx = out.ep_idx[:n_used], out.ep_P[:n_used], out.ep_dx[:n_used]
    nav, C, bias = out.nav, out.C, out.bias  # a backward run's stored in forward order (reverse_out)
    if backward:
        nav[:, 3:] *= -1.0
        bias[:, 3:6] *= -1.0
        bias[:, 6:][:, odd] *= -1.0
        ep_idx = (n - 1 - ep_idx)[::-1]
        ep_P = ep_P[::-1]
        ep_P *= np.outer(sign, sign)[np.tril_indices(ns)]  # in place: this array is the run's largest
        nu[np.isin(meas.kind, _VELOCITY_KINDS)] *= -1.0
        ep_dx = None
    if not np.all(np.isfinite(nav)):
        bad = int(np.argmax(~np.all(np.isfinite(nav), axis=1)))
        bad = bad if keep is None else int(keep[bad])
        raise ProcessingError(f"filter diverged at t_s = {np.asarray(t_s)[k0 + bad]:.3f} (session epoch removed)")
    rts = store_rts and not backward
    return FilterRun(backward, k0, np.asarray(t_s, dtype=float)[k0:], nav, C, bias, ep_idx, SymmetricStack(ep_P, ns),
                     out.ep_Phi[:n_used] if rts else None, out.ep_Ppred[:n_used] if rts else None, ep_dx,
                     lay, meas, nu, pvar, nis, logdet, accepted, out.ep_phi_extra[:n_used] if rts else None, keep,
                     inflation, jump)


def _reused(arrays, *shapes) -> list[np.ndarray]:
    """Uninitialized float64 arrays of the given shapes (C order), in that order of `shapes`,
    each carved from the first of the C-contiguous float64 `arrays` with room left (a view of its
    memory), else `np.empty`. The kernel writes every entry it hands out before reading it."""
    free = [np.ravel(a) for a in arrays if a is not None and a.dtype == np.float64 and a.flags.c_contiguous]
    out = []
    for shape in shapes:
        size = int(np.prod(shape))
        i = next((i for i, b in enumerate(free) if b.size >= size), None)
        if i is None:
            out.append(np.empty(shape))
            continue
        out.append(free[i][:size].reshape(shape))
        free[i] = free[i][size:]
    return out


def _nominal_idx(idx, n: int) -> np.ndarray | None:
    """`FilterConfig.nominal_idx` as sorted unique run-local samples with both ends (None: every sample)."""
    if idx is None:
        return None
    i = np.asarray(idx, dtype=np.int64)
    if i.size and (i.min() < 0 or i.max() >= n):
        raise ValueError(f"`nominal_idx` must lie in [0, {n}), got {i.min()}..{i.max()}")
    if i.ndim == 1 and i.size and np.all(i[1:] > i[:-1]):  # the usual output rows: sorted already, no sort
        return np.concatenate([[0][: int(i[0] != 0)], i, [n - 1][: int(i[-1] != n - 1)]]).astype(np.int64)
    return np.union1d(i, [0, n - 1])


def epoch_count(n: int, cov_step: int, k_meas) -> int:
    """Covariance epochs of `error_state_kernel` over n samples: sample 0, every sample with a
    measurement (k_meas: sorted unique, 1 <= k < n), after every `cov_step` samples without one,
    and the last sample. Exact, so the stored covariances are allocated once at their size (they
    are the largest arrays of a run)."""
    k = np.asarray(k_meas, dtype=np.int64)
    prev = np.concatenate(([0], k[:-1]))
    steps = int(np.sum((k - 1 - prev) // cov_step)) + k.size  # step epochs strictly between, then the measurement
    last = int(k[-1]) if k.size else 0
    tail = (n - 1 - last + cov_step - 1) // cov_step  # step epochs after it, the last sample included
    return 1 + steps + tail


def _check(cfg: FilterConfig, meas: Measurements) -> None:
    """Shapes and units the kernel trusts (programmer errors: ValueError naming the field)."""
    q = np.asarray(cfg.q, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or np.any(q < 0):
        raise ValueError(f"`q` must be 4 finite PSDs >= 0 (SI units), got {cfg.q!r}")
    if np.shape(cfg.lever_arm_b_m) != (3,):
        raise ValueError(f"`lever_arm_b_m` must have shape (3,), got {np.shape(cfg.lever_arm_b_m)}")
    E = len(meas)
    for name, shape in (("kind", (E,)), ("dim", (E,)), ("z", (E, 3)), ("R", (E, 3, 3)), ("gated", (E,)),
                        ("slot", (E,)), ("par", (E,))):
        if np.shape(getattr(meas, name)) != shape:
            raise ValueError(f"`Measurements.{name}` must have shape {shape}, got {np.shape(getattr(meas, name))}")
    if E and (meas.dim.min() < 1 or meas.dim.max() > 3 or not np.isin(meas.kind, [int(k) for k in Kind]).all()):
        raise ValueError("`Measurements`: dim must be 1-3 and kind a fusion.measurements.Kind")
    if np.any(np.isin(meas.kind, [Kind.RANGE, Kind.FIX_NE, Kind.FLOOR])) and meas.origin_lla is None:
        raise ValueError("`Measurements`: range, fix and floor rows need `origin_lla` (and `anchors_ned_m`)")


def _aiding(cfg: FilterConfig, meas: Measurements, backward: bool = False) -> Aiding:
    anchors = np.ascontiguousarray(meas.anchors_ned_m, dtype=float).reshape(-1, 3)
    if meas.origin_lla is not None:
        r0_e = geodetic.lla_to_ecef(np.asarray(meas.origin_lla, dtype=float))
        C_ne0 = geodetic.ecef_to_ned_dcm(meas.origin_lla[0], meas.origin_lla[1])
    else:
        r0_e, C_ne0 = np.zeros(3), np.eye(3)
    sens = meas.sens if meas.sens is not None and meas.sens.shape[0] else np.zeros((1, 2, 1 + anchors.shape[0]))
    return Aiding(np.ascontiguousarray(cfg.lever_arm_b_m, dtype=float).reshape(3), np.zeros(3), anchors,
                  np.ascontiguousarray(r0_e, dtype=float), np.ascontiguousarray(C_ne0, dtype=float),
                  np.ascontiguousarray(sens, dtype=float), np.ascontiguousarray(cfg.C_vb, dtype=float).reshape(3, 3),
                  -1.0 if backward else 1.0)


def _q_stops(q_stops, backward: bool) -> np.ndarray:
    """`FilterConfig.q_stops` in the run's own time ((0, 4) when none)."""
    if q_stops is None or not len(q_stops):
        return np.zeros((0, 4))
    q = np.array(q_stops, dtype=float).reshape(-1, 4)
    if backward:
        q[:, :2] = -q[:, [1, 0]]
    return q


def backward_start(run: FilterRun, P0: np.ndarray) -> InitialState:
    """The start of a backward run: the forward run's nominal navigation state and IMU biases at
    its last sample, with the prior covariance P0 (15, 15) (the initial SDs, not the forward
    covariance) and the extra states at their priors, so that the two runs share no information
    beyond that rough start and their combination may treat them as independent."""
    return InitialState(run.nav[-1].copy(), run.C_nb[-1].copy(), run.bias[-1, :6].copy(), np.asarray(P0, dtype=float), run.k0)


def epoch_of(run: FilterRun, idx) -> np.ndarray:
    """Covariance epoch of each run-local sample index: the nearest epoch on the data side (the
    last at or before the sample for a forward run, the first at or after it for a backward run)."""
    if run.backward:
        return np.minimum(np.searchsorted(run.ep_idx, idx, side="left"), run.ep_idx.size - 1)
    return np.maximum(np.searchsorted(run.ep_idx, idx, side="right") - 1, 0)
