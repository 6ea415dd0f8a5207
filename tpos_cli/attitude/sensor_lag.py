"""Delay of the magnetometer behind the gyro, estimated from the log's own rotations.

A field that is constant in the navigation frame obeys, in body axes, dm_b/dt = -omega_b x m_b
(Earth rate neglected: 15 deg/h against hand rates of tens of deg/s). A magnetometer that reports
m_b(t - tau) (internal filtering, a slower sampling clock) satisfies it only with the gyro delayed by
tau too. During a turn at rate w a delay tau tilts the measured field by w tau (100 deg/s x 11 ms =
1.1 deg), and a MARG filter's magnetic update, whose azimuth depends on the tilt through the field's
dip, turns that into a rotation-rate-dependent attitude error. tau is the delay that minimizes the
residual of the kinematic relation over the samples where the device turns; the magnetometer is then
read tau later (`advance`).

Gyro rows follow the package's IMU convention (mean rate over (t_{k-1}, t_k], i.e. the rate at the
interval's midpoint), magnetometer rows are instantaneous at t_k: a log without delay gives tau = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt
from scipy.stats import chi2


@dataclass(frozen=True)
class SensorLag:
    """Estimated delay (s, > 0: the magnetometer lags the gyro), the kinematic residual RMS (uT/s)
    at that delay and at zero delay, the number of turning samples used, and why tau may be 0."""

    lag_s: float
    rms_uts: float
    rms_zero_uts: float
    n_used: int
    reason: str = ""


def estimate_mag_lag(t_s, gyro_b_rps, mag_b_ut, min_rate_rps=np.radians(20.0), max_lag_s=0.05,
                     lowpass_hz=5.0, step_s=2.5e-4, min_samples=500, significance=0.999) -> SensorLag:
    """Delay of the magnetometer behind the gyro that best satisfies dm_b/dt = -omega_b x m_b.

    Both signals pass the same zero-phase low-pass (lowpass_hz: the hand's rotations, not the
    sensors' noise), so the filter itself adds no delay. The residual is evaluated for delays on a
    grid of step_s within +-max_lag_s (gyro interpolated at the midpoint times minus tau) over the
    samples turning faster than min_rate_rps; tau = 0 with a reason when fewer than min_samples turn
    or the minimum sits on the edge of the grid (no delay explains the log better than the bounds),
    or the residual's drop from tau = 0 is not significant at `significance`.
    """
    t = np.asarray(t_s, dtype=float)
    w = np.asarray(gyro_b_rps, dtype=float)
    m = np.asarray(mag_b_ut, dtype=float)
    n = t.size
    ok = np.all(np.isfinite(m), axis=1) & np.all(np.isfinite(w), axis=1)
    if n < 50 or ok.sum() < min_samples:
        return SensorLag(0.0, np.nan, np.nan, int(ok.sum()), "too few magnetometer samples")
    dt = float(np.median(np.diff(t)))
    idx = np.arange(n)
    m = np.stack([np.interp(idx, idx[ok], m[ok, j]) for j in range(3)], axis=1)
    wf = w.copy()
    if lowpass_hz < 0.45 / dt:
        sos = butter(4, lowpass_hz * 2.0 * dt, output="sos")
        m = sosfiltfilt(sos, m, axis=0)
        wf = sosfiltfilt(sos, wf, axis=0)
    dm = np.gradient(m, t, axis=0)
    t_mid = t.copy()
    t_mid[1:] = 0.5 * (t[1:] + t[:-1])  # a gyro row is the mean over its interval
    t_mid[0] = t[0] - 0.5 * dt
    edge = int(np.ceil(max_lag_s / dt)) + 2
    sel = ok & (np.linalg.norm(wf, axis=1) > min_rate_rps)
    sel[:edge] = False
    sel[n - edge:] = False
    if sel.sum() < min_samples:
        return SensorLag(0.0, np.nan, np.nan, int(sel.sum()), "the device hardly turns")
    ts, ms, dms = t[sel], m[sel], dm[sel]

    def rms(tau):
        wl = np.stack([np.interp(ts - tau, t_mid, wf[:, j]) for j in range(3)], axis=1)
        r = dms + np.cross(wl, ms)
        return float(np.sqrt(np.mean(np.sum(r * r, axis=1))))

    grid = np.arange(-max_lag_s, max_lag_s + 0.5 * step_s, step_s)
    cost = np.array([rms(tau) for tau in grid])
    k = int(np.argmin(cost))
    r0 = rms(0.0)
    if k == 0 or k == grid.size - 1:
        return SensorLag(0.0, r0, r0, int(sel.sum()), "best delay on the edge of the searched range")
    c0, c1, c2 = cost[k - 1], cost[k], cost[k + 1]
    den = c0 - 2.0 * c1 + c2
    tau = grid[k] + (0.5 * (c0 - c2) / den * step_s if den > 0 else 0.0)  # parabola through the minimum
    r_tau = rms(tau)
    # likelihood-ratio test of tau against 0 on the independent samples the low-pass leaves
    # (about 2 lowpass_hz per second): a log without a delay must keep its samples as they are
    n_eff = sel.sum() * dt * 2.0 * min(lowpass_hz, 0.5 / dt)
    if not r_tau > 0 or n_eff * np.log(r0**2 / r_tau**2) < chi2.ppf(significance, 1):
        return SensorLag(0.0, r0, r0, int(sel.sum()), "no significant delay")
    return SensorLag(float(tau), r_tau, r0, int(sel.sum()))


def advance(t_s, x, lag_s):
    """(N,k) samples x read lag_s later (x(t + lag_s), linear interpolation between the finite rows,
    ends held): removes a delay. Rows that are NaN (no sample) stay NaN."""
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x, dtype=float)
    out = x.copy()
    ok = np.all(np.isfinite(x), axis=1)
    if lag_s == 0.0 or ok.sum() < 2:
        return out
    for j in range(x.shape[1]):
        out[ok, j] = np.interp(t[ok] + lag_s, t[ok], x[ok, j])
    return out
