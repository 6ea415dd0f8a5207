"""IMU noise figures for the filters: which value each chain uses, and where it came from.

One resolution for every chain: a key the pipeline sets (file or `--set`) wins, then the session's
`[imu]` figure, then a figure measured from the log (when the chain measures one), then the
pipeline model's default. Figures are in the contract's units (`gyro_noise_dps` and
`acc_noise_mg` white noise SD per sample, `gyro_bias_dph` and `acc_bias_mg` bias SD,
`mag_noise_ut`); `ImuNoiseFigures.summary()` records value and source for `summary.json`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel

KEYS = ("gyro_noise_dps", "acc_noise_mg", "gyro_bias_dph", "acc_bias_mg", "mag_noise_ut")


@dataclass(frozen=True)
class ImuNoiseFigures:
    """Resolved figures (contract units) and the source of each: "pipeline", "session",
    the `measured` label, or "default"."""

    values: Mapping[str, float]
    sources: Mapping[str, str]

    def __getitem__(self, key: str) -> float:
        return self.values[key]

    def summary(self, digits: int = 6) -> dict:
        return {k: {"value": round(float(v), digits), "source": self.sources[k]} for k, v in self.values.items()}


def resolve_imu_noise(params: BaseModel, session_noise, *, measured: Mapping[str, float | None] | None = None,
                      measured_label: str = "measured from the log", keys=KEYS[:4]) -> ImuNoiseFigures:
    """Figures for `keys`: pipeline (a key the user set: in `params.model_fields_set`) > session
    `[imu]` (`session_noise`, a `session.ImuNoise`) > `measured` > the model's default."""
    measured = measured or {}
    values, sources = {}, {}
    for key in keys:
        given = getattr(params, key)
        if key in params.model_fields_set and given is not None:
            v, src = given, "pipeline"
        elif getattr(session_noise, key, None) is not None:
            v, src = getattr(session_noise, key), "session"
        elif measured.get(key) is not None:
            v, src = measured[key], measured_label
        else:
            v, src = type(params).model_fields[key].default, "default"
        values[key] = float(v)
        sources[key] = src
    return ImuNoiseFigures(values, sources)


def _row_medians(d: np.ndarray) -> np.ndarray:
    """np.median(d, axis=1), the same values, of a C-contiguous (m, n) array whose rows it partitions in
    place: one selection per row (the upper middle) and the largest of the lower half, where numpy's
    median selects three elements (the two middles and, for its NaN check, the largest): 6x faster
    on an hour of IMU differences. NaN rows (or no columns): numpy's own."""
    n = d.shape[1]
    if n == 0 or np.isnan(d).any():
        return np.median(d, axis=1, overwrite_input=True)
    h = n // 2
    d.partition(h, axis=1)
    if n % 2:
        return d[:, h].copy()
    return (d[:, :h].max(axis=1) + d[:, h]) / 2.0  # numpy's mean of the two middles


def measured_white_noise(x, block_n: int = 1, *, robust: bool = True) -> float:
    """Per-sample white-noise SD of a sensor series (N, 3), from the first differences of its means
    over blocks of `block_n` samples (1: the samples themselves), times sqrt(block_n).

    For white noise of SD s, consecutive block means differ with SD s sqrt(2 / block_n), so the figure
    is s at any block size; the motion of a vehicle at IMU rates adds little to a difference. For
    vibration, whose power sits far above 1 / (block_n dt), blocks give a much smaller figure than
    samples: what the strapdown integration feels over a block. Robust scale (1.4826 MAD) so that
    bumps do not dominate; averaged over the three axes. robust=False: the RMS of the differences
    instead, every bump counted (a walker's steps: `chains.drive_smooth.step_acc_noise`).
    """
    x = np.asarray(x, dtype=float)
    if block_n > 1:
        k = x.shape[0] // block_n
        x = x[: k * block_n].reshape(k, block_n, x.shape[1]).mean(axis=1)
    if not robust:
        return float(np.mean(np.std(np.diff(x, axis=0), axis=0) / np.sqrt(2.0)) * np.sqrt(block_n))
    d = np.empty((x.shape[1], x.shape[0] - 1))  # one contiguous row per axis: the medians partition rows
    np.subtract(x[1:].T, x[:-1].T, out=d)
    # medians of temporaries partitioned in place (no copies): the order of d does not matter below
    d -= _row_medians(d)[:, None]
    mad = _row_medians(np.abs(d, out=d))
    return float(np.mean(1.4826 * mad / np.sqrt(2.0)) * np.sqrt(block_n))


def stop_noise_factors(t_s, gyro_b_rps, acc_b_mps2, intervals_s, q, rate_hz: float, *, floors=(0.0, 0.0),
                       block_s: float = 1.0, min_blocks: int = 8) -> np.ndarray:
    """(K, 4) [t0, t1, acc factor, gyro factor] per detected stop (intervals_s (K, 2), the IMU's time):
    the white-noise PSDs q[0], q[1] (measured on the whole log: on a moving car mostly vibration)
    scaled to the IMU's noise inside the stop at the time scale of the covariance growth between
    fixes: `measured_white_noise` over blocks of `block_s` (at least `min_blocks` of them; a shorter
    stop keeps the per-sample scatter, blocks of one sample, the larger), at least `floors`
    (per-sample SDs, the pipeline's default noise figures), factor at most 1: a stop never gets
    more noise than the run. An idling engine's vibration (part 1's first stop: 11 mg / 1.5 deg/s
    per sample) averages out over a second (2.3 mg / 0.26 deg/s); the whole-log figure is the moving
    car's (26 mg / 1.6 deg/s). A stop where either sensor's scatter reaches the run's figure (its factor
    capped at 1) is not still in the IMU's sense: both factors stay 1. A standing walker shifting his
    weight (the walk's second stop: accelerometer at the run's figure, gyro at 0.009 of it) keeps
    moving on the IMU: with only the gyro's noise lowered the filter there lagged a steady 2-3 cm/s
    velocity residual (rule chosen after seeing that walk; the car stops' factors are all under 1)."""
    t = np.asarray(t_s, dtype=float)
    n = max(1, int(round(block_s * rate_hz)))
    out = []
    for a, b in np.asarray(intervals_s, dtype=float).reshape(-1, 2):
        m = (t >= a) & (t <= b)
        count = int(m.sum())
        if count < 20:
            continue
        block_n = n if count >= min_blocks * n else 1
        sd_a = max(floors[0], measured_white_noise(acc_b_mps2[m], block_n))
        sd_g = max(floors[1], measured_white_noise(gyro_b_rps[m], block_n))
        f = (sd_a**2 / rate_hz / q[0], sd_g**2 / rate_hz / q[1])
        out.append([a, b, *((1.0, 1.0) if max(f) >= 1.0 else f)])
    return np.array(out, dtype=float).reshape(-1, 4)
