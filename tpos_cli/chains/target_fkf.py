"""Chain `target_fkf`: static-observer target positioning (papers 000 and 001).

Stages: initial alignment (stationary window, Eq. 6, 8/9 with declination) -> local filters
`gyro`, `lf1` (acc/mag), `lf2` (three LRs) -> fault detection -> federated master `fkf` (Eq. 27
with the detector's weights) and `fkf_raw` (the paper's plain fusion) -> shots (given or detected)
-> target positions for every solution (Eq. 2-4, 29) -> reference-point calibration `fkf_cal`
(paper 001 Eq. 31-38) -> pairwise slant range / height difference (paper 001 Eq. 15-16).
A target session without ranges (attitude-only MARG log) yields `gyro`, `lf1`, `fkf` only.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
from scipy.stats import chi2

from tpos_cli import alignment as al
from tpos_cli import magnetic, targeting
from tpos_cli.attitude import _kernels as K
from tpos_cli.attitude import faults, master, motion, sensor_lag
from tpos_cli.attitude.local import (
    AttitudeSolution,
    FilterNoise,
    FilterSetup,
    add_heading_variance,
    range_differences,
    run_full,
    run_paper8,
)
from tpos_cli.attitude.smoother import smooth_full
from tpos_cli.chains.context import ChainOutput, RunContext
from tpos_cli.config import TargetFkfParams
from tpos_cli.errors import InvalidInputError, ProcessingError
from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.rotation import (
    dcm_to_rotvec,
    euler_sigmas_deg,
    euler_to_dcm,
    rotvec_to_dcm,
)
from tpos_cli.session import Session


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


def _noise(session: Session, p: TargetFkfParams, measured: dict | None = None) -> FilterNoise:
    n = session.meta.imu_noise
    rf = session.meta.rangefinders
    measured = measured or {}

    def pick(given, key, default):
        if given is not None:
            return given
        return measured.get(key) if measured.get(key) is not None else default

    gyro_dps = pick(n.gyro_noise_dps, "gyro_dps", p.gyro_noise_dps)
    bias_dph = n.gyro_bias_dph if n.gyro_bias_dph is not None else p.gyro_bias_dph
    acc_mg = pick(n.acc_noise_mg, "acc_mg", p.acc_noise_mg)
    mag_ut = pick(n.mag_noise_ut, "mag_ut", p.mag_noise_ut)
    rng_m = rf.sigma_m if (rf is not None and rf.sigma_m is not None) else p.range_sigma_m
    return FilterNoise(
        gyro_noise_rps=np.radians(gyro_dps), gyro_bias_rps=np.radians(max(bias_dph, 1e-3) / 3600.0),
        gyro_bias_rw_rps_rts=np.radians(p.gyro_bias_rw_dph_per_rth / 3600.0 / 60.0),
        acc_noise_mps2=acc_mg * 1e-3 * G0_MPS2, mag_noise_ut=mag_ut, range_sigma_m=rng_m,
        gyro_scale_sd=p.gyro_scale_sd_ppm * 1e-6,
    )


def observer_position(session: Session) -> tuple[np.ndarray, str]:
    """`[observer]` if given, else the mean of valid GPS fixes; InvalidInputError otherwise."""
    if session.meta.observer_lla is not None:
        return np.asarray(session.meta.observer_lla, dtype=float), "session.toml"
    g = session.gps
    if g is not None and np.any(g.valid):
        return np.mean(g.lla[g.valid], axis=0), "GPS mean"
    raise InvalidInputError("session.toml: the target chain needs [observer] lat/lon/h or GPS fixes (gps.*) to place the observer")


def wall_normal_ned(C_nb, rdiff_mean, b12, b13) -> np.ndarray:
    """Horizontal unit normal (NED) of the wall from mean (d1-d2, d1-d3) at attitude C_nb.

    n_b ~ (1, -(d1-d2)/b12, (d1-d3)/b13) solves d1 - d_i = n.C o_i / n.C e_x; buildings' walls
    are vertical, so the NED normal is projected onto the horizontal.
    """
    n_b = np.array([1.0, -rdiff_mean[0] / b12, rdiff_mean[1] / b13])
    n = C_nb @ n_b
    n[2] = 0.0
    return n / np.linalg.norm(n)


def detect_shots(t_s, gyro, range_m_on_imu, start_i, min_s, gyro_tol_rps):
    """(starts, ends) s of windows where the device is still and LR1 returns, after `start_i`."""
    still = al.static_mask(t_s, gyro, np.zeros_like(gyro), gyro_tol_rps=gyro_tol_rps, acc_sd_tol_mps2=np.inf)
    ok = still & np.isfinite(range_m_on_imu)
    ok[:start_i] = False
    d = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
    s, e = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
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


def run(session: Session, p: TargetFkfParams, ctx: RunContext) -> ChainOutput:
    imu = session.imu
    t = imu.t_s
    summary: dict = {}
    if imu.mag_b_ut is not None and p.mag_lag_from_log:
        with ctx.stage("magnetometer delay"):
            lag = sensor_lag.estimate_mag_lag(t, imu.gyro_b_rps, imu.mag_b_ut, max_lag_s=p.mag_lag_max_s)
            summary["mag_lag"] = {"lag_s": lag.lag_s, "residual_uts": lag.rms_uts, "residual_zero_lag_uts": lag.rms_zero_uts,
                                  "turning_samples": lag.n_used, "note": lag.reason}
            if lag.lag_s != 0.0:
                # every consumer (alignment, LF1, paper8 observations) sees the delay-free magnetometer
                imu = replace(imu, mag_b_ut=sensor_lag.advance(t, imu.mag_b_ut, lag.lag_s))
                session = replace(session, imu=imu)
    noise = _noise(session, p)
    obs_lla, obs_src = observer_position(session)
    lat = np.radians(obs_lla[0])
    summary.update({"observer": {"lla": obs_lla.tolist(), "source": obs_src}, "model": p.model})

    with ctx.stage("initial alignment"):
        decl_deg = 0.0
        if imu.mag_b_ut is not None:
            decl_deg, src = magnetic.resolve_declination_deg(session.meta.declination_deg, obs_lla, session.meta.start_utc)
            summary["declination"] = {"deg": decl_deg, "source": src}
        else:
            ctx.warn("imu: no magnetometer; yaw is initialized to 0 (relative heading only)")
        decl = np.radians(decl_deg)
        win = al.detect_static_window(
            t, imu.gyro_b_rps, imu.acc_b_mps2, imu.mag_b_ut, min_duration_s=p.static_min_s,
            max_duration_s=p.static_max_s, gyro_tol_rps=np.radians(p.static_gyro_tol_dps),
            acc_sd_tol_mps2=p.static_acc_sd_tol_mps2, mag_step_tol_ut=p.align_mag_step_tol_ut)
        if win.end_reason == "magnetic":
            ctx.warn(f"alignment: the field magnitude changed {t[win.i1] - t[0]:.2f} s into the still window; "
                     "the alignment stops there (magnetic disturbance)")
        if p.noise_from_static:
            measured = static_noise(imu, win)
            noise = _noise(session, p, measured)
            summary["noise_from_static_window"] = measured
        A = al.coarse_alignment(t, imu.gyro_b_rps, imu.acc_b_mps2, imu.mag_b_ut, win, declination_rad=decl,
                                lat_rad=lat, acc_noise_mps2=noise.acc_noise_mps2, mag_noise_ut=noise.mag_noise_ut)
        summary["alignment"] = {
            "t_start": float(t[win.i0] + session.t0_s), "t_end": float(t[win.i1 - 1] + session.t0_s),
            "end_reason": win.end_reason, "roll_deg": np.degrees(A.roll_rad), "pitch_deg": np.degrees(A.pitch_rad),
            "yaw_deg": float(np.degrees(A.yaw_rad) % 360.0), "sigma_rpy_deg": np.degrees(A.sigma_rpy_rad).tolist(),
            "mag_norm_ut": A.mag_norm_ut, "mag_dip_deg": float(np.degrees(A.mag_dip_rad)),
        }

    rdiff = None
    wall_var = 0.0
    wall_n = np.array([np.cos(A.yaw_rad), np.sin(A.yaw_rad), 0.0])
    rf = session.meta.rangefinders
    if session.ranges is not None and rf is not None:
        rdiff = range_differences(t, session.ranges.t_s, session.ranges.range_m)
        in_win = rdiff[win.i0:win.i1]
        good = np.all(np.isfinite(in_win), axis=1)
        if good.sum() < 3:
            ctx.warn("ranges: fewer than 3 three-beam returns during the alignment window; LF2 is not run")
            rdiff = None
        else:
            wall_n = wall_normal_ned(A.C_nb, in_win[good].mean(axis=0), rf.baseline_12_m, rf.baseline_13_m)
            # the wall azimuth inherits the alignment's yaw error plus the mean beam-difference noise
            # (d1 - d2 over b12, K samples); LF2's heading carries it as a constant bias
            wall_var = float(A.sigma_rpy_rad[2] ** 2 + 2.0 * noise.range_sigma_m**2 / rf.baseline_12_m**2 / good.sum())
            summary["wall_azimuth_deg"] = float(np.degrees(np.arctan2(wall_n[1], wall_n[0])) % 360.0)
            summary["wall_azimuth_sigma_deg"] = float(np.degrees(np.sqrt(wall_var)))
    elif session.ranges is None:
        ctx.warn("ranges: none in this session; LF2 needs the three rangefinders, so only gyro/lf1/fkf are produced")

    P0 = np.diag(np.r_[np.maximum(A.sigma_rpy_rad, np.radians(0.01)) ** 2, [noise.gyro_bias_rps**2] * 3])
    setup = FilterSetup(
        lat_rad=lat, h_m=float(obs_lla[2]), C0=A.C_nb, bias0_rps=A.gyro_bias_rps if win.i1 - win.i0 > 0 else np.zeros(3),
        P0=P0, noise=noise, declination_rad=decl,
        mag_ref=(A.mag_norm_ut, A.mag_dip_rad) if np.isfinite(A.mag_norm_ut) else (0.0, 0.0),
        mag_norm_tol_ut=p.mag_norm_tol_ut if np.isfinite(A.mag_norm_ut) else 0.0,
        mag_dip_tol_rad=np.radians(p.mag_dip_tol_deg), acc_static_tol_mps2=p.acc_static_tol_mps2,
        wall_n_ned=wall_n, baseline_12_m=rf.baseline_12_m if rf else 0.2,
        baseline_13_m=rf.baseline_13_m if rf else 0.2,
        range_gate_chi2=float(chi2.ppf(p.range_gate_probability, 2)), beta=p.beta,
        gyro_static_tol_rps=np.radians(p.gyro_static_tol_dps), motion_sd_mps=p.motion_sd_mps,
        motion_sd_m=p.motion_sd_m, motion_interval_s=p.motion_interval_s, motion_freq_hz=p.motion_freq_hz,
        motion_damping=p.motion_damping, motion_step_s=p.motion_step_s,
        heading_recover_nis=p.heading_recover_nis,
        gyro_err_sd=p.gyro_err_pct * 1e-2, gyro_err_rw_rts=p.gyro_err_rw_ppm_rts * 1e-6,
        gravity_mps2=float(np.linalg.norm(np.mean(imu.acc_b_mps2[win.i0:win.i1], axis=0))) if p.gravity_from_static else None,
    )
    # the bias estimated in the window already removes the window's mean rate
    setup_gyro = FilterSetup(**{**setup.__dict__, "beta": 1.0, "gyro_err_sd": 0.0})

    with ctx.stage("local filters"):
        sols: dict[str, AttitudeSolution] = {}
        sols["gyro"] = run_full("gyro", t, imu.gyro_b_rps, imu.acc_b_mps2, None, None, setup_gyro, 0)
        if p.model == "full":
            run = smooth_full if p.smooth else run_full
            mot = K.USE_MOTION if p.motion_model else 0
            still = al.static_mask(t, imu.gyro_b_rps, imu.acc_b_mps2, gyro_tol_rps=np.radians(p.static_gyro_tol_dps),
                                   acc_sd_tol_mps2=p.static_acc_sd_tol_mps2)
            ctx.count("still_samples", int(still.sum()))
            if p.motion_model and p.motion_fit:
                setup = _fit_motion(setup, p, t, sols["gyro"], imu.acc_b_mps2, still, summary, ctx)
            use1 = K.USE_ACC | mot | (K.USE_MAG if imu.mag_b_ut is not None else 0)
            sols["lf1"] = run("lf1", t, imu.gyro_b_rps, imu.acc_b_mps2, imu.mag_b_ut, None, setup, use1, still=still)
            if rdiff is not None:
                sols["lf2"] = add_heading_variance(
                    run("lf2", t, imu.gyro_b_rps, imu.acc_b_mps2, None, rdiff, setup, K.USE_RANGE | K.USE_ACC | mot,
                        still=still), wall_var)
        else:
            wall_yaw = float(np.arctan2(wall_n[1], wall_n[0]))
            o1, v1, o2, v2 = _paper8_obs(session, p, t, A, decl, rdiff, noise, wall_yaw)
            sols["lf1"] = run_paper8("lf1", t, imu.gyro_b_rps, o1, v1, setup)
            if rdiff is not None:
                sols["lf2"] = run_paper8("lf2", t, imu.gyro_b_rps, o2, v2, setup)
        for k, s in sols.items():
            ctx.count(f"updates_{k}", int(sum(np.isfinite(v).sum() for v in s.nis.values())))

    with ctx.stage("federated fusion"):
        locals_ = [sols[k] for k in ("lf1", "lf2") if k in sols]
        if len(locals_) == 2:
            fr = faults.detect(locals_, p.fault, setup.range_gate_chi2)
            w = fr.weights() if p.fault_tolerant else None
            sols["fkf"] = master.fuse("fkf", locals_, w)
            sols["fkf_raw"] = master.fuse("fkf_raw", locals_, None)
            summary["faults"] = {
                name: {"excluded_fraction": float(1.0 - fr.ok[i].mean()),
                       "excluded_s": float(np.sum(np.diff(t, prepend=t[0])[~fr.ok[i]]))}
                for i, name in enumerate(fr.names)}
            ctx.count("fkf_samples_lf1_excluded", int((~fr.ok[0]).sum()))
            ctx.count("fkf_samples_lf2_excluded", int((~fr.ok[1]).sum()))
        else:
            s1 = locals_[0]
            sols["fkf"] = AttitudeSolution("fkf", s1.t_s, s1.C_nb, s1.P_att)
        if sols["lf1"].mag_ok is not None:
            ctx.count("mag_samples_rejected", int((~sols["lf1"].mag_ok).sum()))

    with ctx.stage("targeting"):
        shots = _shots(session, p, t, win)
        tg_rows, pair_tables = [], []
        cal_info = None
        if shots is not None and session.ranges is not None:
            d1 = _d1_on_imu(session, t)
            fixes = {}
            for name, sol in sols.items():
                fixes[name] = _geolocate_shots(sol, shots, t, d1, obs_lla, noise.range_sigma_m)
            cal = _calibrate(session, shots, fixes.get("fkf"), obs_lla)
            if cal is not None:
                cal_info = {"dpitch_deg": np.degrees(cal.dpitch_rad), "dyaw_deg": np.degrees(cal.dyaw_rad),
                            "residual_rms_m": cal.residual_rms_m, "shots": cal.n_shots}
                sols["fkf_cal"] = _apply_offsets(sols["fkf"], cal)
                fixes["fkf_cal"] = _geolocate_shots(sols["fkf_cal"], shots, t, d1, obs_lla, noise.range_sigma_m)
            for name, fx in fixes.items():
                if fx is None:
                    continue
                df, lla, cov = fx
                tg_rows.append(df.assign(t_start=df.t_start + session.t0_s, t_end=df.t_end + session.t0_s))
                ok = np.isfinite(lla[:, 0])
                if ok.sum() >= 2:
                    pair_tables.append(targeting.target_pairs(list(df.id[ok]), lla[ok], name, cov[ok]))
            ctx.count("shots", len(shots[0]))
        elif session.ranges is not None:
            ctx.warn("shots: none given and none detected; no target positions")
        if cal_info is not None:
            summary["calibration"] = cal_info

    traj = _trajectory(sols, t + session.t0_s, obs_lla)
    targets = pd.concat(tg_rows, ignore_index=True) if tg_rows else None
    tables = {}
    if pair_tables:
        tables["targets_pairs"] = pd.concat(pair_tables, ignore_index=True)
    summary["solutions"] = list(sols)
    return ChainOutput(trajectory=traj, targets=targets, tables=tables,
                       summary=summary)


def _fit_motion(setup: FilterSetup, p: TargetFkfParams, t, gyro_sol: AttitudeSolution, acc_b, still, summary, ctx):
    """`setup` with the hand-motion oscillator fitted to the log (attitude.motion); unchanged, with a
    warning, when the log cannot support a fit. The gyro-only attitude suffices: its slow tilt drift
    only reaches frequencies below the fitted band."""
    acc_n = np.einsum("nij,nj->ni", gyro_sol.C_nb, acc_b)
    try:
        fit = motion.fit_oscillator(t, acc_n, ~still, band_hz=tuple(p.motion_fit_band_hz), damping=p.motion_damping,
                                    corner=p.motion_corner)
    except ProcessingError as e:
        ctx.warn(f"{e}; using the fixed bounded-motion epochs (motion_sd_mps, motion_sd_m)")
        return setup
    summary["motion_fit"] = {"freq_hz": fit.freq_hz, "sd_m": fit.sd_m, "q_m2ps3": fit.q_m2ps3,
                             "moving_fraction": fit.moving_fraction, "corner_hz": fit.corner_hz}
    return replace(setup, motion_freq_hz=fit.freq_hz, motion_sd_m=fit.sd_m, motion_damping=fit.damping,
                   motion_corner_hz=fit.corner_hz)


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


def _geolocate_shots(sol: AttitudeSolution, shots, t, d1, obs_lla, sigma_r):
    ids, ta, tb = shots
    rows, llas, covs = [], [], []
    for sid, a, b in zip(ids, ta, tb):
        i0, i1 = np.searchsorted(t, a, side="left"), np.searchsorted(t, b, side="right")
        r = d1[i0:i1]
        r = r[np.isfinite(r)]
        if i1 <= i0 or r.size == 0:
            rows.append({"id": sid, "t_start": a, "t_end": b, "range_m": np.nan, "lat": np.nan, "lon": np.nan,
                         "h": np.nan, "solution": sol.name, "sigma_n": np.nan, "sigma_e": np.nan, "sigma_u": np.nan})
            llas.append(np.full(3, np.nan))
            covs.append(np.full((3, 3), np.nan))
            continue
        Cm, Pm = _window_attitude(sol, slice(i0, i1))
        d = float(r.mean())
        fx = targeting.geolocate(obs_lla, Cm[None], np.array([d]), P_att_rad2=Pm[None],
                                 sigma_range_m=sigma_r / np.sqrt(r.size))
        s = fx.sigma_neu_m[0]
        rows.append({"id": sid, "t_start": a, "t_end": b, "range_m": d, "lat": fx.lla[0, 0], "lon": fx.lla[0, 1],
                     "h": fx.lla[0, 2], "solution": sol.name, "sigma_n": s[0], "sigma_e": s[1], "sigma_u": s[2]})
        llas.append(fx.lla[0])
        covs.append(fx.cov_ned_m2[0])
    return pd.DataFrame(rows), np.array(llas), np.array(covs)


def _calibrate(session: Session, shots, fkf_fix, obs_lla):
    """Paper 001 Eq. 31-38 on every shot at a `reference` target; None when there is none."""
    tg = session.targets
    if tg is None or fkf_fix is None:
        return None
    ref = {i: tg.lla[k] for k, i in enumerate(tg.ids) if tg.role[k] == "reference"}
    df, lla, _ = fkf_fix
    sel = [k for k, i in enumerate(df.id) if i in ref and np.isfinite(lla[k, 0])]
    if not sel:
        return None
    from tpos_cli.frames import geodetic
    ned = geodetic.lla_to_ned(lla[sel], obs_lla)
    d = np.linalg.norm(ned, axis=1)
    pitch = np.arcsin(-ned[:, 2] / d)
    yaw = np.arctan2(ned[:, 1], ned[:, 0])
    return targeting.calibrate_offsets(obs_lla, pitch, yaw, d, np.array([ref[df.id[k]] for k in sel]))


def _apply_offsets(sol: AttitudeSolution, cal) -> AttitudeSolution:
    """Subtract the pitch/heading offsets (paper 001 Eq. 35) from every attitude of `sol`."""
    from tpos_cli.frames.rotation import dcm_to_euler
    r, pch, y = dcm_to_euler(sol.C_nb)
    C = euler_to_dcm(r, pch - cal.dpitch_rad, y - cal.dyaw_rad)
    return AttitudeSolution("fkf_cal", sol.t_s, C, sol.P_att)


def _trajectory(sols: dict, t_logger, obs_lla) -> pd.DataFrame:
    frames = []
    n = t_logger.size
    for name, s in sols.items():
        e = s.euler_deg()
        sg = euler_sigmas_deg(s.C_nb, s.P_att)
        frames.append(pd.DataFrame({
            "t": t_logger, "lat": np.full(n, obs_lla[0]), "lon": np.full(n, obs_lla[1]), "h": np.full(n, obs_lla[2]),
            "vn": np.zeros(n), "ve": np.zeros(n), "vd": np.zeros(n),
            "roll": e[:, 0], "pitch": e[:, 1], "yaw": e[:, 2], "solution": name,
            "sigma_roll": sg[:, 0], "sigma_pitch": sg[:, 1], "sigma_yaw": sg[:, 2],
        }))
    return pd.concat(frames, ignore_index=True)

