"""Loosely coupled INS/GPS filter runs (paper 003): GPS fixes as measurements of the one error-state
filter (`fusion.engine.run_filter`), forward or backward in time.

Each fix is a `Kind.GPS_POSITION` row and, when it has a velocity, a `Kind.GPS_VELOCITY` row
(processed in that order: each with its own NIS, 3 d.o.f. or 2 for speed/course receivers, and
its own gate and counter of consecutive rejections, so that a bad velocity does not throw away a
good position). `gps_innovations` gives the per-fix view of a run's results.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tpos_cli.fusion.engine import FilterConfig, FilterRun, InitialState, Measurements, run_filter
from tpos_cli.fusion.layout import Block, StateLayout, gps_error_block
from tpos_cli.fusion.measurements import Kind
from tpos_cli.fusion.rtk_float import float_velocity_var
from tpos_cli.fusion.velocity_lag import LAG_GRID_S, velocity_latency_s  # noqa: F401  (re-exported: chains and tests import it here)
from tpos_cli.timebase import in_intervals

_SLOT_POSITION, _SLOT_VELOCITY = 0, 1


@dataclass(frozen=True)
class GpsFixes:
    """Fixes used by the filter: t_s (M,), lla (M,3) deg/m, vel_ned_mps (M,3) NaN if absent,
    sigma_pos_ned_m (M,3), sigma_vel_mps (M,3), from_receiver (4,) bool."""

    t_s: np.ndarray
    lla: np.ndarray
    vel_ned_mps: np.ndarray
    sigma_pos_ned_m: np.ndarray
    sigma_vel_mps: np.ndarray
    # per group (pos_h, pos_v, vel_h, vel_v): SDs the receiver logged (not pipeline defaults);
    # noise matching may raise those but never lower them
    from_receiver: tuple = (False, False, False, False)
    vel_latency_s: float = 0.0  # the logged velocity is the platform's velocity this long before t_s
    n_wild: int = 0  # fixes left out before the filter (`fusion.screening.wild_fixes`)
    float_intervals_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (K, 2) [first, last] time
    # of each stretch of RTK float fixes (`fusion.rtk_float`)
    n_float: int = 0  # fixes in those stretches (before the decimation)


@dataclass(frozen=True)
class GpsInnovations:
    """Per fix of a run (in the order of `GpsFixes`): innovation (M, 6) [pos NED m, vel NED m/s]
    residuals (NaN where absent), pvar (M, 6) the filter's own variance of each (diagonal of
    H P- H^T, R excluded), nis (M, 2), logdet (M, 2) and accepted (M, 2) of the [position,
    velocity] parts (NaN / False where not processed, e.g. fixes before the first sample), dof (M, 2)."""

    innovation: np.ndarray
    pvar: np.ndarray
    nis: np.ndarray
    logdet: np.ndarray
    accepted: np.ndarray
    dof: np.ndarray


def gps_error_layout(sigma_ned_m, tau_s: float, base: StateLayout | None = None) -> StateLayout:
    """`base`'s blocks (none by default) with the extra states for time-correlated GPS errors:
    three Gauss-Markov states (`fusion.gps_error`) when any SD is > 0, else none (white fixes)."""
    kept = tuple(b for b in (base.blocks if base is not None else ()) if b.block != Block.GPS_ERROR)
    if sigma_ned_m is None or not np.any(np.asarray(sigma_ned_m, dtype=float) > 0):
        return StateLayout(kept)
    return StateLayout((*kept, gps_error_block(sigma_ned_m, tau_s)))


def gps_measurements(fixes: GpsFixes, t_run_s, *, backward: bool, gap_s: float, float_intervals_s=None,
                     float_vel_var=None) -> Measurements:
    """The fixes as filter rows, interleaved (velocity, position) per fix. `t_run_s` are the
    run's IMU times in its own direction (negated, reversed for a backward run): with gap_s > 0
    the first fix processed more than gap_s after the previous one (or the run's start) is not
    gated (an outage: the INS has then drifted by more than a MEMS error model predicts, and
    refusing the returning fixes prolongs the outage). The velocity rows of fixes inside
    `float_intervals_s` (RTK float stretches) carry `float_vel_var` (3,) more variance (`fusion.rtk_float`)."""
    t_fix = np.asarray(fixes.t_s, dtype=float)
    m = t_fix.size
    gated = np.ones(m, dtype=bool)
    if gap_s > 0 and m:
        t_run = np.asarray(t_run_s, dtype=float)
        k = np.searchsorted(t_run, -t_fix if backward else t_fix, side="left")
        used = np.flatnonzero((k >= 1) & (k < t_run.size))
        used = used[np.argsort(k[used], kind="stable")]
        tk = t_run[k[used]]
        gated[used] = np.diff(np.concatenate([[t_run[0]], tk])) <= gap_s
    pos = np.column_stack([np.radians(fixes.lla[:, 0]), np.radians(fixes.lla[:, 1]), fixes.lla[:, 2]])
    var_p = np.asarray(fixes.sigma_pos_ned_m, dtype=float) ** 2
    vel = np.asarray(fixes.vel_ned_mps, dtype=float)
    var_v = np.asarray(fixes.sigma_vel_mps, dtype=float) ** 2
    if float_vel_var is not None:
        var_v = var_v + np.where(in_intervals(t_fix, float_intervals_s, closed=True)[:, None], np.asarray(float_vel_var, dtype=float), 0.0)
    g = np.arange(m)
    rows = [Measurements.rows(t_fix, Kind.GPS_POSITION, pos, var_p[:, :, None] * np.eye(3), dim=3, gated=gated,
                              slot=_SLOT_POSITION, par=g)]
    has_v = ~np.isnan(vel[:, 0])
    for dim, sel in ((3, has_v & ~np.isnan(vel[:, 2])), (2, has_v & np.isnan(vel[:, 2]))):
        # receivers that log speed and course give no vertical velocity: a 2-dim update
        R = var_v[sel][:, :dim, None] * np.eye(dim)
        rows.append(Measurements.rows(t_fix[sel] - fixes.vel_latency_s, Kind.GPS_VELOCITY, np.nan_to_num(vel[sel]), R, dim=dim,
                                      gated=gated[sel], slot=_SLOT_VELOCITY, par=g[sel]))
    allm = Measurements.merge(*rows)
    # per fix: velocity, then position (merge sorts by time only). The position row's clock column is
    # the nominal velocity (`measurements.measure`): after a coast that velocity is metres per second
    # off until the fix's own velocity row has corrected it, and a column that changes by that much
    # from one fix to the next reads as information on the clock offset that the fixes do not hold
    return allm.take(np.lexsort((-np.asarray(allm.kind, dtype=np.int64), allm.par)))


def run_insgps(t_s, gyro_b_rps, acc_b_mps2, fixes: GpsFixes, init: InitialState, cfg: FilterConfig,
               *, backward: bool = False, store_rts: bool | None = None, extra: Measurements | None = None,
               reuse=()) -> FilterRun:
    """Run the closed-loop INS/GPS filter over the log, forward or backward in time.

    For `backward`, `init` is the state at the LAST sample (forward-time signs). `extra`: further
    rows (motion constraints, `fusion.constraints`), processed after the fixes of the same sample.
    `reuse`: arrays no longer read that the run may overwrite (`fusion.engine.run_filter`).
    """
    t = np.asarray(t_s, dtype=float)[init.k0:]
    t_run = -t[::-1] if backward else t
    meas = gps_measurements(fixes, t_run, backward=backward, gap_s=float(cfg.ungated_after_gap_s),
                            float_intervals_s=cfg.float_intervals_s, float_vel_var=float_velocity_var(cfg.layout))
    if extra is not None and len(extra):
        meas = Measurements.merge(meas, extra)
    return run_filter(t_s, gyro_b_rps, acc_b_mps2, init, cfg, meas, backward=backward, store_rts=store_rts, reuse=reuse)


def gps_innovations(run: FilterRun, n_fixes: int) -> GpsInnovations:
    """The per-fix view of an INS/GPS run's measurement results."""
    meas = run.measurements
    innov = np.full((n_fixes, 6), np.nan)
    pvar = np.full((n_fixes, 6), np.nan)
    nis = np.full((n_fixes, 2), np.nan)
    logdet = np.full((n_fixes, 2), np.nan)
    accepted = np.zeros((n_fixes, 2), dtype=bool)
    dof = np.zeros((n_fixes, 2), dtype=np.int64)
    for j, kind in enumerate((Kind.GPS_POSITION, Kind.GPS_VELOCITY)):
        r = np.flatnonzero(meas.kind == kind)
        g = meas.par[r]
        for i in range(3):
            ok = meas.dim[r] > i
            innov[g[ok], 3 * j + i] = run.ev_nu[r[ok], i]
            pvar[g[ok], 3 * j + i] = run.ev_pvar[r[ok], i]
        nis[g, j] = run.ev_nis[r]
        logdet[g, j] = run.ev_logdet[r]
        accepted[g, j] = run.ev_accepted[r]
        dof[g, j] = np.where(np.isfinite(run.ev_nis[r]), meas.dim[r], 0)
    return GpsInnovations(innov, pvar, nis, logdet, accepted, dof)
