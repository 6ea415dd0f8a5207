"""RTK-like GPS fix errors: a centimetre floor, float stretches and multipath steps (issue 11 item 7).

An RTK receiver states a constant floor SD while its ambiguities are fixed, and its error is then
white at that floor. For a few seconds at a time it falls back to a float solution: it raises its
stated SD, but by far less than its error grows (a correlated offset of decimetres). Multipath can
also shift a fixed solution for a few seconds while the receiver still states its floor.

The defaults describe the shared real log `rtklibexplorer_drive_0708_part1` (u-blox RTK, 4 Hz,
293 s of fixes; helper nis, session 19, job 2): its stated sigma_n/sigma_e sit at 0.99 cm (1154 of
1174 rows) and sigma_u at 1.0 cm; it raises sigma_n to 1.07-2.57x that floor in three stretches
(37.4-40.9 s, 141.6 s and 193.6-195.1 s after the first IMU sample: 0.6 per minute, 0.25-3.75 s
long) while those fixes sit 5-25 cm off a smoothed run that never used them. They describe the data
and tune no filter. Not measured there (the log's truth is its own fixes): the offset's time
constant `float_tau_s` and every multipath figure, which are assumed and say so below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.sim.sensor_errors import gauss_markov

FIXED, FLOAT, MULTIPATH = 0, 1, 2  # regime codes of an epoch


@dataclass(frozen=True)
class RtkModel:
    """Figures of the RTK error model; ranges (lo, hi) are drawn uniformly per stretch."""

    floor_sigma_neu_m: tuple[float, float, float] = (0.0099, 0.0099, 0.010)  # the real log's stated floor
    float_per_min: float = 0.6  # float stretch starts per minute of fixed time (real log: 3 in 4.9 min)
    float_duration_s: tuple[float, float] = (0.25, 3.75)  # real log: 1, 7 and 15 epochs at 4 Hz
    float_sd_factor: tuple[float, float] = (1.2, 2.6)  # stated SD / floor in a stretch (real log: up to 2.57)
    float_offset_m: tuple[float, float] = (0.05, 0.25)  # horizontal RMS of the offset (real log: 5-25 cm)
    float_tau_s: float = 5.0  # assumed: the offset's correlation time (not measurable on the real log)
    multipath_per_min: float = 0.5  # assumed, as the three multipath figures below: the real log
    multipath_duration_s: tuple[float, float] = (1.0, 5.0)  # cannot show an offset its receiver
    multipath_offset_m: tuple[float, float] = (0.03, 0.10)  # did not state (horizontal size of the step)

    def __post_init__(self) -> None:
        ranges = (self.float_duration_s, self.float_sd_factor, self.float_offset_m, self.multipath_duration_s,
                  self.multipath_offset_m)
        if (min(self.floor_sigma_neu_m) <= 0 or min(self.float_per_min, self.multipath_per_min) < 0
                or self.float_tau_s <= 0 or any(not 0 <= lo <= hi for lo, hi in ranges)
                or self.float_duration_s[1] <= 0 or self.multipath_duration_s[1] <= 0 or self.float_sd_factor[0] < 1):
            raise InvalidInputError("gps rtk: floor SDs, durations and time constant must be > 0, rates and offsets >= 0, "
                                    "ranges (lo, hi) with lo <= hi, the SD factor >= 1")


@dataclass(frozen=True)
class RtkErrors:
    """The drawn RTK errors at every GPS epoch (before outage rows are removed) and their parameters."""

    regime: np.ndarray  # (M,) FIXED | FLOAT | MULTIPATH
    sigma_neu_m: np.ndarray  # (M, 3) the stated SDs: the floor, times the stretch's factor in a float stretch
    offset_neu_m: np.ndarray  # (M, 3) the error beyond the white floor noise (zero at fixed epochs)
    float_s: np.ndarray  # (K, 2) start, end of each float stretch (end exclusive)
    float_sd_factor: np.ndarray  # (K,)
    float_offset_sd_neu_m: np.ndarray  # (K, 3) stationary SD per axis of the stretch's Gauss-Markov offset
    multipath_s: np.ndarray  # (J, 2) start, end of each multipath step
    multipath_offset_neu_m: np.ndarray  # (J, 3) the step's constant offset


def stretches(duration_s: float, per_min: float, length_s, rng: np.random.Generator) -> np.ndarray:
    """(K, 2) start, end of non-overlapping stretches in [0, duration_s): the gap before each is
    exponential with mean 60 / `per_min` s (a Poisson process of starts in the time between
    stretches), its length uniform in `length_s`."""
    out = []
    if per_min > 0:
        t = rng.exponential(60.0 / per_min)
        while t < duration_s:
            end = t + rng.uniform(*length_s)
            out.append((t, end))
            t = end + rng.exponential(60.0 / per_min)
    return np.array(out, dtype=float).reshape(-1, 2)


def rtk_errors(t_s, model: RtkModel, rng: np.random.Generator) -> RtkErrors:
    """Draw the regimes, stated SDs and offsets of `model` at the equally spaced epochs `t_s`.

    Float stretch k: stated SD = floor x f_k (f_k uniform in `float_sd_factor`); offset per axis a
    stationary first-order Gauss-Markov sequence over the stretch's epochs, SD s_k / sqrt(2) north
    and east (s_k uniform in `float_offset_m`, the horizontal RMS) and that times floor_u / floor_h
    up, time constant `float_tau_s`. Multipath step j (outside float stretches: a float solution is
    what the receiver reports there): stated SD the floor, a constant offset of horizontal size
    uniform in `multipath_offset_m` in a uniform direction, up that times floor_u / floor_h with a
    random sign. The white noise at the floor is not drawn here (simulate_gps draws it).
    """
    t = np.asarray(t_s, dtype=float)
    floor = np.asarray(model.floor_sigma_neu_m, dtype=float)
    up_ratio = floor[2] / floor[0]
    span = float(t[-1] - t[0]) + (t[1] - t[0] if t.size > 1 else 0.0)
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    fl = stretches(span, model.float_per_min, model.float_duration_s, rng) + t[0]
    factor = rng.uniform(*model.float_sd_factor, size=len(fl))
    off_sd = rng.uniform(*model.float_offset_m, size=len(fl))[:, None] * np.array([1.0, 1.0, up_ratio]) / np.sqrt(2.0)
    mp = stretches(span, model.multipath_per_min, model.multipath_duration_s, rng) + t[0]
    size = rng.uniform(*model.multipath_offset_m, size=len(mp))
    az = rng.uniform(-np.pi, np.pi, size=len(mp))
    mp_off = size[:, None] * np.column_stack([np.cos(az), np.sin(az), up_ratio * rng.choice([-1.0, 1.0], size=len(mp))])

    regime = np.full(t.size, FIXED, dtype=np.int8)
    sigma = np.tile(floor, (t.size, 1))
    offset = np.zeros((t.size, 3))
    for (start, end), d in zip(mp, mp_off, strict=True):
        inside = (t >= start) & (t < end)
        regime[inside], offset[inside] = MULTIPATH, d
    for (start, end), f, sd in zip(fl, factor, off_sd, strict=True):
        inside = (t >= start) & (t < end)
        regime[inside], sigma[inside] = FLOAT, floor * f
        if inside.any():
            offset[inside] = gauss_markov(int(inside.sum()), 1.0, model.float_tau_s, dt, rng) * sd
    return RtkErrors(regime, sigma, offset, fl, factor, off_sd, mp, mp_off)
