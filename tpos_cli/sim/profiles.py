"""Smooth scalar profiles of time with exact first and second derivatives.

The simulator's truth (speed, heading, grade, aiming angles) is built from these, so that every
rate the IMU senses is an analytic derivative, never a finite difference. A ramp changes a value
by `delta` over `duration_s` with the septic smoothstep S(x) = 35x^4 - 84x^5 + 70x^6 - 20x^7,
whose first three derivatives vanish at both ends: profiles made of ramps are C3, so angular
rates and specific force are C2 (continuous, as the mechanization's coning/sculling terms assume).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: max of S'(x) (at x = 1/2): the peak rate of a ramp is SMOOTHSTEP_PEAK_RATE * delta / duration.
SMOOTHSTEP_PEAK_RATE = 140.0 / 64.0


def smoothstep7(x):
    """Septic smoothstep S(x) on [0, 1] (clamped outside) and its derivatives S', S'' w.r.t. x."""
    x = np.clip(np.asarray(x, dtype=float), 0.0, 1.0)
    x2 = x * x
    s = x2 * x2 * (35.0 - 84.0 * x + 70.0 * x2 - 20.0 * x2 * x)
    xm = 1.0 - x
    ds = 140.0 * (x * xm) ** 3
    d2s = 420.0 * (x * xm) ** 2 * (1.0 - 2.0 * x)
    return s, ds, d2s


@dataclass(frozen=True)
class RampProfile:
    """Initial value plus non-overlapping smoothstep ramps (sorted by start time).

    Attributes
    ----------
    initial : float
        Value before the first ramp.
    t_start_s, duration_s, delta : ndarray (R,)
        Ramp starts (s), durations (s, > 0) and the change each ramp makes.
    """

    initial: float
    t_start_s: np.ndarray
    duration_s: np.ndarray
    delta: np.ndarray

    @classmethod
    def from_ramps(cls, initial: float, ramps) -> RampProfile:
        """Build from an iterable of (t_start_s, duration_s, delta); raises ValueError on overlaps."""
        r = np.asarray(list(ramps), dtype=float).reshape(-1, 3)
        order = np.argsort(r[:, 0], kind="stable")
        r = r[order]
        if np.any(r[:, 1] <= 0.0):
            raise ValueError("`duration_s` of every ramp must be > 0")
        if np.any(r[:-1, 0] + r[:-1, 1] > r[1:, 0] + 1e-9):
            raise ValueError("ramps of one profile must not overlap")
        return cls(float(initial), r[:, 0].copy(), r[:, 1].copy(), r[:, 2].copy())

    def eval(self, t_s):
        """Value, first and second time derivatives at times `t_s` (any shape)."""
        t = np.asarray(t_s, dtype=float)
        f = np.full(t.shape, self.initial)
        if self.t_start_s.size == 0:
            return f, np.zeros(t.shape), np.zeros(t.shape)
        before = np.concatenate([[0.0], np.cumsum(self.delta)])  # sum of the ramps before ramp i
        i = np.searchsorted(self.t_start_s, t, side="right") - 1
        active = i >= 0
        j = np.where(active, i, 0)
        T = self.duration_s[j]
        s, ds, d2s = smoothstep7((t - self.t_start_s[j]) / T)
        d = np.where(active, self.delta[j], 0.0)
        f = f + np.where(active, before[j], 0.0) + d * s
        return f, d * ds / T, d * d2s / T**2


@dataclass(frozen=True)
class SineProfile:
    """offset + amplitude * sin(2 pi t / period_s + phase_rad)."""

    amplitude: float
    period_s: float
    offset: float = 0.0
    phase_rad: float = 0.0

    def eval(self, t_s):
        """Value, first and second time derivatives at times `t_s`."""
        w = 2.0 * np.pi / self.period_s
        a = w * np.asarray(t_s, dtype=float) + self.phase_rad
        return (
            self.offset + self.amplitude * np.sin(a),
            self.amplitude * w * np.cos(a),
            -self.amplitude * w * w * np.sin(a),
        )


@dataclass(frozen=True)
class ConstantProfile:
    """A constant value."""

    value: float = 0.0

    def eval(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return np.full(t.shape, self.value), np.zeros(t.shape), np.zeros(t.shape)
