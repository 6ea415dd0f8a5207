"""Where a run's platform stood still, by its solution's velocity: the stretches the Allan page may use.

The IMU's own stillness test (`alignment.static_mask`: moving-window mean rate and specific-force
scatter) cannot tell a platform at rest from a vehicle driving straight at constant speed on an
even road: neither rotates nor accelerates. Such a stretch has driving in it (pitch over hills,
steering), and its Allan deviation is not the sensor's noise. The solution's velocity (GPS-aided)
tells them apart: at rest its speed stays below `REST_SPEED_MPS`, driving it is metres per second.
"""

from __future__ import annotations

import numpy as np

from tpos_cli.io.columns import Columns, column

REST_SPEED_MPS = 0.1  # the speed under which the chains' stop detector counts a vehicle as stopped (fusion.constraints)
MAX_STEP_S = 1.5  # epochs further apart than this end a stretch (a gap in the solution)


def solution_velocity(trajectory: Columns | None, solution: str | None) -> tuple[np.ndarray, np.ndarray] | None:
    """(t logger clock (N,), NED velocity m/s (N, 3)) of one solution of trajectory.parquet, or None
    when the run writes no velocity for it (attitude-only solutions, older runs)."""
    if trajectory is None or solution is None or not {"vn", "ve", "vd"} <= set(trajectory.columns):
        return None
    rows = np.asarray(column(trajectory, "solution")) == solution
    v = np.stack([np.asarray(column(trajectory, c), dtype=float)[rows] for c in ("vn", "ve", "vd")]).T
    if not np.isfinite(v).all(axis=1).any():
        return None
    return np.asarray(column(trajectory, "t"), dtype=float)[rows], v


def rest_stretches(t_s, vel_ned_mps, min_s: float) -> np.ndarray:
    """[first, last] epochs (K, 2) of the runs of consecutive epochs whose speed |v| is below
    `REST_SPEED_MPS`, at most `MAX_STEP_S` apart, lasting at least `min_s` (NaN velocity is not rest)."""
    t = np.asarray(t_s, dtype=float)
    rest = np.linalg.norm(np.asarray(vel_ned_mps, dtype=float), axis=1) < REST_SPEED_MPS  # NaN -> False
    if t.size == 0:
        return np.empty((0, 2))
    # a run continues while the next epoch is at rest too and close enough in time
    joined = rest[1:] & rest[:-1] & (np.diff(t) <= MAX_STEP_S)
    starts = np.flatnonzero(rest & np.concatenate([[True], ~joined]))
    ends = np.flatnonzero(rest & np.concatenate([~joined, [True]]))
    out = np.column_stack([t[starts], t[ends]])
    return out[out[:, 1] - out[:, 0] >= min_s]
