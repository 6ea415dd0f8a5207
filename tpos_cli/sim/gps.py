"""GPS fixes from the truth: position and velocity with white noise, outages as missing rows."""

from __future__ import annotations

import dataclasses

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames import earth
from tpos_cli.sim.result import SimGps, SimTruth
from tpos_cli.sim.rtk import RtkModel, rtk_errors


def outage_mask(t_s, outages_s) -> np.ndarray:
    """True where t lies in one of the [start, start + length) windows of `outages_s` (K, 2)."""
    t = np.asarray(t_s, dtype=float)
    m = np.zeros(t.shape, dtype=bool)
    for start, length in np.asarray(outages_s, dtype=float).reshape(-1, 2):
        m |= (t >= start) & (t < start + length)
    return m


def simulate_gps(
    truth: SimTruth,
    imu_rate_hz: float,
    *,
    rate_hz: float = 1.0,
    sigma_h_m: float = 1.5,
    sigma_v_m: float = 2.5,
    sigma_vel_mps: float = 0.05,
    outages_s=((40.0, 30.0),),
    rng: np.random.Generator,
    correlated_sigma_neu_m=(0.0, 0.0, 0.0),
    correlated_tau_s: float = 30.0,
    rtk: RtkModel | None = None,
) -> SimGps:
    """Sample the truth at `rate_hz` (a divisor of the IMU rate) and add white noise.

    Position noise is drawn in north/east/up metres (SD `sigma_h_m`, `sigma_h_m`, `sigma_v_m`) and
    mapped to lat/lon/h with the radii of curvature; velocity noise is `sigma_vel_mps` per NED axis.
    Noise is drawn for every epoch before the outage rows are removed, so outages do not change the
    noise of the other epochs. Every kept row has fix = 2 (SBAS/WAAS differential).
    `correlated_sigma_neu_m` > 0 adds a time-correlated position error on top (first-order
    Gauss-Markov per axis, stationary SD as given, time constant `correlated_tau_s`, drawn exactly
    at the epochs: b_k = a b_(k-1) + sqrt(1 - a^2) sigma w_k, a = exp(-dt / tau)), drawn after
    the white noise so that the white draws of a seed do not change; the `sigma_*` columns still
    give the white SDs only (a receiver does not know its multipath).
    `rtk` (default None: off) makes the fixes RTK-like (`rtk.py`): the white position noise is
    drawn at `rtk.floor_sigma_neu_m` instead of the `sigma_h_m`/`sigma_v_m` figures, float stretches
    and multipath steps add their offsets, and the `sigma_*` columns give the stated SDs (the floor,
    raised in float stretches). Its draws come after all others, so the white draws of a seed and
    the draws of every run without it do not change. fix stays 2: the contract has no RTK flag.
    """
    stride = imu_rate_hz / rate_hz
    if rate_hz <= 0 or abs(stride - round(stride)) > 1e-9 or round(stride) < 1:
        raise InvalidInputError(f"gps rate: {rate_hz} Hz must divide the IMU rate {imu_rate_hz} Hz")
    if min(sigma_h_m, sigma_v_m, sigma_vel_mps) < 0:
        raise InvalidInputError("gps sigmas must be >= 0")
    idx = np.arange(0, truth.t_s.size, int(round(stride)))
    n = idx.size
    sig = np.array([sigma_h_m, sigma_h_m, sigma_v_m]) if rtk is None else np.asarray(rtk.floor_sigma_neu_m, dtype=float)
    e_neu = rng.standard_normal((n, 3)) * sig
    e_vel = rng.standard_normal((n, 3)) * sigma_vel_mps
    nsat = rng.integers(7, 13, size=n)
    csig = np.asarray(correlated_sigma_neu_m, dtype=float) * np.ones(3)
    if np.any(csig < 0) or correlated_tau_s <= 0:
        raise InvalidInputError("gps correlated error: SDs must be >= 0 and the time constant > 0")
    if np.any(csig > 0):
        a = np.exp(-stride / imu_rate_hz / correlated_tau_s)
        w = rng.standard_normal((n, 3)) * csig
        b = np.empty((n, 3))
        b[0] = w[0]  # stationary start
        for k in range(1, n):
            b[k] = a * b[k - 1] + np.sqrt(1.0 - a * a) * w[k]
        e_neu = e_neu + b
    sigma_neu = np.tile(sig, (n, 1))
    rtk_err = None
    if rtk is not None:
        rtk_err = rtk_errors(truth.t_s[idx], rtk, rng)
        e_neu, sigma_neu = e_neu + rtk_err.offset_neu_m, rtk_err.sigma_neu_m
    keep = ~outage_mask(truth.t_s[idx], outages_s)
    idx, e_neu, e_vel, nsat, sigma_neu = idx[keep], e_neu[keep], e_vel[keep], nsat[keep], sigma_neu[keep]
    if rtk_err is not None:
        rtk_err = dataclasses.replace(rtk_err, regime=rtk_err.regime[keep], sigma_neu_m=sigma_neu,
                                      offset_neu_m=rtk_err.offset_neu_m[keep])

    lla_true = truth.lla[idx]
    lat = np.radians(lla_true[:, 0])
    h = lla_true[:, 2]
    lla = lla_true.copy()
    lla[:, 0] += np.degrees(e_neu[:, 0] / (earth.meridian_radius_m(lat) + h))
    lla[:, 1] += np.degrees(e_neu[:, 1] / ((earth.transverse_radius_m(lat) + h) * np.cos(lat)))
    lla[:, 2] += e_neu[:, 2]
    vel_true = truth.vel_ned_mps[idx]
    m = idx.size
    return SimGps(
        t_s=truth.t_s[idx].copy(),
        lla=lla,
        vel_ned_mps=vel_true + e_vel,
        sigma_neu_m=sigma_neu,
        fix=np.full(m, 2, dtype=np.int64),
        nsat=nsat.astype(np.int64),
        hdop=np.full(m, max(sig[0], 0.5) / 1.5),  # HDOP x ~1.5 m UERE gives the horizontal SD
        lla_true=lla_true.copy(),
        vel_true_ned_mps=vel_true.copy(),
        sigma_vel_mps=float(sigma_vel_mps),
        rtk=rtk_err,
    )
