"""Plausibility of positions in a session: heights, lat/lon written in each other's column, targets
too far from the observer to have been aimed at.

Each check is a plain function over arrays that returns the evidence (figures) or None; the
session loader turns evidence into a refusal naming file, column and row.
"""

from __future__ import annotations

import numpy as np

from tpos_cli.frames import geodetic

# Ellipsoidal heights outside this band are not a platform tpos navigates: the lowest land surface
# (Dead Sea, about -430 m above the geoid, geoid +20 m) and the geoid low (-107 m) stay above
# -1000 m; 100 km is the edge of space.
H_MIN_M = -1000.0
H_MAX_M = 100_000.0
# A target aimed at with a laser rangefinder is within a few km of the observer; 50 km is past any
# handheld rangefinder's reach by a factor of ten.
TARGET_MAX_DISTANCE_M = 50_000.0
# Lat/lon swap test on GPS fixes with velocities: fixes at most this far apart in time, a track of
# at least this length, and the swapped reading must fit this many times better than the given one
# (and better than reading vn/ve exchanged, which is the other way to mismatch).
SWAP_MAX_DT_S = 5.0
SWAP_MIN_TRACK_M = 100.0
SWAP_FIT_RATIO = 3.0
SWAP_LAG = 10

_M_PER_RAD_DEG = 6_371_000.0 * np.pi / 180.0  # metres per degree of arc on a sphere of the Earth's mean radius


def first_bad_height(h_m: np.ndarray) -> int | None:
    """Index of the first finite height outside [H_MIN_M, H_MAX_M], or None."""
    bad = np.flatnonzero(np.isfinite(h_m) & ((h_m < H_MIN_M) | (h_m > H_MAX_M)))
    return int(bad[0]) if bad.size else None


def _finite_spans(t_s, *columns):
    """The rows where `t_s` and every column are finite, and spans of SWAP_LAG fixes over them with no
    gap over SWAP_MAX_DT_S or time reversal inside: ((t, *columns), i, j, step ok mask, lag), or None
    when fewer than 5 rows or 4 spans."""
    a = [np.asarray(x, dtype=float) for x in (t_s, *columns)]
    ok = np.logical_and.reduce([np.isfinite(x) for x in a])
    a = [x[ok] for x in a]
    t = a[0]
    if t.size < 5:
        return None
    dt = np.diff(t)
    step_ok = (dt > 0) & (dt <= SWAP_MAX_DT_S)
    lag = max(1, min(SWAP_LAG, t.size // 4))
    bad_steps = np.concatenate([[0], np.cumsum(~step_ok)])
    i = np.arange(t.size - lag)
    i = i[bad_steps[i + lag] == bad_steps[i]]  # no gap or reversal inside the span
    return None if i.size < 4 else (a, i, i + lag, step_ok, lag)


def _integral(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Trapezoid integral of `v` from the first row to each row of `t`."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])


def velocity_spans(t_s, lat_deg, lon_deg, vn_mps, ve_mps):
    """(lat, lon at the span starts, dlat, dlon over the spans, dN, dE integrated from the velocities)
    over spans of SWAP_LAG fixes (see `latlon_swap_evidence`), or None when the log cannot tell.
    Built once per GPS table and handed to both `latlon_swap_evidence` and `latlon_radians_evidence`."""
    got = _finite_spans(t_s, lat_deg, lon_deg, vn_mps, ve_mps)
    if got is None:
        return None
    (t, lat, lon, vn, ve), i, j, step_ok, _ = got
    n_vel, e_vel = _integral(t, vn), _integral(t, ve)
    if np.hypot(np.diff(n_vel), np.diff(e_vel))[step_ok].sum() < SWAP_MIN_TRACK_M:
        return None
    return lat[i], lon[i], lat[j] - lat[i], lon[j] - lon[i], n_vel[j] - n_vel[i], e_vel[j] - e_vel[i]


def latlon_swap_evidence(spans) -> tuple[float, float] | None:
    """(median mismatch as given, median mismatch with lat and lon exchanged), metres, when the fixes'
    displacements match the logged velocities clearly better with the columns exchanged; else None.
    `spans`: `velocity_spans` of the fixes (None: the log cannot tell).

    Over spans of SWAP_LAG fixes (consecutive fixes at most SWAP_MAX_DT_S apart, so that the
    displacement outgrows the fixes' own noise), the displacement between fixes i and j is compared
    with the trapezoid integral of the velocities, d_v = sum (v_k + v_k+1) dt_k / 2, under three readings:
      given:      dN = dlat R, dE = dlon R cos(lat)
      swapped:    dN = dlon R, dE = dlat R cos(lon)      (lat and lon columns exchanged)
      vel. swap:  positions as given against (ve, vn)    (velocity columns exchanged)
    R is a spherical Earth's metres per radian: the readings differ by factors, not by the flattening.
    The swap is reported only when the swapped reading fits SWAP_FIT_RATIO times better than both
    others and the velocities add up to a track of at least SWAP_MIN_TRACK_M (a static log cannot tell).
    """
    if spans is None:
        return None
    lat, lon, dlat, dlon, dvn, dve = spans
    dlat, dlon = dlat * _M_PER_RAD_DEG, dlon * _M_PER_RAD_DEG
    given = np.hypot(dlat - dvn, dlon * np.cos(np.deg2rad(lat)) - dve)
    swapped = np.hypot(dlon - dvn, dlat * np.cos(np.deg2rad(lon)) - dve)
    vel_swap = np.hypot(dlat - dve, dlon * np.cos(np.deg2rad(lat)) - dvn)
    m_given, m_swapped, m_vel = (float(np.median(x)) for x in (given, swapped, vel_swap))
    if m_swapped * SWAP_FIT_RATIO < min(m_given, m_vel):
        return m_given, m_swapped
    return None


def latlon_radians_evidence(spans) -> tuple[float, float] | None:
    """(median mismatch read as degrees, median mismatch read as radians), metres, when the fixes'
    displacements match the logged velocities SWAP_FIT_RATIO times better with lat and lon read as
    radians (dN = dlat R, dE = dlon R cos(lat), lat in rad): a log writing radians in the degree
    columns moves 57.3 times too little. `spans`: `velocity_spans` of the fixes as logged (lat/lon
    columns in whatever unit they hold), as for `latlon_swap_evidence`; else None."""
    if spans is None:
        return None
    lat, _, dlat, dlon, dvn, dve = spans
    as_deg = np.hypot(dlat * _M_PER_RAD_DEG - dvn, dlon * _M_PER_RAD_DEG * np.cos(np.deg2rad(lat)) - dve)
    r = _M_PER_RAD_DEG * 180.0 / np.pi
    as_rad = np.hypot(dlat * r - dvn, dlon * r * np.cos(lat) - dve)
    m_deg, m_rad = float(np.median(as_deg)), float(np.median(as_rad))
    if m_rad * SWAP_FIT_RATIO < m_deg:
        return m_deg, m_rad
    return None


# Heights in feet against the logged vertical velocity: the heights' changes over non-overlapping spans
# regressed on -integral(vd) give a gain that is 1 in metres and 1/0.3048 = 3.28 in feet. Said only
# when the gain is within FEET_GAIN_TOL of 3.28, more than 5 SDs from 1, and the fixes climb and
# descend at least FEET_MIN_CLIMB_M in all (a flat log cannot tell: its height changes are noise).
FEET_PER_M = 1.0 / 0.3048
FEET_GAIN_TOL = 0.15
FEET_MIN_CLIMB_M = 20.0


def height_feet_evidence(t_s, h, vd_mps) -> tuple[float, float] | None:
    """(gain, its SD) of the fixes' height changes on the heights integrated from -vd, over
    non-overlapping spans of SWAP_LAG fixes, when it shows heights in feet (see FEET_GAIN_TOL);
    else None. Scale-free: shrinking the heights shrinks their noise too, so no fit ratio of two
    readings can tell feet (a flat log in metres would fit "better" as feet)."""
    got = _finite_spans(t_s, h, vd_mps)
    if got is None:
        return None
    (t, h, vd), i, j, _, lag = got
    i, j = i[::lag], j[::lag]  # non-overlapping: independent spans for the SD
    up = -_integral(t, vd)
    dv, dh = up[j] - up[i], h[j] - h[i]
    if i.size < 10 or np.abs(dv).sum() < FEET_MIN_CLIMB_M:
        return None
    k = float(dh @ dv / (dv @ dv))
    sd = float(np.sqrt(np.sum((dh - k * dv) ** 2) / (i.size - 1) / (dv @ dv)))
    if abs(k / FEET_PER_M - 1.0) < FEET_GAIN_TOL and k - 1.0 > 5.0 * sd:
        return k, sd
    return None


def distances_from_m(lla: np.ndarray, origin_lla: np.ndarray) -> np.ndarray:
    """Straight-line distance (m) of each row of `lla` (deg, deg, m) from `origin_lla`."""
    ned = geodetic.lla_to_ned(np.atleast_2d(np.asarray(lla, dtype=float)), np.asarray(origin_lla, dtype=float))
    return np.linalg.norm(ned, axis=1)
