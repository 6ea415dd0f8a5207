"""Hand-motion model of a hand-held device held by a standing observer, fitted to the log itself.

The displacement about the mean position is modelled as a damped oscillator driven by white noise
(`_kernels.run_full`, `osc`): p'' = -w0^2 p - 2 zeta w0 p' + w, E[w w] = q delta. Its acceleration
PSD (one-sided, per Hz) is S_a(f) = 2 q w^4 / ((w0^2 - w^2)^2 + (2 zeta w0 w)^2), w = 2 pi f:
flat (2 q) above w0, falling as f^4 below it, as a bounded displacement requires. q and w0 are
fitted to the PSD of the log's own NED acceleration C f + g in a band where a tilt error of the
attitude used (a slowly varying g phi) does not reach; the stationary displacement SD is then
sqrt(q / (4 zeta w0^3)).

A hand's acceleration spectrum also falls above a few hertz (muscles do not drive it white). With
`corner=True` the driving force is a first-order Gauss-Markov process of corner frequency wc
(u' = -wc u + w), which multiplies S_a by 1 / (wc^2 + w^2): a band-pass shape with one more
parameter, fitted with the others (the single oscillator is its limit wc -> infinity).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import welch

from tpos_cli.errors import ProcessingError


@dataclass(frozen=True)
class OscillatorFit:
    """Fitted hand-motion oscillator: natural frequency (Hz), damping ratio, displacement SD (m),
    driving-noise PSD q ((m/s^2)^2/Hz), moving fraction of the log, and the band used (Hz)."""

    freq_hz: float
    damping: float
    sd_m: float
    q_m2ps3: float
    moving_fraction: float
    band_hz: tuple[float, float]
    corner_hz: float = 0.0  # > 0: corner of the Gauss-Markov driving force (band-pass model); 0: white


def displacement_var(freq_hz, damping, q, corner_hz=0.0):
    """Stationary (var p m^2, var v (m/s)^2) of the hand model, per axis (Lyapunov equation)."""
    from scipy.linalg import solve_continuous_lyapunov
    w0 = 2.0 * np.pi * freq_hz
    if corner_hz <= 0.0:
        vp = q / (4.0 * damping * w0**3)
        return vp, w0**2 * vp
    wc = 2.0 * np.pi * corner_hz
    F = np.array([[0.0, 1.0, 0.0], [-w0**2, -2.0 * damping * w0, 1.0], [0.0, 0.0, -wc]])
    Qc = np.diag([0.0, 0.0, q])
    P = solve_continuous_lyapunov(F, -Qc)
    return float(P[0, 0]), float(P[1, 1])


def oscillator_psd(f_hz, freq_hz, damping, q):
    """One-sided acceleration PSD ((m/s^2)^2/Hz) of the oscillator at frequencies f_hz."""
    w = 2.0 * np.pi * np.asarray(f_hz, dtype=float)
    w0 = 2.0 * np.pi * freq_hz
    return 2.0 * q * w**4 / ((w0**2 - w**2) ** 2 + (2.0 * damping * w0 * w) ** 2)


def hand_psd(f_hz, freq_hz, damping, q, corner_hz=0.0):
    """One-sided acceleration PSD of the oscillator driven by white (corner_hz = 0) or
    Gauss-Markov (corner_hz > 0, force PSD q / (wc^2 + w^2)) noise."""
    S = oscillator_psd(f_hz, freq_hz, damping, q)
    if corner_hz > 0.0:
        S = S / ((2.0 * np.pi * corner_hz) ** 2 + (2.0 * np.pi * np.asarray(f_hz, dtype=float)) ** 2)
    return S


def fit_oscillator(t_s, acc_ned_mps2, moving, band_hz=(0.3, 5.0), damping=0.7071, segment_s=20.0,
                   corner: bool = False) -> OscillatorFit:
    """Least-squares fit (in log PSD) of the oscillator to the NED kinematic acceleration (N,3).

    `moving` (N,) bool marks the samples outside detected still periods; the PSD of the whole log is
    divided by their fraction (a still device contributes no acceleration), so q is the intensity
    while the device moves. The mean PSD over the three axes is fitted. `corner`: also fit the
    corner of a Gauss-Markov driving force (0.1-20 Hz; a corner at the top of that range is no
    corner inside the band, and the white model is returned).
    """
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(acc_ned_mps2, dtype=float)
    frac = float(np.mean(moving))
    dt = float(np.median(np.diff(t)))
    nper = int(min(round(segment_s / dt), t.size))
    if frac <= 0.0 or nper < int(4.0 / (band_hz[0] * dt)):
        raise ProcessingError("motion model: the log is too short or never moves; cannot fit the hand-motion model")
    a = np.where(np.isfinite(a), a, 0.0)
    a = a - a.mean(axis=0)
    f, S = welch(a, fs=1.0 / dt, nperseg=nper, axis=0)
    S = S.mean(axis=1) / frac
    sel = (f >= band_hz[0]) & (f <= band_hz[1]) & (S > 0)
    lf, lS = f[sel], np.log(S[sel])
    best = None
    grid = np.exp(np.linspace(np.log(0.05), np.log(10.0), 200))
    corners = np.exp(np.linspace(np.log(0.1), np.log(20.0), 80)) if corner else np.zeros(1)
    for fc in corners:
        for fn in grid:
            shape = np.log(hand_psd(lf, fn, damping, 1.0, fc))
            lq = float(np.mean(lS - shape))  # the best q for this shape, in closed form
            cost = float(np.sum((lS - shape - lq) ** 2))
            if best is None or cost < best[0]:
                best = (cost, fn, np.exp(lq), fc)
    _, fn, q, fc = best
    if corner and fc >= corners[-1]:
        return fit_oscillator(t_s, acc_ned_mps2, moving, band_hz, damping, segment_s, corner=False)
    if fn <= grid[0] or fn >= grid[-1]:
        # no roll-off inside the searched range: the PSD has no oscillator shape to fit
        raise ProcessingError(f"motion model: the acceleration PSD in {band_hz[0]}-{band_hz[1]} Hz has no "
                              "hand-motion shape (fit at the edge of 0.05-10 Hz)")
    vp, _ = displacement_var(fn, damping, q, fc)
    return OscillatorFit(freq_hz=float(fn), damping=damping, sd_m=float(np.sqrt(vp)), q_m2ps3=float(q),
                         moving_fraction=frac, band_hz=(float(band_hz[0]), float(band_hz[1])), corner_hz=float(fc))
