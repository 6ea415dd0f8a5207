"""Chain `target_fkf`: static-observer target positioning (papers 000 and 001).

Stages (`run`): magnetometer delay -> alignment at both ends of the log (stationary windows, Eq. 6,
8/9 with declination) -> IMU noise figures (`imu_noise`) -> magnetic survey (`attitude.magfield`:
Earth field, body-fixed offsets removed, room disturbances masked) -> beam geometry (wall normal)
-> local filters `gyro`, `lf1` (acc/mag), `lf2` (three LRs), each smoothed by independent forward and
backward runs (`attitude.smoother`) -> fault detection -> federated master `fkf` (Eq. 27 with the
detector's weights) and `fkf_raw` (the paper's plain fusion) -> shots (given or detected) -> target
positions for every solution (Eq. 2-4, 29) -> reference-point calibration `fkf_cal` (paper 001
Eq. 31-38) -> pairwise slant range / height difference (paper 001 Eq. 15-16).
A target session without ranges (attitude-only MARG log) yields `gyro`, `lf1`, `fkf` only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from scipy.stats import chi2

from tpos_cli import alignment as al
from tpos_cli import magnetic, targeting
from tpos_cli.attitude import _kernels as K
from tpos_cli.attitude import faults, magfield, master, motion, sensor_lag
from tpos_cli.attitude.local import (
    AttitudeSolution,
    FilterNoise,
    FilterSetup,
    add_heading_variance,
    honest_covariance,
    range_differences,
    run_full,
    run_paper8,
)
from tpos_cli.attitude.smoother import smooth_full
from tpos_cli.chains.context import ChainOutput, RunContext
from tpos_cli.config import TargetFkfParams
from tpos_cli.errors import InvalidInputError, ProcessingError
from tpos_cli.frames import earth, geodetic
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.rotation import dcm_to_euler, dcm_to_rotvec, euler_error_map, euler_to_dcm, rotvec_to_dcm
from tpos_cli.imu_noise import resolve_imu_noise
from tpos_cli.quality import unresolved_offset_text, unsupported_heading_text
from tpos_cli.session import Session
from tpos_cli.timebase import true_runs
from tpos_cli.trajectory import trajectory_table

#: attitude SD (rad, each axis) of the backward run's prior when it starts from the start alignment carried
#: by the gyro (`_align_at_end`): uninformative beside any alignment (0.1 rad is 5.7 deg; a still window
#: levels to ~0.01 deg), small enough that the error-state linearization holds
BACKWARD_CARRIED_SD_RAD = 0.1
#: share of the samples on which neither LF1 run used the field above which its heading counts as unsupported
#: ("most of the log": `unsupported_heading`)
HEADING_UNSUPPORTED_SHARE = 0.5


@dataclass(frozen=True)
class End:
    """Alignment at one end of the log: the coarse alignment (`alignment.Alignment`) in its still
    window, the gravity magnitude there (m/s^2), the SD of the gyro bias measured in it (rad/s) and the
    attitude at which the accelerometer levelled it (`levelling_map`; None: align.C_nb)."""

    align: al.Alignment
    window: al.StaticWindow
    gravity_mps2: float
    bias_sd_rps: float
    level_C: np.ndarray | None = None

    def levelled_at(self) -> np.ndarray:
        return self.align.C_nb if self.level_C is None else self.level_C


@dataclass(frozen=True)
class Beams:
    """Range differences on the IMU samples (N,2) or None, the wall's NED normal, its azimuth variance,
    the share of it that the accelerometer bias explains (carried by the filters' sensitivity) and the
    share that is the start alignment's heading error (`local.add_heading_variance`)."""

    rdiff: np.ndarray | None
    wall_n: np.ndarray
    wall_var_rad2: float
    wall_lev_var_rad2: float = 0.0
    wall_align_var_rad2: float = 0.0


@dataclass(frozen=True)
class Setups:
    """Forward and backward filter set-ups (each from its own end of the log), and the gyro-only one."""

    forward: FilterSetup
    backward: FilterSetup
    gyro: FilterSetup


def static_noise(imu, win) -> dict:
    """Per-sample white-noise SDs (gyro dps, acc mg, mag uT; RMS over axes) measured in a still window.

    A hand-held device trembles a little, so these are upper bounds of the sensor noise: safe
    figures for the filters. None where the window is too short (< 50 samples) or no magnetometer.
    """
    sl = slice(win.i0, win.i1)
    if win.i1 - win.i0 < 50:
        return {"gyro_dps": None, "acc_mg": None, "mag_ut": None}

    def sd(a):
        a = np.asarray(a[sl], dtype=float)
        a = a[np.all(np.isfinite(a), axis=1)]
        return float(np.sqrt(np.mean(np.var(a, axis=0)))) if a.shape[0] >= 50 else None

    g = sd(imu.gyro_b_rps)
    a = sd(imu.acc_b_mps2)
    m = sd(imu.mag_b_ut) if imu.mag_b_ut is not None else None
    return {"gyro_dps": None if g is None else float(np.degrees(g)), "acc_mg": None if a is None else a / G0_MPS2 * 1e3,
            "mag_ut": m}


def observer_position(session: Session) -> tuple[np.ndarray, str]:
    """`[observer]` if given, else the mean of valid GPS fixes; InvalidInputError otherwise."""
    if session.meta.observer_lla is not None:
        return np.asarray(session.meta.observer_lla, dtype=float), "session.toml"
    g = session.gps
    if g is not None and np.any(g.valid):
        return np.mean(g.lla[g.valid], axis=0), "GPS mean"
    raise InvalidInputError("session.toml: the target chain needs [observer] lat/lon/h or GPS fixes (gps.*) to place the observer")


def beam_normal_b(rdiff_m, b12, b13) -> np.ndarray:
    """(..., 3) body-frame (unnormalized) wall normal from (d1-d2, d1-d3) (..., 2):
    n_b ~ (1, -(d1-d2)/b12, (d1-d3)/b13) solves d1 - d_i = n.C o_i / n.C e_x."""
    r = np.asarray(rdiff_m, dtype=float)
    return np.stack([np.ones(r.shape[:-1]), -r[..., 0] / b12, r[..., 1] / b13], axis=-1)


def wall_normal_ned(C_nb, n_b) -> np.ndarray:
    """Horizontal unit normal (NED) of the wall from its body-frame normal `n_b` (`beam_normal_b`) at attitude
    C_nb; buildings' walls are vertical, so the NED normal is projected onto the horizontal."""
    n = C_nb @ n_b
    n[2] = 0.0
    return n / np.linalg.norm(n)


def detect_shots(t_s, gyro, range_m_on_imu, start_i, min_s, gyro_tol_rps):
    """(starts, ends) s of windows where the device is still and LR1 returns, after `start_i`."""
    still = al.static_mask(t_s, gyro, np.zeros_like(gyro), gyro_tol_rps=gyro_tol_rps, acc_sd_tol_mps2=np.inf)
    ok = still & np.isfinite(range_m_on_imu)
    ok[:start_i] = False
    s, e = true_runs(ok)
    keep = (t_s[np.maximum(e - 1, 0)] - t_s[s]) >= min_s
    return t_s[s[keep]], t_s[e[keep] - 1]


def _window_attitude(sol: AttitudeSolution, sl: slice):
    """Mean rotation and mean covariance of a solution over a window (the shot average)."""
    C = sol.C_nb[sl]
    ref = C[C.shape[0] // 2]
    d = dcm_to_rotvec(C @ ref.T)
    Cm = rotvec_to_dcm(d.mean(axis=0)) @ ref
    return Cm, sol.P_att[sl].mean(axis=0)


def _paper8_obs(session, p, t, al_res, decl, rdiff, noise, wall_yaw):
    """Per-sample (pitch, yaw) of Eq. 9 (acc/mag) and Eq. 15 (LRs) for the paper8 model."""
    n = t.size
    acc = session.imu.acc_b_mps2
    g = np.linalg.norm(acc, axis=1)
    _, pitch = al.level_rad(acc)
    o1 = np.full((n, 2), np.nan)
    v1 = np.zeros((n, 2))
    gref = np.median(g[al_res.window.i0:al_res.window.i1])
    still = np.abs(g - gref) < p.acc_static_tol_mps2
    if session.imu.mag_b_ut is not None:
        yaw = al.magnetic_yaw_rad(session.imu.mag_b_ut, 0.0, pitch, decl)  # Eq. 9 (zero roll)
        o1[still, 0] = pitch[still]
        o1[still, 1] = yaw[still]
        h = al_res.mag_norm_ut * np.cos(al_res.mag_dip_rad)
        v1[:, 0] = (noise.acc_noise_mps2 / gref) ** 2
        v1[:, 1] = (noise.mag_noise_ut / h) ** 2 + v1[:, 0] * np.tan(al_res.mag_dip_rad) ** 2
    o2 = np.full((n, 2), np.nan)
    v2 = np.zeros((n, 2))
    if rdiff is not None:
        rf = session.meta.rangefinders
        th = np.arctan(rdiff[:, 1] / rf.baseline_13_m)  # Eq. 10, exact at zero roll
        cth = np.cos(th) if p.lr_yaw_form == "exact" else 1.0
        dpsi = np.arctan(rdiff[:, 0] * cth / rf.baseline_12_m)
        o2[:, 0] = th
        o2[:, 1] = wall_yaw + dpsi  # Eq. 14-15
        v2[:, 0] = 2 * noise.range_sigma_m**2 / rf.baseline_13_m**2
        v2[:, 1] = 2 * noise.range_sigma_m**2 / rf.baseline_12_m**2
    return o1, v1, o2, v2


def remove_mag_lag(session: Session, p: TargetFkfParams, ctx: RunContext, summary: dict) -> Session:
    """The session with its magnetometer read `lag` later (`attitude.sensor_lag`), when the log shows one."""
    imu = session.imu
    if imu.mag_b_ut is None or not p.mag_lag_from_log:
        return session
    with ctx.stage("magnetometer delay"):
        lag = sensor_lag.estimate_mag_lag(imu.t_s, imu.gyro_b_rps, imu.mag_b_ut, max_lag_s=p.mag_lag_max_s)
        summary["mag_lag"] = {"lag_s": lag.lag_s, "residual_uts": lag.rms_uts, "residual_zero_lag_uts": lag.rms_zero_uts,
                              "turning_samples": lag.n_used, "note": lag.reason}
    if lag.lag_s == 0.0:
        return session
    # every consumer (alignment, survey, LF1, paper8 observations) sees the delay-free magnetometer
    return replace(session, imu=replace(imu, mag_b_ut=sensor_lag.advance(imu.t_s, imu.mag_b_ut, lag.lag_s)))


def _carry(C, bias, t, gyro, i_from, i_to, w_ie_ned):
    """Attitude C at sample i_from carried to sample i_to by the gyro alone: bias and Earth rate removed
    (Eq. 19, omega_nb = omega_ib - b - C^T omega_ie; the Earth turns a still device's heading by
    15 deg/h sin(lat))."""
    step = 1 if i_to >= i_from else -1
    for k in range(i_from + step, i_to + step, step) if i_to != i_from else ():
        kk = k if step > 0 else k + 1  # the rate of row kk covers (t_{kk-1}, t_kk]
        w = (gyro[kk] - bias - C.T @ w_ie_ned) * (t[kk] - t[kk - 1]) * step
        C = C @ rotvec_to_dcm(w)
    return C


def align_end(session: Session, p: TargetFkfParams, lat: float, decl: float, noise_mps2_ut, *, at_end: bool) -> End:
    """Coarse alignment (Eq. 6, 8) in the first (or, `at_end`, the last) still window of the log (white noise
    `noise_mps2_ut` = (acc m/s^2, mag uT, gyro rad/s) per sample and the accelerometer bias's random walk
    m/s^2/sqrt(s)), levelled at its edge sample, carried
    by the gyro to the first (last) sample when the window does not reach it. Raises ProcessingError
    when the log has no such window."""
    imu = session.imu
    t, g, a, m = imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, imu.mag_b_ut
    n = t.size
    kw = dict(min_duration_s=p.static_min_s, max_duration_s=p.static_max_s, gyro_tol_rps=np.radians(p.static_gyro_tol_dps),
              acc_sd_tol_mps2=p.static_acc_sd_tol_mps2, mag_step_tol_ut=p.align_mag_step_tol_ut)
    if at_end:
        w = al.detect_static_window(-t[::-1], g[::-1], a[::-1], None if m is None else m[::-1], **kw)
        win = al.StaticWindow(n - w.i1, n - w.i0, w.end_reason)
    else:
        win = al.detect_static_window(t, g, a, m, **kw)
    edge = n - 1 if at_end else 0
    ref = win.i1 - 1 if at_end else win.i0
    # the attitude at the window's edge sample, not the window's mean attitude (a hand sways)
    A = al.coarse_alignment(t, g, a, m, win, declination_rad=decl, lat_rad=lat, acc_noise_mps2=noise_mps2_ut[0],
                            mag_noise_ut=noise_mps2_ut[1], ref=ref, gyro_noise_rps=noise_mps2_ut[2],
                            acc_bias_rw_mps2_rts=noise_mps2_ut[3])
    sg = float(np.sqrt(np.mean(np.var(g[win.i0:win.i1], axis=0))))
    C_level = A.C_nb
    if ref != edge:
        A = replace(A, C_nb=_carry(A.C_nb, A.gyro_bias_rps, t, g, ref, edge, earth.earth_rate_ned_rps(lat)))
    grav = float(np.linalg.norm(np.mean(a[win.i0:win.i1], axis=0)))
    return End(A, win, grav, sg / np.sqrt(max(win.i1 - win.i0, 1)), C_level)


def imu_figures(session: Session, p: TargetFkfParams, start: End, summary: dict) -> FilterNoise:
    """Filter noise from the IMU figures (`imu_noise`: pipeline > session > measured in the still window > default)."""
    measured = static_noise(session.imu, start.window) if p.noise_from_static else {}
    fig = resolve_imu_noise(p, session.meta.imu_noise, measured={
        "gyro_noise_dps": measured.get("gyro_dps"), "acc_noise_mg": measured.get("acc_mg"),
        "mag_noise_ut": measured.get("mag_ut")}, measured_label="measured in the still window",
        keys=("gyro_noise_dps", "acc_noise_mg", "gyro_bias_dph", "acc_bias_mg", "mag_noise_ut"))
    summary["imu_noise"] = fig.summary()
    rf = session.meta.rangefinders
    return FilterNoise(
        gyro_noise_rps=np.radians(fig["gyro_noise_dps"]), gyro_bias_rps=np.radians(max(fig["gyro_bias_dph"], 1e-3) / 3600.0),
        gyro_bias_rw_rps_rts=np.radians(p.gyro_bias_rw_dph_per_rth / 3600.0 / 60.0),
        acc_noise_mps2=fig["acc_noise_mg"] * 1e-3 * G0_MPS2, mag_noise_ut=fig["mag_noise_ut"],
        range_sigma_m=rf.sigma_m if (rf is not None and rf.sigma_m is not None) else p.range_sigma_m,
        gyro_scale_sd=p.gyro_scale_sd_ppm * 1e-6, gyro_scale_const_sd=p.gyro_scale_const_ppm * 1e-6,
        acc_bias_mps2=fig["acc_bias_mg"] * 1e-3 * G0_MPS2,
        acc_bias_rw_mps2_rts=p.acc_bias_rw_mg_per_rts * 1e-3 * G0_MPS2)


def survey_field(session: Session, p: TargetFkfParams, start: End, obs_lla, noise: FilterNoise, ctx: RunContext,
                 summary: dict):
    """The log's magnetic survey (`attitude.magfield`), or None without magnetometer or with `mag_survey` off;
    `noise.mag_noise_ut` (white) is what the survey's field departure (`magfield.field_sd_ut`) is measured beyond."""
    imu = session.imu
    if imu.mag_b_ut is None or not p.mag_survey:
        return None
    with ctx.stage("magnetic survey"):
        fs = magfield.survey(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, imu.mag_b_ut, start.align.gyro_bias_rps,
                             prior=_igrf_norm_dip(session, obs_lla), white_ut=noise.mag_noise_ut)
    summary["magnetic_survey"] = fs.summary()
    summary["imu_noise"]["mag_update_sd_ut"] = {"value": round(mag_update_sd_ut(noise, fs), 6),
                                                "source": "hypot(mag_noise_ut, magnetic_survey.field_sd_ut)"}
    return fs


def mag_update_sd_ut(noise: FilterNoise, field) -> float:
    """Per-axis SD (uT) of the magnetometer update's error against the one Earth vector: the white noise and,
    with a survey, the field's departure from that vector (`magfield.field_sd_ut`), independent, so in quadrature."""
    return float(np.hypot(noise.mag_noise_ut, field.field_sd_ut if field is not None else 0.0))


def _igrf_norm_dip(session: Session, obs_lla):
    """(norm uT, dip rad) of the IGRF field at the observer on the log's date, or None without a date."""
    if session.meta.start_utc is None:
        return None
    b = magnetic.field_ned_ut(obs_lla, session.meta.start_utc)
    return float(np.linalg.norm(b)), float(np.arctan2(b[2], np.hypot(b[0], b[1])))


def beam_geometry(session: Session, start: End, noise: FilterNoise, yaw_var_rad2: float, ctx: RunContext,
                  summary: dict) -> Beams:
    """Range differences and the wall normal from the alignment window (LF2 needs three-beam returns there);
    `yaw_var_rad2` the variance of the alignment's heading (the forward set-up's prior)."""
    A, win = start.align, start.window
    wall_n = np.array([np.cos(A.yaw_rad), np.sin(A.yaw_rad), 0.0])
    rf = session.meta.rangefinders
    if session.ranges is None or rf is None:
        if session.ranges is None:
            ctx.warn("ranges: none in this session; LF2 needs the three rangefinders, so only gyro/lf1/fkf are produced")
        return Beams(None, wall_n, 0.0)
    rdiff = range_differences(session.imu.t_s, session.ranges.t_s, session.ranges.range_m)
    in_win = rdiff[win.i0:win.i1]
    good = np.all(np.isfinite(in_win), axis=1)
    if good.sum() < 3:
        ctx.warn("ranges: fewer than 3 three-beam returns during the alignment window; LF2 is not run")
        return Beams(None, wall_n, 0.0)
    # the beams' body-frame normal at each return, turned into the body frame at the sample the start
    # alignment levelled (the window's first, `align_end`; `alignment.held_at`: a swaying hand turns the
    # beams as it turns the accelerometer), at that attitude
    n_b = np.full((rdiff.shape[0], 3), np.nan)
    n_b[win.i0:win.i1][good] = beam_normal_b(in_win[good], rf.baseline_12_m, rf.baseline_13_m)
    held, _, _ = al.held_at(session.imu.t_s, session.imu.gyro_b_rps, [session.imu.acc_b_mps2, n_b], win, win.i0,
                            noise.gyro_noise_rps, noise.acc_noise_mps2, noise.acc_bias_rw_mps2_rts)
    wall_n = wall_normal_ned(start.levelled_at(), held[1])
    # the wall azimuth inherits the alignment's yaw error plus the beam-difference noise
    # (d1 - d2 over b12 at the K returns); LF2's heading carries it as a constant bias
    var = float(yaw_var_rad2 + 2.0 * noise.range_sigma_m**2 / rf.baseline_12_m**2 / good.sum())
    summary["wall_azimuth_deg"] = float(np.degrees(np.arctan2(wall_n[1], wall_n[0])) % 360.0)
    summary["wall_azimuth_sigma_deg"] = float(np.degrees(np.sqrt(var)))
    return Beams(rdiff, wall_n, var, wall_align_var_rad2=float(yaw_var_rad2))


def _initial_covariance(end: End, noise: FilterNoise, m_ref_n, mag_w):
    """9x9 prior of [phi, gyro bias, acc bias] at one end: the levelling error is the alignment's noise
    and the accelerometer bias an independent prior. (The bias seen as tilt, phi_h = J b_a with
    J = [[C_E], [-C_N]] / g, as a correlated prior is exact on paper but measured worse on the real
    hand-held logs: BROAD mean tpos/VQF 1.36 against 0.70, so the filters learn that coupling from the
    motion.) The heading adds the coupling of the bias through the dip and, with a survey, the field's
    unexplained deviation from the Earth field in the window; the gyro bias is the window mean (spec
    prior and noise / sqrt(N) combined)."""
    A = end.align
    C = A.C_nb
    sb = noise.acc_bias_mps2
    P = np.zeros((9, 9))
    P[0:2, 0:2] = np.eye(2) * A.sigma_rpy_rad[0] ** 2
    P[6:9, 6:9] = np.eye(3) * sb**2
    var_yaw = A.sigma_rpy_rad[2] ** 2
    if np.isfinite(A.mag_dip_rad):
        var_yaw += (sb / end.gravity_mps2 * np.tan(A.mag_dip_rad)) ** 2
    if m_ref_n is not None and mag_w is not None:
        dv = C @ mag_w - m_ref_n
        dv[1] = 0.0  # the east component is the heading itself
        var_yaw += float(dv @ dv) / float(m_ref_n[0] ** 2 + m_ref_n[1] ** 2)
    P[2, 2] = var_yaw
    var_b = 1.0 / (1.0 / noise.gyro_bias_rps**2 + 1.0 / max(end.bias_sd_rps, 1e-12) ** 2)
    P[3:6, 3:6] = np.eye(3) * var_b
    return P


def with_wall(setups: Setups, beams: Beams) -> Setups:
    """`setups` with the wall normal of the beam geometry."""
    return Setups(*(replace(s, wall_n_ned=beams.wall_n) for s in (setups.forward, setups.backward, setups.gyro)))


def filter_setups(session: Session, p: TargetFkfParams, obs_lla, decl, ends, noise: FilterNoise, field) -> Setups:
    """Forward and backward set-ups, each from its own end of the log (no estimate of one run enters the other)."""
    rf = session.meta.rangefinders
    start, end = ends
    if field is not None:
        mag_ref = (field.norm_ut, field.dip_rad)
    elif np.isfinite(start.align.mag_norm_ut):
        mag_ref = (start.align.mag_norm_ut, start.align.mag_dip_rad)
    else:
        mag_ref = (0.0, 0.0)
    m_ref_n = magfield.reference_field_ned(*mag_ref, decl) if mag_ref[0] > 0 else None

    def window_mag(e: End):
        if field is None:
            return None
        mw = field.mag_b_ut[e.window.i0:e.window.i1]
        ok = np.all(np.isfinite(mw), axis=1)
        return mw[ok].mean(axis=0) if ok.any() else np.nanmean(session.imu.mag_b_ut[e.window.i0:e.window.i1], axis=0)

    # the filters' magnetometer R holds the field's departure from m_ref beside the white noise (the kernel's r_mag);
    # the NIS gate (a disturbance that lasts: the 1 s mean NIS over mag_nis_ratio) keeps its threshold on the
    # innovation's power where the white noise set it, so a wider R does not let a disturbance through (BROAD 26,
    # phone vibration: with the ratio on the wider R the gate refused 2370 samples instead of 32047 and the
    # heading followed the disturbance, tpos/VQF .72 -> 1.05)
    f_noise = replace(noise, mag_noise_ut=mag_update_sd_ut(noise, field))
    base = FilterSetup(
        lat_rad=np.radians(obs_lla[0]), h_m=float(obs_lla[2]), C0=start.align.C_nb, bias0_rps=start.align.gyro_bias_rps,
        P0=_initial_covariance(start, noise, m_ref_n, window_mag(start)), noise=f_noise, declination_rad=decl,
        mag_ref=mag_ref, mag_norm_tol_ut=0.0 if (field is not None or mag_ref[0] <= 0) else p.mag_norm_tol_ut,
        mag_dip_tol_rad=np.radians(p.mag_dip_tol_deg), mag_nis_tau_s=p.mag_nis_window_s,
        mag_nis_ratio=p.mag_nis_ratio * (noise.mag_noise_ut / f_noise.mag_noise_ut) ** 2,
        acc_static_tol_mps2=p.acc_static_tol_mps2,
        baseline_12_m=rf.baseline_12_m if rf else 0.2, baseline_13_m=rf.baseline_13_m if rf else 0.2,
        range_gate_chi2=float(chi2.ppf(p.range_gate_probability, 2)), beta=p.beta,
        gyro_static_tol_rps=np.radians(p.gyro_static_tol_dps), motion_sd_mps=p.motion_sd_mps, motion_sd_m=p.motion_sd_m,
        motion_interval_s=p.motion_interval_s, motion_freq_hz=p.motion_freq_hz, motion_damping=p.motion_damping,
        motion_step_s=p.motion_step_s, gyro_err_sd=p.gyro_err_pct * 1e-2, gyro_err_rw_rts=p.gyro_err_rw_ppm_rts * 1e-6,
        gravity_mps2=start.gravity_mps2 if p.gravity_from_static else None)
    back = replace(base, C0=end.align.C_nb, bias0_rps=end.align.gyro_bias_rps,
                   P0=_initial_covariance(end, noise, m_ref_n, window_mag(end)))
    gyro = replace(base, beta=1.0, gyro_err_sd=0.0)
    return Setups(base, back, gyro)


def _fit_motion(setups: Setups, p: TargetFkfParams, t, gyro_sol: AttitudeSolution, acc_b, still, summary, ctx) -> Setups:
    """`setups` with the hand-motion oscillator fitted to the log (attitude.motion); unchanged, with a
    warning, when the log cannot support a fit. The gyro-only attitude suffices: its slow tilt drift
    only reaches frequencies below the fitted band."""
    acc_n = np.einsum("nij,nj->ni", gyro_sol.C_nb, acc_b)
    try:
        fit = motion.fit_oscillator(t, acc_n, ~still, band_hz=tuple(p.motion_fit_band_hz),
                                    acc_noise_mps2=setups.forward.noise.acc_noise_mps2)
    except ProcessingError as e:
        ctx.warn(f"{e}; using the fixed bounded-motion epochs (motion_sd_mps, motion_sd_m)")
        return setups
    summary["motion_fit"] = {"freq_hz": fit.freq_hz, "damping": fit.damping, "sd_m": fit.sd_m, "q_m2ps3": fit.q_m2ps3,
                             "moving_fraction": fit.moving_fraction}
    kw = dict(motion_freq_hz=fit.freq_hz, motion_sd_m=fit.sd_m, motion_damping=fit.damping)
    return replace(setups, forward=replace(setups.forward, **kw), backward=replace(setups.backward, **kw))


def local_filters(session: Session, p: TargetFkfParams, setups: Setups, field, beams: Beams, ends, noise, decl,
                  ctx: RunContext, summary: dict, still, fb_diff_cov=None) -> dict:
    """gyro, lf1 and (with beams) lf2, each smoothed by independent forward and backward runs
    (`still`: the full model's still samples, `still_mask`, None for paper8; `fb_diff_cov`: the runs' expected
    difference their covariances leave out, `smoother.fb_scale`)."""
    imu = session.imu
    t = imu.t_s
    with ctx.stage("local filters"):
        sols = {"gyro": _covariance_parts(run_full("gyro", t, imu.gyro_b_rps, imu.acc_b_mps2, None, None, setups.gyro, 0))}
        mag = field.mag_b_ut if field is not None else imu.mag_b_ut
        if beams.rdiff is None:
            # LF1 alone holds all the information (Eq. 23-24: the shares sum to one over the local filters)
            setups = replace(setups, forward=replace(setups.forward, beta=1.0), backward=replace(setups.backward, beta=1.0))
        if p.model == "full":
            mot = K.USE_MOTION if p.motion_model else 0
            ctx.count("still_samples", int(still.sum()))
            if p.motion_model and p.motion_fit:
                setups = _fit_motion(setups, p, t, sols["gyro"], imu.acc_b_mps2, still, summary, ctx)

            def run(name, mag_, rd, use):
                if p.smooth:
                    return smooth_full(name, t, imu.gyro_b_rps, imu.acc_b_mps2, mag_, rd, setups.forward, use,
                                       setups.backward, still=still, diff_cov=fb_diff_cov)
                return run_full(name, t, imu.gyro_b_rps, imu.acc_b_mps2, mag_, rd, setups.forward, use, still=still)

            # the smoothed biases are read by nothing after the filters (memory: 34 MB an hour at 100 Hz)
            sols["lf1"] = _without_biases(run("lf1", mag, None, K.USE_ACC | mot | (K.USE_MAG if mag is not None else 0)))
            if field is not None and sols["lf1"].mag_ok is not None:
                # the samples the survey masked were not used either
                any_ = sols["lf1"].mag_any
                sols["lf1"] = replace(sols["lf1"], mag_ok=sols["lf1"].mag_ok & ~field.disturbed,
                                      mag_any=None if any_ is None else any_ & ~field.disturbed)
            if beams.rdiff is not None:
                sols["lf2"] = add_heading_variance(_without_biases(run("lf2", None, beams.rdiff, K.USE_RANGE | K.USE_ACC | mot)),
                                                   beams.wall_var_rad2, beams.wall_lev_var_rad2,
                                                   beams.wall_align_var_rad2)
            summary["forward_backward_consistency"] = {
                k: {"tilt": round(s.fb_scale[0], 3), "heading": round(s.fb_scale[1], 3)}
                for k, s in sols.items() if s.fb_scale is not None}
        else:
            wall_yaw = float(np.arctan2(beams.wall_n[1], beams.wall_n[0]))
            o1, v1, o2, v2 = _paper8_obs(session, p, t, ends[0].align, decl, beams.rdiff, noise, wall_yaw)
            sols["lf1"] = run_paper8("lf1", t, imu.gyro_b_rps, o1, v1, replace(setups.forward, P0=setups.forward.P0[0:6, 0:6]))
            if beams.rdiff is not None:
                sols["lf2"] = run_paper8("lf2", t, imu.gyro_b_rps, o2, v2, replace(setups.forward, P0=setups.forward.P0[0:6, 0:6]))
        for k, s in sols.items():
            ctx.count(f"updates_{k}", int(sum(np.isfinite(v).sum() for v in s.nis.values())))
    return sols


def still_mask(session: Session, p: TargetFkfParams) -> np.ndarray:
    """(N,) bool: the IMU samples of the detected still periods (`alignment.static_mask` with the chain's
    tolerances), where the hand model's zero-velocity update applies and its oscillator is not driven."""
    imu = session.imu
    return al.static_mask(imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2, gyro_tol_rps=np.radians(p.static_gyro_tol_dps),
                          acc_sd_tol_mps2=p.static_acc_sd_tol_mps2)


#: d.o.f. of one update of each kind the local filters record (`AttitudeSolution.nis`): gravity (`acc`), the hand
#: model's velocity check (`hand` while the device moves, `hand_still` in the still periods: the kernel records it as
#: the accelerometer's NIS when the motion model is on) and the field vector 3, the two range differences 2, paper 8's
#: (pitch, yaw) 2
NIS_DOF = {"acc": 3, "hand": 3, "hand_still": 3, "mag": 3, "range": 2, "obs": 2}


def innovations_table(sols: dict, range_gate_chi2: float, share: float, still: np.ndarray | None,
                      t0_s: float) -> pd.DataFrame:
    """`innovations.parquet`: one row per update of every local filter run: t, solution (`<filter>_forward` |
    `<filter>_backward`), kind (acc | hand | hand_still | mag | range | obs), nis, dof, accepted, share.

    `still` (N,) bool, the still samples (`still_mask`), when the hand model is on (None: off, the accelerometer's
    updates are gravity's, `acc`). The hand model's updates are split by it: in a still period the oscillator is
    not driven and its bound on the motion (q T) is far above what the accelerometer shows (BROAD: NIS ~0.01 per
    dof over ~40 % of the updates), so one mean over both would hide a misfit while the device moves.

    Only the range differences pass a chi-square gate (`range_gate_chi2`, 2 dof; <= 0: none): the NIS recorded
    of the other kinds are those of the updates made (a field sample the magnitude, dip or windowed-NIS tests
    refused is no update, not a chi-square truncation: `quality.nis_findings` takes them as ungated). `share`:
    the information share beta the runs' prior and process noise were divided by (Eq. 23-24; 1 without beams),
    which lowers their expected NIS (`quality.nis_findings`)."""
    parts = []
    for name, sol in sols.items():
        runs = [("forward", sol.nis)] + ([("backward", sol.nis_backward)] if sol.nis_backward is not None else [])
        for run_name, nis in runs:
            for key, v in nis.items():
                m = np.isfinite(v)
                if not m.any():
                    continue
                if key == "acc" and still is not None:
                    kind = np.where(still[m], "hand_still", "hand")
                    dof = NIS_DOF["hand"]
                else:
                    kind, dof = key, NIS_DOF[key]
                x = np.asarray(v, dtype=float)[m]
                acc = x < range_gate_chi2 if (key == "range" and range_gate_chi2 > 0.0) else np.ones(x.size, bool)
                parts.append(pd.DataFrame({"t": sol.t_s[m] + t0_s, "solution": f"{name}_{run_name}", "kind": kind,
                                           "nis": x, "dof": dof, "accepted": acc, "share": float(share)}))
    if not parts:
        return pd.DataFrame({c: [] for c in ("t", "solution", "kind", "nis", "dof", "accepted", "share")})
    return pd.concat(parts, ignore_index=True)


def _without_biases(sol: AttitudeSolution) -> AttitudeSolution:
    """`sol` without its smoothed gyro and accelerometer biases and their variance, which nothing after the
    local filters reads (34 MB an hour at 100 Hz for lf1)."""
    return replace(sol, bias_rps=None, acc_bias_mps2=None, var_bias=None)


def _covariance_parts(sol: AttitudeSolution) -> AttitudeSolution:
    """`sol` with only what the chain reads of a solution outside the federation (the gyro-only run): its
    attitude, covariance, accelerometer-bias sensitivity and prior share (`with_levelling`) and NIS (counts);
    its gyro-scale sensitivity (N,3,9), biases and alignment sensitivity are freed."""
    return AttitudeSolution(sol.name, sol.t_s, sol.C_nb, sol.P_att, nis=sol.nis, S_ba=sol.S_ba, Q_ba=sol.Q_ba)


def unsupported_heading(sols: dict, mag_b_ut, decl: float, ctx: RunContext, summary: dict) -> dict:
    """`sols` with LF1's heading variance raised when neither of its runs used the field on most samples
    (more than `HEADING_UNSUPPORTED_SHARE`): its heading is then the alignments' (their still windows' field)
    carried by the gyro, and nothing in the motion confirms it. The field samples the runs refused still
    show a heading (`magfield.field_heading_offsets_rad`); their mean square offset from the solution's
    heading is added to its variance: a disturbance at the alignment (a magnet present from the start) and
    a disturbance in the motion look alike here, and either leaves the heading uncertain by that much."""
    lf1 = sols.get("lf1")
    if lf1 is None or lf1.mag_any is None or mag_b_ut is None:
        return sols
    unused = ~lf1.mag_any
    share = float(unused.mean())
    summary["magnetometer_unused_share"] = round(share, 4)
    if share <= HEADING_UNSUPPORTED_SHARE:
        return sols
    off = magfield.field_heading_offsets_rad(lf1.C_nb, mag_b_ut, decl)[unused]
    off = off[np.isfinite(off)]
    if off.size == 0:
        return sols
    var = float(np.mean(off**2))
    summary["unsupported_heading_sigma_deg"] = round(float(np.degrees(np.sqrt(var))), 3)
    ctx.warn(unsupported_heading_text(share, summary["unsupported_heading_sigma_deg"]))  # the verdict's reason too
    return {**sols, "lf1": add_heading_variance(lf1, var)}


def unresolved_offset_heading(sols: dict, field, session: Session, start: End, ctx: RunContext, summary: dict) -> dict:
    """`sols` with LF1's heading variance raised when the start alignment's field may hold a disturbance: the
    survey shows a body-fixed offset that the windows it could not separate, the alignments' still windows
    among them, may still hold (`FieldSurvey.unresolved_offset_ut`), or it masked most of the start
    alignment's window as disturbed (its magnitude is off the Earth field's). The alignments' headings, and
    every field sample that agreed with them, are then off by up to the disturbance's share of the
    horizontal field, |b| / H (a magnet present from the start: its field turns the heading by asin(|b_h| / H)
    at most); |b| is the fitted offsets' median magnitude, at least the window's magnitude gap. Variance
    (min(|b| / H, 1))^2 rad^2."""
    lf1 = sols.get("lf1")
    if lf1 is None or field is None:
        return sols
    b = field.unresolved_offset_ut()
    win = slice(start.window.i0, start.window.i1)
    if b <= 0.0 and np.mean(field.disturbed[win]) > 0.5:
        gap = abs(float(np.nanmedian(np.linalg.norm(session.imu.mag_b_ut[win], axis=1))) - field.norm_ut)
        b = max(field.offset_ut(), gap)
    if b <= 0.0:
        return sols
    h = max(field.norm_ut * np.cos(field.dip_rad), 1e-6)
    var = min(b / h, 1.0) ** 2
    summary["unresolved_offset_ut"] = round(b, 3)
    summary["unresolved_offset_heading_sigma_deg"] = round(float(np.degrees(np.sqrt(var))), 3)
    ctx.warn(unresolved_offset_text(b, summary["unresolved_offset_heading_sigma_deg"]))  # the verdict's reason too
    return {**sols, "lf1": add_heading_variance(lf1, var)}


def federate(sols: dict, p: TargetFkfParams, gate_chi2: float, t, ctx: RunContext, summary: dict,
             acc_bias_var: float = 0.0) -> dict:
    """`fkf` (Eq. 27 with the fault detector's weights) and `fkf_raw` (the paper's plain fusion); `acc_bias_var`
    the accelerometer bias's variance the local filters carry as a sensitivity (the detector's consistency test)."""
    with ctx.stage("federated fusion"):
        locals_ = [sols[k] for k in ("lf1", "lf2") if k in sols]
        if len(locals_) == 2:
            fr = faults.detect(locals_, p.fault, gate_chi2, acc_bias_var)
            # nothing after the federation reads the fused solutions' gyro-scale or alignment sensitivities
            # (their share is in P_att): only what `with_levelling` and targeting read is kept
            sols["fkf"] = _covariance_parts(master.fuse("fkf", locals_, fr.weights() if p.fault_tolerant else None))
            sols["fkf_raw"] = _covariance_parts(master.fuse("fkf_raw", locals_, None, independent=True))
            summary["faults"] = {
                name: {"excluded_fraction": float(1.0 - fr.ok[i].mean()),
                       "excluded_s": float(np.sum(np.diff(t, prepend=t[0])[~fr.ok[i]]))}
                for i, name in enumerate(fr.names)}
            ctx.count("fkf_samples_lf1_excluded", int((~fr.ok[0]).sum()))
            ctx.count("fkf_samples_lf2_excluded", int((~fr.ok[1]).sum()))
        else:
            s1 = locals_[0]
            sols["fkf"] = AttitudeSolution("fkf", s1.t_s, s1.C_nb, s1.P_att, S_ba=s1.S_ba, Q_ba=s1.Q_ba, s_al=s1.s_al,
                                           var_al=s1.var_al, S_gm=s1.S_gm, var_gm=s1.var_gm)
        if sols["lf1"].mag_ok is not None:
            ctx.count("mag_samples_rejected", int((~sols["lf1"].mag_ok).sum()))
            if sols["lf1"].mag_any is not None:
                # neither the forward nor the backward run used the field here: the heading is the alignments'
                # carried by the gyro, its sigma grows with the turns (gyro scale consider) and the bias
                ctx.count("mag_samples_unused", int((~sols["lf1"].mag_any).sum()))
    return sols


def levelling_map(C_nb, gravity_mps2: float, dip_rad: float | None, decl_rad: float) -> np.ndarray:
    """(..., 3, 3) map M = L J from the body-frame accelerometer bias b_a to the NED attitude error it
    leaves in a solution levelled at attitude C_nb: phi = L J b_a (`levelling_consider_cov`)."""
    C = np.asarray(C_nb, dtype=float)
    L = np.zeros((3, 2))
    L[0:2, 0:2] = np.eye(2)
    if dip_rad is not None:
        L[2] = np.tan(dip_rad) * np.array([np.cos(decl_rad), np.sin(decl_rad)])
    J = np.stack([C[..., 1, :], -C[..., 0, :]], axis=-2) / gravity_mps2
    return L @ J


def levelling_consider_cov(maps, noise: FilterNoise) -> tuple[np.ndarray, np.ndarray]:
    """(P, D): (3,3) NED covariances (rad^2) of the levelling error that the accelerometer bias leaves in
    an alignment (P, the mean over the two ends: the whole error when nothing after the alignment
    observes the bias) and of its difference between the two ends (D, for the forward/backward
    consistency test, `smoother.fb_scale`; the runs' sensitivities would give the exact difference,
    (S_f - S_b)(S_f - S_b)^T var - Q_f - Q_b, but that moves the test's scale and the fusion weights
    with it: a rolled-device session's fkf 0.0200 -> 0.0201 m at the issue's 0.02 m goal).
    The full model does not use P for its covariances: its filters carry the levelling error as a
    sensitivity to the bias (`FilterSetup.lev_map`, `local.honest_covariance`), which shrinks as the
    device turns and the filters learn the bias (kept in full, a MEMS session's target sigmas came out
    twice their errors, NEES/dof 0.27). P is added in full to the paper8 model's solutions and reported.

    An alignment takes f_b = C^T f_up + b_a for gravity, so its tilt is off by phi_h = J b_a with
    J = [[C_E], [-C_N]] / g (C the alignment's attitude; phi with C_true = exp(phi) C_hat). A magnetic
    heading levelled with that tilt is off too: the field's horizontal part seen through a tilt phi_h
    turns the heading by tan(dip) (u_h . phi_h), u_h the field's horizontal direction (Eq. 8 with a
    tilted levelling); the alignment's heading, and the wall normal LF2 takes from it, inherit it. So
    phi = L J b_a with L = [I2; tan(dip) u_h^T] (`levelling_map`); for an isotropic bias prior
    J J^T = I / g^2 at any attitude."""
    sb2 = noise.acc_bias_mps2**2
    P = sum(M @ M.T for M in maps) * sb2 / len(maps)
    dM = maps[0] - maps[-1]
    return P, dM @ dM.T * sb2


def with_levelling(sol: AttitudeSolution, P_lev: np.ndarray, noise: FilterNoise) -> AttitudeSolution:
    """`sol` with the accelerometer bias's effect in its attitude covariance: through its own
    sensitivity (`local.honest_covariance`) where the filters carried one, else the levelling consider
    covariance `P_lev` added in full (the paper8 model)."""
    if sol.S_ba is not None:
        return replace(sol, P_att=honest_covariance(sol, noise.acc_bias_mps2**2))
    return replace(sol, P_att=sol.P_att + P_lev[None])


def with_levelling_maps(setups: Setups, maps) -> Setups:
    """`setups` with each run's levelling map (forward: the start's, backward: the end's) and the wall
    normal's azimuth sensitivity (it is the start alignment's heading turned by the beams: -M[2]); the runs
    that start from the start alignment (forward, gyro-only) carry their sensitivity to its heading error,
    which LF2's wall normal shares (`FilterSetup.align_heading_var_rad2`, `master.fuse`)."""
    m0, m1 = (np.asarray(m, dtype=float) for m in maps)
    kw = dict(wall_sens=-m0[2].copy())
    h = dict(align_heading_var_rad2=float(setups.forward.P0[2, 2]))
    return Setups(replace(setups.forward, lev_map=m0, **kw, **h), replace(setups.backward, lev_map=m1, **kw),
                  replace(setups.gyro, lev_map=m0, **kw, **h))


def position_targets(session: Session, p: TargetFkfParams, sols: dict, obs_lla, start: End, noise: FilterNoise,
                     ctx: RunContext, summary: dict, base_fkf: AttitudeSolution | None = None, P_lev=None):
    """Target rows of every solution for every shot, `fkf_cal` from reference shots (calibrating `base_fkf`,
    default `sols["fkf"]`, with the filters' own covariance: the accelerometer bias's share, through the
    sensitivity `S_ba` (full model) or the levelling consider covariance `P_lev` (paper8), is added to
    fkf_cal for what the offsets leave of it), and the target pairs."""
    t = session.imu.t_s
    rows, pairs = [], []
    with ctx.stage("targeting"):
        shots = _shots(session, p, t, start.window)
        if shots is None or session.ranges is None:
            if session.ranges is not None:
                ctx.warn("shots: none given and none detected; no target positions")
            return None, {}
        d1 = _d1_on_imu(session, t)
        fixes = {name: _geolocate_shots(sol, shots, t, d1, obs_lla, noise.range_sigma_m) for name, sol in sols.items()}
        # the reference shots calibrate fkf's own pitch/heading offsets, which take up the levelling error
        # at those shots: the fit uses fkf's own covariance (`_apply_offsets` adds what is left of it)
        fkf_base = base_fkf if base_fkf is not None else sols.get("fkf")
        cal = None
        if fkf_base is not None:
            # the offsets' own uncertainty comes from what is not attitude (range noise): the
            # attitude error at the reference shots is what they estimate, not noise on them
            df_b, lla_b, _ = _geolocate_shots(fkf_base, shots, t, d1, obs_lla, noise.range_sigma_m)
            _, _, cov_r = _geolocate_shots(fkf_base, shots, t, d1, obs_lla, noise.range_sigma_m, attitude=False)
            cal, t_ref = _calibrate(session, shots, (df_b, lla_b, cov_r), obs_lla)
        if cal is not None:
            summary["calibration"] = {"dpitch_deg": np.degrees(cal.dpitch_rad), "dyaw_deg": np.degrees(cal.dyaw_rad),
                                      "sigma_deg": np.degrees(np.sqrt(np.diag(cal.cov_rad2))).tolist(),
                                      "residual_rms_m": cal.residual_rms_m, "shots": cal.n_shots}
            sols["fkf_cal"] = _apply_offsets(fkf_base, cal, t_ref, noise, session.meta.rate_hz)
            if P_lev is not None and fkf_base.S_ba is None:
                # without a sensitivity (paper8) what the offsets leave of the levelling error is unknown: all
                # of it is kept (its change re-levelled at each attitude, (M(t) - M(t_ref)) b_a, was measured
                # over-confident on MEMS simulations, NEES/dof 6: the filters do not follow J(C))
                sols["fkf_cal"] = with_levelling(sols["fkf_cal"], P_lev, noise)
            fixes["fkf_cal"] = _geolocate_shots(sols["fkf_cal"], shots, t, d1, obs_lla, noise.range_sigma_m)
        for name, (df, lla, cov) in fixes.items():
            rows.append(df.assign(t_start=df.t_start + session.t0_s, t_end=df.t_end + session.t0_s))
            ok = np.isfinite(lla[:, 0])
            if ok.sum() >= 2:
                pairs.append(targeting.target_pairs(list(df.id[ok]), lla[ok], name, cov[ok]))
        ctx.count("shots", len(shots[0]))
    return pd.concat(rows, ignore_index=True), ({"targets_pairs": pd.concat(pairs, ignore_index=True)} if pairs else {})


def run(session: Session, p: TargetFkfParams, ctx: RunContext) -> ChainOutput:
    # an IMU gap longer than imu_gap_max_s is refused before the chain (`pipeline.check_imu_gaps`)
    summary: dict = {"model": p.model}
    session = remove_mag_lag(session, p, ctx, summary)
    obs_lla, obs_src = observer_position(session)
    summary["observer"] = {"lla": obs_lla.tolist(), "source": obs_src}
    decl = _declination(session, obs_lla, ctx, summary)
    with ctx.stage("initial alignment"):
        coarse = _coarse_noise(session, p)
        start = align_end(session, p, np.radians(obs_lla[0]), decl, coarse, at_end=False)
        noise = imu_figures(session, p, start, summary)
        start = align_end(session, p, np.radians(obs_lla[0]), decl, _white(noise), at_end=False)
        summary["alignment"] = _alignment_summary(session, start)
    field = survey_field(session, p, start, obs_lla, noise, ctx, summary)
    with ctx.stage("initial alignment"):
        end = _align_at_end(session, p, np.radians(obs_lla[0]), decl, noise, start, field, ctx)
    setups = filter_setups(session, p, obs_lla, decl, (start, end), noise, field)
    mag_ref = setups.forward.mag_ref
    lev = (mag_ref[1] if mag_ref[0] > 0 else None, decl)
    maps = [levelling_map(e.levelled_at(), e.gravity_mps2, *lev) for e in (start, end)]
    P_lev, D_lev = levelling_consider_cov(maps, noise)
    tracked = p.model == "full"  # the full model's filters carry the accelerometer bias's effect themselves
    beams = beam_geometry(session, start, noise, float(setups.forward.P0[2, 2]), ctx, summary)
    if tracked:
        setups = with_levelling_maps(setups, maps)
        # the wall azimuth's levelling share is carried by the sensitivity (`FilterSetup.wall_sens`)
        lev_var = noise.acc_bias_mps2**2 * float(maps[0][2] @ maps[0][2])
        beams = replace(beams, wall_lev_var_rad2=min(lev_var, beams.wall_var_rad2))
    setups = with_wall(setups, beams)
    still = still_mask(session, p) if p.model == "full" else None
    sols = local_filters(session, p, setups, field, beams, (start, end), noise, decl, ctx, summary, still,
                         fb_diff_cov=D_lev)
    innovations = innovations_table(sols, setups.forward.range_gate_chi2, 1.0 if beams.rdiff is None else p.beta,
                                    still if p.motion_model else None, session.t0_s)
    sols = unsupported_heading(sols, field.mag_b_ut if field is not None else session.imu.mag_b_ut, decl, ctx, summary)
    sols = unresolved_offset_heading(sols, field, session, start, ctx, summary)
    sols = federate(sols, p, setups.forward.range_gate_chi2, session.imu.t_s, ctx, summary,
                    noise.acc_bias_mps2**2 if tracked else 0.0)
    summary["levelling_consider_sigma_deg"] = np.degrees(np.sqrt(np.diag(P_lev))).round(4).tolist()
    # what targeting reads of the unlevelled fkf (`_apply_offsets`); each solution then keeps its attitude and
    # levelled covariance only, the rest freed as it goes (an hour at 100 Hz: ~0.2 GB per solution)
    f = sols["fkf"]
    fkf = AttitudeSolution("fkf", f.t_s, f.C_nb, f.P_att, var_bias=f.var_bias, S_ba=f.S_ba)
    del f
    for k in list(sols):
        v = with_levelling(sols.pop(k), P_lev, noise)
        sols[k] = AttitudeSolution(v.name, v.t_s, v.C_nb, v.P_att)
        del v
    targets, tables = position_targets(session, p, sols, obs_lla, start, noise, ctx, summary, base_fkf=fkf, P_lev=P_lev)
    traj = _trajectory(sols, session.imu.t_s + session.t0_s, obs_lla)
    summary["solutions"] = list(sols)
    return ChainOutput(trajectory=traj, targets=targets, tables={"innovations": innovations, **tables}, summary=summary)


def _declination(session: Session, obs_lla, ctx: RunContext, summary: dict) -> float:
    if session.imu.mag_b_ut is None:
        ctx.warn("imu: no magnetometer; yaw is initialized to 0 (relative heading only)")
        return 0.0
    deg, src = magnetic.resolve_declination_deg(session.meta.declination_deg, obs_lla, session.meta.start_utc)
    summary["declination"] = {"deg": deg, "source": src}
    return float(np.radians(deg))


def _coarse_noise(session: Session, p: TargetFkfParams):
    """(acc m/s^2, mag uT, gyro rad/s) white noise and the accelerometer bias's random walk (m/s^2/sqrt(s)) for
    the first alignment, before the still window's own figures are known (`imu_noise.resolve_imu_noise`
    without measured values)."""
    fig = resolve_imu_noise(p, session.meta.imu_noise, keys=("acc_noise_mg", "mag_noise_ut", "gyro_noise_dps"))
    return (fig["acc_noise_mg"] * 1e-3 * G0_MPS2, fig["mag_noise_ut"], float(np.radians(fig["gyro_noise_dps"])),
            p.acc_bias_rw_mg_per_rts * 1e-3 * G0_MPS2)


def _white(noise: FilterNoise):
    """(acc m/s^2, mag uT, gyro rad/s) white noise per sample of `noise` and its accelerometer bias's random walk
    (`align_end`)."""
    return noise.acc_noise_mps2, noise.mag_noise_ut, noise.gyro_noise_rps, noise.acc_bias_rw_mps2_rts


def _align_at_end(session: Session, p: TargetFkfParams, lat, decl, noise: FilterNoise, start: End, field,
                  ctx: RunContext) -> End:
    """The backward run's own alignment at the end of the log; without a still window there, or when the
    survey marked most of that window's field as disturbed, the start alignment carried to the end by the
    gyro (its heading and tilt then grow by the bias SD times the log)."""
    try:
        end = align_end(session, p, lat, decl, _white(noise), at_end=True)
        if field is None or np.mean(field.disturbed[end.window.i0:end.window.i1]) <= 0.5:
            return end
        ctx.warn("alignment: the magnetic field is disturbed at the end of the log; the backward run starts from "
                 "the gyro-carried start alignment with its drift as uncertainty")
    except ProcessingError:
        ctx.warn("alignment: no still window at the end of the log; the backward run starts from the gyro-carried "
                 "start alignment with its drift as uncertainty")
    imu = session.imu
    n = imu.t_s.size
    A = start.align
    # the start alignment is held at the first sample (`align_end` carried it there)
    C = _carry(A.C_nb, A.gyro_bias_rps, imu.t_s, imu.gyro_b_rps, 0, n - 1, earth.earth_rate_ned_rps(lat))
    # that attitude is the forward run's own information: as the backward run's prior it would be fused
    # with the forward run as if independent (a heading that only the start's magnetometer fixed, counted
    # twice). The backward run keeps it as its linearization point with an uninformative covariance
    # (BACKWARD_CARRIED_SD_RAD, or the bias SD times the log when larger), so it holds only what the
    # samples after each instant tell
    grow = noise.gyro_bias_rps * (imu.t_s[-1] - imu.t_s[0])
    A = replace(A, C_nb=C, sigma_rpy_rad=np.maximum(np.hypot(A.sigma_rpy_rad, grow), BACKWARD_CARRIED_SD_RAD))
    return End(A, start.window, start.gravity_mps2, noise.gyro_bias_rps, start.levelled_at())


def _alignment_summary(session: Session, start: End) -> dict:
    A, win, t = start.align, start.window, session.imu.t_s
    return {"t_start": float(t[win.i0] + session.t0_s), "t_end": float(t[win.i1 - 1] + session.t0_s),
            "end_reason": win.end_reason, "roll_deg": float(np.degrees(A.roll_rad)), "pitch_deg": float(np.degrees(A.pitch_rad)),
            "yaw_deg": float(np.degrees(A.yaw_rad) % 360.0), "sigma_rpy_deg": np.degrees(A.sigma_rpy_rad).tolist(),
            "mag_norm_ut": A.mag_norm_ut, "mag_dip_deg": float(np.degrees(A.mag_dip_rad)),
            "gyro_bias_dph": (np.degrees(A.gyro_bias_rps) * 3600.0).tolist()}


def _d1_on_imu(session: Session, t):
    d1 = np.full(t.size, np.nan)
    r = session.ranges
    idx = np.searchsorted(t, r.t_s, side="left")
    keep = idx < t.size
    d1[idx[keep]] = r.range_m[keep, 0]
    return d1


def _shots(session: Session, p: TargetFkfParams, t, win):
    """(ids, t_start_s, t_end_s) relative times, from shots.csv or detected."""
    if session.shots is not None and len(session.shots.ids):
        s = session.shots
        return list(s.ids), np.asarray(s.t_start_s, dtype=float), np.asarray(s.t_end_s, dtype=float)
    if session.ranges is None:
        return None
    d1 = _d1_on_imu(session, t)
    # ranges come slower than the IMU: carry each return over the IMU samples until the next one
    s = pd.Series(d1).ffill(limit=int(max(1, round(0.5 / max(np.median(np.diff(t)), 1e-6))))).to_numpy()
    a, b = detect_shots(t, session.imu.gyro_b_rps, s, win.i1, p.shot_min_s, np.radians(p.shot_gyro_tol_dps))
    if a.size == 0:
        return None
    return [f"auto_{i + 1:02d}" for i in range(a.size)], a, b


def _sigma_columns(cov_ned_m2) -> dict:
    """A target's SDs (m) and the off-diagonal covariances (m^2) of north, east and up (up = -down)."""
    c = np.asarray(cov_ned_m2, dtype=float)
    sd = np.sqrt(np.clip(np.diag(c), 0.0, None))
    return {"sigma_n": sd[0], "sigma_e": sd[1], "sigma_u": sd[2],
            "cov_ne_m2": c[0, 1], "cov_nu_m2": -c[0, 2], "cov_eu_m2": -c[1, 2]}


def _geolocate_shots(sol: AttitudeSolution, shots, t, d1, obs_lla, sigma_r, attitude: bool = True):
    """(rows, lla (S,3), cov (S,3,3)) of every shot; `attitude` False: covariances of the range
    noise alone (the attitude taken as exact)."""
    ids, ta, tb = shots
    rows, llas, covs = [], [], []
    for sid, a, b in zip(ids, ta, tb):
        i0, i1 = np.searchsorted(t, a, side="left"), np.searchsorted(t, b, side="right")
        r = d1[i0:i1]
        r = r[np.isfinite(r)]
        if i1 <= i0 or r.size == 0:
            rows.append({"id": sid, "t_start": a, "t_end": b, "range_m": np.nan, "lat": np.nan, "lon": np.nan,
                         "h": np.nan, "solution": sol.name, **_sigma_columns(np.full((3, 3), np.nan))})
            llas.append(np.full(3, np.nan))
            covs.append(np.full((3, 3), np.nan))
            continue
        Cm, Pm = _window_attitude(sol, slice(i0, i1))
        d = float(r.mean())
        fx = targeting.geolocate(obs_lla, Cm[None], np.array([d]), P_att_rad2=(Pm if attitude else 0.0 * Pm)[None],
                                 sigma_range_m=sigma_r / np.sqrt(r.size))
        rows.append({"id": sid, "t_start": a, "t_end": b, "range_m": d, "lat": fx.lla[0, 0], "lon": fx.lla[0, 1],
                     "h": fx.lla[0, 2], "solution": sol.name, **_sigma_columns(fx.cov_ned_m2[0])})
        llas.append(fx.lla[0])
        covs.append(fx.cov_ned_m2[0])
    return pd.DataFrame(rows), np.array(llas), np.array(covs)


def _calibrate(session: Session, shots, fkf_fix, obs_lla):
    """Paper 001 Eq. 31-38 on every shot at a `reference` target: (Calibration, mid-times (R,) s of
    the reference shots), (None, None) when there is none. `fkf_fix` = (rows, lla, cov) with the
    covariances of what the offsets do not estimate (range noise)."""
    tg = session.targets
    if tg is None or fkf_fix is None:
        return None, None
    ref = {i: tg.lla[k] for k, i in enumerate(tg.ids) if tg.role[k] == "reference"}
    df, lla, cov = fkf_fix
    sel = [k for k, i in enumerate(df.id) if i in ref and np.isfinite(lla[k, 0])]
    if not sel:
        return None, None
    ned = geodetic.lla_to_ned(lla[sel], obs_lla)
    d = np.linalg.norm(ned, axis=1)
    pitch = np.arcsin(-ned[:, 2] / d)
    yaw = np.arctan2(ned[:, 1], ned[:, 0])
    cal = targeting.calibrate_offsets(obs_lla, pitch, yaw, d, np.array([ref[df.id[k]] for k in sel]), cov_ned_m2=cov[sel])
    return cal, 0.5 * (df.t_start.to_numpy(float)[sel] + df.t_end.to_numpy(float)[sel])


def attitude_change_variance(sol: AttitudeSolution, t_ref_s, noise: FilterNoise, rate_hz: float) -> np.ndarray:
    """(N,) variance (rad^2, per axis) of the change of the solution's attitude error between the
    nearest reference shot and each sample: what the reference-point offsets leave. The gyro's
    angle random walk q |dt| (q = per-sample SD^2 / rate), its residual bias (the solution's own
    bias variance at the reference) over dt, and its scale error over the rotation between the
    two attitudes (the constant dM, `FilterNoise.gyro_scale_const_sd`, and the white part); never more than the two
    errors independent, (tr P(t) + tr P(t_ref)) / 3."""
    t = sol.t_s
    tr = np.sort(np.asarray(t_ref_s, dtype=float))
    j = np.clip(np.searchsorted(tr, t), 1, tr.size - 1) if tr.size > 1 else np.zeros(t.size, dtype=np.int64)
    if tr.size > 1:
        j = np.where(np.abs(t - tr[j - 1]) < np.abs(tr[j] - t), j - 1, j)
    dt = np.abs(t - tr[j])
    k_ref = np.clip(np.searchsorted(t, tr), 0, t.size - 1)[j]
    vb = (sol.var_bias[k_ref, :3].max(axis=1) if sol.var_bias is not None
          else np.full(t.size, noise.gyro_bias_rps**2))
    turn = np.linalg.norm(dcm_to_rotvec(sol.C_nb @ np.swapaxes(sol.C_nb[k_ref], 1, 2)), axis=1)
    var = (noise.gyro_noise_rps**2 / rate_hz * dt + vb * dt**2
           + (noise.gyro_scale_sd**2 + noise.gyro_scale_const_sd**2) * turn**2)
    cap = (np.trace(sol.P_att, axis1=1, axis2=2) + np.trace(sol.P_att[k_ref], axis1=1, axis2=2)) / 3.0
    return np.minimum(var, cap)


def _apply_offsets(sol: AttitudeSolution, cal, t_ref_s, noise: FilterNoise, rate_hz: float) -> AttitudeSolution:
    """Subtract the pitch/heading offsets (paper 001 Eq. 35) from every attitude of `sol`. The offsets
    remove the attitude error of the reference shots, so the covariance left is that of the error's
    change since then (`attitude_change_variance`, on each axis), the offsets' own uncertainty
    (`Calibration.cov_rad2`, from the reference shots' range noise) and, with the accelerometer-bias
    sensitivity S (`AttitudeSolution.S_ba`), the bias's share the offsets leave: E(t) b_a with
    E(t) = S(t) - Mx(t) Pi mean_ref(Mx^-1 S) (Mx the Euler error map, Pi keeps pitch and heading)."""
    r, pch, y = dcm_to_euler(sol.C_nb)
    C = euler_to_dcm(r, pch - cal.dpitch_rad, y - cal.dyaw_rad)
    Pe = np.zeros((3, 3))
    Pe[1:, 1:] = cal.cov_rad2
    Mx = euler_error_map(C)
    drift = attitude_change_variance(sol, t_ref_s, noise, rate_hz)[:, None, None] * np.eye(3)
    P = drift + Mx @ Pe @ np.swapaxes(Mx, 1, 2)
    if sol.S_ba is not None:
        # the accelerometer bias's part: S(t) b_a less what the offsets took up at the reference shots,
        # the pitch/heading Euler part of Mx(t_ref)^-1 S(t_ref) (mean over them), turned at each sample
        k_ref = np.clip(np.searchsorted(sol.t_s, np.asarray(t_ref_s, dtype=float)), 0, sol.t_s.size - 1)
        E_ref = np.mean(np.linalg.solve(euler_error_map(sol.C_nb[k_ref]), sol.S_ba[k_ref]), axis=0)
        E_ref[0] = 0.0  # roll is not calibrated
        E = sol.S_ba - Mx @ E_ref
        P = P + noise.acc_bias_mps2**2 * (E @ np.swapaxes(E, 1, 2))
    return AttitudeSolution("fkf_cal", sol.t_s, C, P)


def _trajectory(sols: dict, t_logger, obs_lla) -> pd.DataFrame:
    return pd.concat([trajectory_table(name, t_logger, obs_lla, None, s.C_nb, P_att_rad2=s.P_att)
                      for name, s in sols.items()], ignore_index=True)
