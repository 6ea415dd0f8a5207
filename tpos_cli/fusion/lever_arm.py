"""The GPS lever arm as an estimated correction (issue 11 item 4; states: `layout.lever_arm_block`).

A session states the antenna's position from the IMU (`[gps] lever_arm_m`, default zero); a
wrong or missing one shows in every turn as a position error that rotates with the heading.
With fixes better than the correction's prior SD and a course that turns, the filter estimates
the horizontal correction dl (vehicle forward, right). The trajectory keeps its meaning: the
point at the *stated* lever arm from the antenna (the IMU when the statement is right, the
antenna when the session states none), i.e. the IMU position plus C_nb C_vb^T (dl, 0).
"""

from __future__ import annotations

import numpy as np

from tpos_cli.frames.earth import ned_rate_to_lla_rate
from tpos_cli.fusion.layout import N_NAV, Block, StateLayout
from tpos_cli.fusion.measurements import Kind
from tpos_cli.timebase import in_intervals

LEVEL_MAX_TILT_DEG = 20.0  # without vehicle axes, the IMU's own x, y serve when its z is this close to vertical


def course_span_deg(vel_ned_mps, min_speed_mps: float) -> float:
    """Range (deg) of the unwrapped course over ground of the rows faster than min_speed_mps, in
    their time order: how far the heading turned over the log (a U-turn: 180; 0 with under two
    such rows). What makes a horizontal lever arm observable from position fixes."""
    v = np.asarray(vel_ned_mps, dtype=float)
    ok = np.isfinite(v[:, :2]).all(axis=1) & (np.hypot(v[:, 0], v[:, 1]) > min_speed_mps)
    if ok.sum() < 2:
        return 0.0
    course = np.unwrap(np.arctan2(v[ok, 1], v[ok, 0]))
    return float(np.degrees(course.max() - course.min()))


def lever_arm_wanted(mode: str, axes: str | None, sigma_h_fix_m: float, span_deg: float, prior_sd_m: float,
                     min_turn_deg: float) -> tuple[bool, str]:
    """Whether to estimate the correction, and why. axes: which horizontal axes the two states
    follow ("vehicle": a wheeled platform's; "imu": a level IMU's own x, y), None when neither
    holds. `auto`: with such axes, fixes whose median horizontal SD sigma_h_fix_m is under a third
    of the prior SD (coarser fixes bury a lever arm in their noise: the state would only add its
    prior to the position sigmas), and a course that spans min_turn_deg or more."""
    if mode == "off":
        return False, "pipeline: lever_arm = off"
    if mode == "on":
        return True, "pipeline: lever_arm = on"
    if axes is None:
        return False, f"auto: no horizontal axes (not a wheeled platform, IMU tilted over {LEVEL_MAX_TILT_DEG:g} deg)"
    if not sigma_h_fix_m < prior_sd_m / 3.0:
        return False, f"auto: fixes' horizontal SD {sigma_h_fix_m:.3g} m is not under a third of the prior SD {prior_sd_m:g} m"
    if span_deg < min_turn_deg:
        return False, f"auto: the course spans {span_deg:.0f} deg, under {min_turn_deg:g} deg"
    return True, (f"auto: fixes' horizontal SD {sigma_h_fix_m:.3g} m under a third of the prior SD {prior_sd_m:g} m, "
                  f"course spans {span_deg:.0f} deg, {axes} axes")


def lever_axes(wheeled: bool, C_nb0) -> str | None:
    """The horizontal axes the correction follows: the vehicle's on a wheeled platform (its
    mounting is known), else the IMU's own x, y when the IMU is level within LEVEL_MAX_TILT_DEG at
    the start (C_nb0: the initial attitude; a walker's or a rover's board), else None."""
    if wheeled:
        return "vehicle"
    tilt = np.degrees(np.arccos(np.clip(np.asarray(C_nb0, dtype=float)[2, 2], -1.0, 1.0)))
    return "imu" if tilt <= LEVEL_MAX_TILT_DEG else None


def lever_correction_b(bias_rows, layout: StateLayout, C_vb) -> np.ndarray | None:
    """(K, 3) body-frame correction C_vb^T (dl, 0) (m) from solution bias rows (K, 6 + n_extra), or
    None when the layout has no lever-arm states."""
    o = layout.offset(Block.LEVER)
    if o < 0 or bias_rows is None:
        return None
    dl = np.asarray(bias_rows)[:, 6 + o - N_NAV: 6 + o - N_NAV + 2]
    return dl @ np.asarray(C_vb, dtype=float)[:2]


def at_stated_point(nav, C_nb, dl_b) -> np.ndarray:
    """Navigation rows nav (K, 6) [lat_rad, lon_rad, h_m, v_ned] moved from the IMU to the point at
    the stated lever arm from the antenna: + C_nb C_vb^T (dl, 0) per row (dl_b (K, 3) from
    `lever_correction_b`). A new array; velocities stay the IMU's (as the attitude does)."""
    d_ned = np.einsum("kij,kj->ki", C_nb, dl_b)
    out = np.array(nav, copy=True)
    out[:, :3] += ned_rate_to_lla_rate(out[:, 0], out[:, 2], d_ned)  # a metre-sized NED step: the same linear map
    return out


def second_order_shares(t_s, kind, rest_intervals_s) -> np.ndarray:
    """(E,) share of the yaw x lever-arm second-order variance (`measurements._lever_second_order`)
    each row carries, rows in the order a run processes them (t_s session seconds, kind `Kind`): 0
    for a GPS row inside a rest interval ((K, 2) session seconds, sorted: the stops of a platform
    whose attitude does not change there) after the interval's first row of its kind in that order,
    else 1. The term is one constant over such a stop, which its first row brings in; a backward run
    meets each stop at its other end and gives its own first row the term."""
    t = np.asarray(t_s, dtype=float)
    kind = np.asarray(kind)
    share = np.ones(t.size)
    iv = np.asarray(rest_intervals_s if rest_intervals_s is not None else np.zeros((0, 2)), dtype=float).reshape(-1, 2)
    if not iv.shape[0] or not t.size:
        return share
    iv = iv[np.argsort(iv[:, 0])]
    j = np.searchsorted(iv[:, 0], t, side="right") - 1
    rows = np.flatnonzero((j >= 0) & (t <= iv[np.maximum(j, 0), 1]) & np.isin(kind, (Kind.GPS_POSITION, Kind.GPS_VELOCITY)))
    _, first = np.unique(np.stack([j[rows], kind[rows]], axis=1), axis=0, return_index=True)  # first in the given order
    later = np.ones(rows.size, dtype=bool)
    later[first] = False
    share[rows[later]] = 0.0
    return share


def yaw_held_rows(t_s, kind, rest_intervals_s) -> np.ndarray:
    """(E,) bool: the velocity rows (GPS velocity and ZUPT; t_s session seconds, kind `Kind`) inside
    a rest interval ((K, 2) session seconds: the platform's stops), whose update leaves yaw
    uncorrected (`filters.kalman.update_holding`). Heading is not observable at a standstill;
    velocity rows with their honest mm/s at-rest R would otherwise gyrocompass a MEMS gyro through
    the INS error dynamics (the walk log: sigma_yaw 15 -> 10.5 deg over its opening 10 s stop, the
    yaw pulled 6 deg, the next window's forward 75-190 % worse; notes nis20, jobs 3 and 5; with the
    GPS rows held but the walker's ZUPT rows not, the forward was still 28-127 % worse)."""
    t = np.asarray(t_s, dtype=float)
    return in_intervals(t, rest_intervals_s, closed=True) & np.isin(np.asarray(kind), (Kind.GPS_VELOCITY, Kind.ZUPT))


def lever_arm_summary(estimate, sd, stated_b_m, C_vb, decided: str) -> dict:
    """`summary.json` figures: the stated lever arm and the estimated one (IMU axes, m), the
    correction (vehicle forward, right) with its SD; estimate/sd: the block at a run's end (None
    when not estimated)."""
    out: dict = {"stated_m": [round(float(v), 3) for v in np.asarray(stated_b_m, dtype=float)], "decided_by": decided,
                 "estimated": estimate is not None}
    if estimate is not None:
        dl = np.asarray(estimate, dtype=float)[:2]
        out["correction_forward_right_m"] = [round(float(v), 3) for v in dl]
        out["sigma_forward_right_m"] = [round(float(v), 3) for v in np.asarray(sd, dtype=float)[:2]]
        out["estimate_m"] = [round(float(v), 3) for v in np.asarray(stated_b_m, dtype=float) + dl @ np.asarray(C_vb)[:2]]
        # the correction a flipped sign of the stated lever arm would need (a common mistake, issue 12)
        out["flip_needs_forward_right_m"] = [round(float(v), 3) for v in (np.asarray(C_vb) @ (-2.0 * np.asarray(stated_b_m)))[:2]]
    return out
