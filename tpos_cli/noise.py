"""IMU noise identification from a static log by the overlapping Allan deviation (IEEE Std 952-1997, Annex C).

Per axis: σ(τ) from the cumulative integral θ (Eq. C.3, overlapping form). Read-offs (Annex C.1):
random walk N = σ at τ = 1 s on the τ^-1/2 line (fitted where the log-log slope is near -1/2);
bias instability B = min σ / 0.664 (flicker floor, Eq. C.9); rate random walk K = σ at τ = 3 s on
the τ^+1/2 line (Eq. C.12), NaN when the log is too short to show it. Contract keys: white noise
SD per sample = N √f_s (`gyro_noise_dps`, `acc_noise_mg`); `gyro_bias_dph`/`acc_bias_mg` are set to
the bias instability: the in-run figure a static log can show (a turn-on bias needs a calibration).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.alignment import static_mask
from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.timebase import true_runs


@dataclass(frozen=True)
class AllanAxis:
    tau_s: np.ndarray
    adev: np.ndarray
    random_walk: float  # units/√Hz (rate units × √s)
    bias_instability: float  # rate units
    rate_random_walk: float  # rate units/√s, NaN if not visible


def allan_deviation(y, rate_hz: float, n_tau: int = 60):
    """(tau_s, adev) of rate samples y (N,) by the overlapping estimator, log-spaced cluster sizes."""
    y = np.asarray(y, float)
    n = y.size
    theta = np.concatenate([[0.0], np.cumsum(y)]) / rate_hz
    m = np.unique(np.logspace(0, np.log10(max(1, (n - 1) // 3)), n_tau).astype(int))
    tau = m / rate_hz
    adev = np.empty(m.size)
    for i, mi in enumerate(m):
        d = theta[2 * mi :] - 2 * theta[mi:-mi] + theta[: -2 * mi]
        adev[i] = np.sqrt(np.mean(d * d) / (2.0 * tau[i] ** 2))
    return tau, adev


def analyse_axis(y, rate_hz: float) -> AllanAxis:
    tau, adev = allan_deviation(y, rate_hz)
    lt, la = np.log10(tau), np.log10(adev)
    slope = np.gradient(la, lt)
    white = np.abs(slope + 0.5) < 0.15
    if not white.any():
        white = np.arange(tau.size) < max(3, tau.size // 10)
    N = float(10 ** np.median(la[white] + 0.5 * lt[white]))  # σ = N / √τ
    B = float(adev.min() / 0.664)
    rrw = (np.abs(slope - 0.5) < 0.15) & (tau > tau[np.argmin(adev)])
    K = float(10 ** np.median(la[rrw] - 0.5 * lt[rrw] + 0.5 * np.log10(3.0))) if rrw.sum() >= 3 else float("nan")
    return AllanAxis(tau, adev, N, B, K)


@dataclass(frozen=True)
class NoiseFigures:
    gyro: tuple[AllanAxis, AllanAxis, AllanAxis]  # rad/s
    acc: tuple[AllanAxis, AllanAxis, AllanAxis]  # m/s²
    rate_hz: float

    def toml_keys(self) -> dict:
        """The contract's `[imu]` noise keys (worst axis), plus the Allan figures (Extensions)."""
        f = self.rate_hz
        g_n = max(a.random_walk for a in self.gyro) * np.sqrt(f)
        a_n = max(a.random_walk for a in self.acc) * np.sqrt(f)
        out = {
            "gyro_noise_dps": float(np.degrees(g_n)),
            "gyro_bias_dph": float(np.degrees(max(a.bias_instability for a in self.gyro)) * 3600.0),
            "acc_noise_mg": float(a_n / G0_MPS2 * 1e3),
            "acc_bias_mg": float(max(a.bias_instability for a in self.acc) / G0_MPS2 * 1e3),
            "gyro_arw_dprh": float(np.degrees(max(a.random_walk for a in self.gyro)) * 60.0),  # deg/√h
            "acc_vrw_mpsrh": float(max(a.random_walk for a in self.acc) * 60.0),  # m/s/√h
        }
        k_g = [a.rate_random_walk for a in self.gyro if np.isfinite(a.rate_random_walk)]
        if k_g:
            out["gyro_rrw_dphrh"] = float(np.degrees(max(k_g)) * 3600.0 * 60.0)  # deg/h/√h
        return {k: float(f"{v:.4g}") for k, v in out.items()}


def identify_noise(t_s, gyro_b_rps, acc_b_mps2) -> NoiseFigures:
    """Allan analysis of a static stretch (N, 3) per axis. Needs at least 100 s."""
    t = np.asarray(t_s, float)
    if t.size < 100 or t[-1] - t[0] < 100.0:
        raise InvalidInputError(f"noise: the static window is {t[-1] - t[0]:.0f} s long; Allan analysis needs at least 100 s")
    rate = (t.size - 1) / (t[-1] - t[0])
    g = tuple(analyse_axis(gyro_b_rps[:, i], rate) for i in range(3))
    a = tuple(analyse_axis(acc_b_mps2[:, i], rate) for i in range(3))
    return NoiseFigures(g, a, float(rate))


MIN_STATIC_S = 100.0  # shortest static stretch worth an Allan analysis (τ up to ~30 s)


def longest_static_window(t_s, gyro_b_rps, acc_b_mps2) -> tuple[int, int]:
    """Sample indices [i0, i1) of the longest contiguous stretch at rest (`alignment.static_mask`)."""
    still = static_mask(np.asarray(t_s, float), gyro_b_rps, acc_b_mps2)
    a, b = true_runs(still)
    if a.size == 0:
        return 0, 0
    k = int(np.argmax(np.asarray(t_s)[b - 1] - np.asarray(t_s)[a]))
    return int(a[k]), int(b[k])


def session_noise(session) -> tuple[NoiseFigures, tuple[float, float]] | None:
    """Allan figures of the session's longest static stretch (logger clock window), or None if it is
    shorter than MIN_STATIC_S: what the PDF report shows when a run's log is static enough."""
    imu = session.imu
    i0, i1 = longest_static_window(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2)
    if i1 - i0 < 100 or imu.t_s[i1 - 1] - imu.t_s[i0] < MIN_STATIC_S:
        return None
    sl = slice(i0, i1)
    nf = identify_noise(imu.t_s[sl], imu.gyro_b_rps[sl], imu.acc_b_mps2[sl])
    return nf, (float(imu.t_s[i0] + session.t0_s), float(imu.t_s[i1 - 1] + session.t0_s))
