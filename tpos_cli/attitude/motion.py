"""Hand-motion model of a hand-held device held by a standing observer, fitted to the log itself.

The displacement about the mean position is modelled as a damped oscillator driven by white noise
(`_kernels.marg_filter`, `Hand`): p'' = -w0^2 p - 2 zeta w0 p' + w, E[w w] = q delta. Its acceleration
PSD (one-sided, per Hz) is S_a(f) = 2 q w^4 / ((w0^2 - w^2)^2 + (2 zeta w0 w)^2), w = 2 pi f:
flat (2 q) above w0, falling as f^4 below it, as a bounded displacement requires. q, w0 and zeta are
fitted (Whittle's likelihood) to the PSD of the log's own NED acceleration C f + g in a band where a tilt error of the
attitude used (a slowly varying g phi) does not reach; the stationary displacement SD is then
sqrt(q / (4 zeta w0^3)). The damping is fitted too: a hand that moves the device back and forth
rhythmically (a translation at ~0.5 Hz) has a sharp resonance (zeta ~ 0.05), a hand that only holds
it still while turning it a broad one (zeta ~ 1); a fixed zeta fits the first with the edge of its
frequency range, which is no fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import welch

from tpos_cli.errors import ProcessingError

FREQ_RANGE_HZ = (0.05, 10.0)
DAMPING_RANGE = (0.05, 1.0)


@dataclass(frozen=True)
class OscillatorFit:
    """Fitted hand-motion oscillator: natural frequency (Hz), damping ratio, displacement SD (m),
    driving-noise PSD q (m^2/s^3), moving fraction of the log, and the band used (Hz)."""

    freq_hz: float
    damping: float
    sd_m: float
    q_m2ps3: float
    moving_fraction: float
    band_hz: tuple[float, float]


def displacement_var(freq_hz, damping, q):
    """Stationary (var p m^2, var v (m/s)^2) of the oscillator per axis, driving PSD q."""
    w0 = 2.0 * np.pi * freq_hz
    vp = q / (4.0 * damping * w0**3)
    return vp, w0**2 * vp


def oscillator_psd(f_hz, freq_hz, damping, q):
    """One-sided acceleration PSD ((m/s^2)^2/Hz) of the oscillator at frequencies f_hz."""
    w = 2.0 * np.pi * np.asarray(f_hz, dtype=float)
    w0 = 2.0 * np.pi * freq_hz
    return 2.0 * q * w**4 / ((w0**2 - w**2) ** 2 + (2.0 * damping * w0 * w) ** 2)


def fit_oscillator(t_s, acc_ned_mps2, moving, band_hz=(0.3, 5.0), damping=None, segment_s: float | None = None,
                   acc_noise_mps2: float = 0.0) -> OscillatorFit:
    """Whittle maximum-likelihood fit of the oscillator to the NED kinematic acceleration (N,3).

    Whittle's negative log-likelihood of the Welch PSD S over the band's bins, sum(log S_m + S / S_m) with
    S_m the model's PSD (+ floor), is minimised over frequency, damping and q; without a floor the best q for
    a shape is closed-form, mean(S / shape), so the model holds the log's in-band power on average whatever
    shape it misses. (A least-squares fit of log PSDs holds their geometric mean instead, below the mean by
    Jensen's inequality where the shape misfits: BROAD's trials, whose power one oscillator cannot follow
    across 0.3-5 Hz, were fitted with q 1.02-2.5x low and hand checks over-confident.)

    `moving` (N,) bool marks the samples outside detected still periods; the PSD of the whole log is
    divided by their fraction (a still device contributes no acceleration), so q is the intensity
    while the device moves. The mean PSD over the three axes is fitted over frequency and damping
    (`damping` given: held fixed). The accelerometer's white noise (`acc_noise_mps2` per sample) is a
    floor under the hand's PSD (one-sided, 2 sigma^2 dt, reduced by the moving fraction like the rest)
    that the filter already counts, so the fit is q shape + floor. `segment_s` (Welch segment length)
    defaults to the longer of 20 s and four periods of the band's lowest frequency, so that a band
    reaching low frequencies is resolved. Raises ProcessingError when the log is too short, never moves, or
    the best frequency lies at the edge of `FREQ_RANGE_HZ` (no oscillator shape in the band).
    """
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(acc_ned_mps2, dtype=float)
    frac = float(np.mean(moving))
    dt = float(np.median(np.diff(t)))
    if segment_s is None:
        segment_s = max(20.0, 4.0 / band_hz[0])
    nper = int(min(round(segment_s / dt), t.size))
    if frac <= 0.0 or nper < int(4.0 / (band_hz[0] * dt)):
        raise ProcessingError("motion model: the log is too short or never moves; cannot fit the hand-motion model")
    a = np.where(np.isfinite(a), a, 0.0)
    a = a - a.mean(axis=0)
    f, S = welch(a, fs=1.0 / dt, nperseg=nper, axis=0)
    S = S.mean(axis=1) / frac
    sel = (f >= band_hz[0]) & (f <= band_hz[1]) & (S > 0)
    lf, Sf = f[sel], S[sel]
    grid = np.exp(np.linspace(np.log(FREQ_RANGE_HZ[0]), np.log(FREQ_RANGE_HZ[1]), 150))
    zetas = np.array([damping]) if damping is not None else np.exp(np.linspace(*np.log(DAMPING_RANGE), 25))
    best = None
    floor = 2.0 * acc_noise_mps2**2 * dt / frac
    for z in zetas:
        for fn in grid:
            shape = oscillator_psd(lf, fn, z, 1.0)
            q0 = float(np.mean(Sf / shape))  # Whittle's best q without a floor, in closed form
            qs = q0 * np.exp(np.linspace(-12.0, 0.5, 126)) if floor > 0.0 else np.array([q0])
            Sm = qs[:, None] * shape[None] + floor
            costs = np.sum(np.log(Sm) + Sf[None] / Sm, axis=1)  # Whittle's negative log-likelihood
            i = int(np.argmin(costs))
            if best is None or costs[i] < best[0]:
                best = (float(costs[i]), fn, z, float(qs[i]))
    _, fn, z, q = best
    if fn <= grid[0] or fn >= grid[-1]:
        raise ProcessingError(f"motion model: the acceleration PSD in {band_hz[0]}-{band_hz[1]} Hz has no "
                              f"hand-motion shape (fit at the edge of {FREQ_RANGE_HZ[0]}-{FREQ_RANGE_HZ[1]} Hz)")
    vp, _ = displacement_var(fn, z, q)
    return OscillatorFit(freq_hz=float(fn), damping=float(z), sd_m=float(np.sqrt(vp)), q_m2ps3=float(q),
                         moving_fraction=frac, band_hz=(float(band_hz[0]), float(band_hz[1])))
