"""Real hand-held MARG logs (BROAD, optical truth): tpos `target-fkf` beside offline VQF, every shared trial.

Metric (issue 13, BROAD's raw figure): RMS of the total attitude error angle |log(C_est C_truth^T)|
over samples with movement == 1 and valid truth, with NO heading-offset removal (the truth frame is
magnetic north: the VQF figures of the issue, 1.01 0.61 1.24 1.47 2.38 1.81 deg, are reproduced exactly);
the offset-removed figure is printed too. VQF runs offline (`offlineVQF`, default parameters, Ts = the
median IMU sample interval) on the same FRD samples. Ours: the `target-fkf` pipeline with its defaults,
one configuration for every trial; truth is read only here, for scoring. Sigma honesty: the share of
motion epochs whose attitude error lies inside the 95 % ellipsoid of its own covariance (3 dof),
rebuilt from the written Euler sigmas (`frames.rotation.attitude_cov_from_euler_sigmas`).

The truth's time tags: the optical truth and the IMU disagree by a fixed ~2.4 ms on every trial (measured
here from the gyro against the truth's own body rate, `truth_time_offset_s`; no estimator is involved).
Every estimator that integrates this gyro, VQF included, then shows a tilt "error" tau * omega (0.35-0.7 deg
at 150-300 deg/s) that is a time-tag difference, not an attitude error (notes marg6.md: regressing the
tilt errors of tpos and VQF on the rate gives the same -2.1..-2.6 ms, and their fast parts are identical).
Both figures are printed: the raw one (issue 13's metric, the VQF figures above) and the one against the
truth moved to the IMU's time tags (`shift_truth`), which is what the sigma-honesty figures are scored on,
there also per axis (`axis_nees`: tilt 2 dof, heading 1 dof; a 3-dof mean can hide a bold tilt behind a
cautious heading).
Every sigma figure scores the ABSOLUTE error (no heading offset removed: the truth's heading is magnetic north,
declination 0 in the sessions): the sigmas hold no constant heading term that an offset-free error would sit
inside by construction (the alignment's heading prior is .000-.003 deg on these trials; notes marg11.md), and
removing an offset could only lower the NEES. The per-axis NEES above rebuild a NED covariance from the three
written Euler sigmas as if independent; the column "NEES roll pitch yaw" scores each written sigma against its
own angle's error (`euler_nees`), the exact test of what the trajectory states.
The second table checks the hand-motion model the accelerometer is read against (`attitude.motion`): per frequency
band, the power of the log's own NED acceleration (the gyro-only attitude's C f + g, what the chain fits) and of
the optical truth's kinematic acceleration (its positions differentiated twice, 0.15 s Savitzky-Golay), each over
the fitted oscillator's power in that band (1: the model holds what the log holds).
The last column needs no truth: LF1's forward/backward consistency scales, tilt (`smoother.fb_scale`, mean NEES per
dof of the two runs' difference against their own covariances; 1 for honest runs) and heading (`smoother.heading_split`:
the same test with the gyro scale/misalignment drift the difference holds taken out; 0 where that drift explains
all of it), which the smoother's covariance factors are built from.

    pip install vqf ; python benchmarks/marg_real.py
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.ndimage import uniform_filter1d
from scipy.signal import savgol_filter, welch
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import chi2

from tpos_cli.attitude.motion import oscillator_psd
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.frames.rotation import attitude_cov_from_euler_sigmas, dcm_to_rotvec, euler_error_map, euler_to_dcm, quat_to_dcm
from tpos_cli.pipeline import process_session
from tpos_cli.session import load_session

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def error_rotvec_deg(C_est, C_true):
    """(N,3) NED error rotation vectors (deg) after the best constant heading offset (about NED down)."""
    E = C_est @ np.swapaxes(C_true, 1, 2)
    yaw = np.arctan2(E[:, 1, 0] - E[:, 0, 1], E[:, 0, 0] + E[:, 1, 1])
    off = np.angle(np.mean(np.exp(1j * yaw)))
    Rz = euler_to_dcm(0.0, 0.0, -off)
    return np.degrees(dcm_to_rotvec(Rz @ E))


def total_rms_deg(C_est, C_true):
    """RMS total angle (deg) after the best constant heading offset."""
    e = error_rotvec_deg(C_est, C_true)
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def error_deg(C_est, C_true):
    """(N,3) NED error rotation vectors (deg), C_est = exp(e) C_true."""
    return np.degrees(dcm_to_rotvec(C_est @ np.swapaxes(C_true, 1, 2)))


def rms_deg(e):
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def truth_time_offset_s(t_s, gyro_b_rps, C_true, use, max_s=0.008, step_s=0.00025):
    """tau (s): the truth's attitude at t + tau matches the IMU at t. The gyro's row k is the mean rate over
    (t_k-1, t_k] (the kernels' convention; offline VQF also integrates row k into
    its attitude at k); the truth's body rate is the rotation between its
    consecutive samples over their interval. Both are smoothed alike (15 samples), a constant gyro bias is
    removed, and tau minimises the RMS rate difference over rows `use` turning faster than 20 deg/s
    (grid of `step_s`, parabolic refinement). Only the gyro and the truth enter: no estimator."""
    ok = np.all(np.isfinite(C_true.reshape(-1, 9)), axis=1)
    k = np.flatnonzero(ok[:-1] & ok[1:])
    R = Rotation.from_matrix(C_true[k])
    w_opt = (R.inv() * Rotation.from_matrix(C_true[k + 1])).as_rotvec() / (t_s[k + 1] - t_s[k])[:, None]
    t_mid = 0.5 * (t_s[k] + t_s[k + 1])
    w_opt = uniform_filter1d(w_opt, 15, axis=0)
    w_imu = uniform_filter1d(gyro_b_rps, 15, axis=0)[k + 1]
    sel = use[k + 1] & (np.linalg.norm(w_imu, axis=1) > np.radians(20.0))
    t_imu = t_mid[sel]  # gyro row k+1 is the mean over the same interval
    taus = np.arange(-max_s, max_s + step_s / 2, step_s)
    rms = []
    for tau in taus:
        w = np.stack([np.interp(t_imu + tau, t_mid, w_opt[:, i]) for i in range(3)], axis=1)
        d = w_imu[sel] - w
        rms.append(np.sqrt(np.mean((d - d.mean(axis=0)) ** 2)))
    rms = np.asarray(rms)
    i = int(np.clip(np.argmin(rms), 1, rms.size - 2))
    a, b, c = rms[i - 1:i + 2]
    return float(taus[i] + 0.5 * (a - c) / (a - 2.0 * b + c) * step_s)


def shift_truth(C_true, t_s, tau_s):
    """(N,3,3) the truth's attitude at t + tau (geodesic interpolation between its valid samples); NaN where
    a neighbour is missing (a capture dropout)."""
    ok = np.all(np.isfinite(C_true.reshape(-1, 9)), axis=1)
    out = np.full_like(C_true, np.nan)
    tq = t_s + tau_s
    inside = (tq >= t_s[ok][0]) & (tq <= t_s[ok][-1])
    # both neighbours valid: the interpolation does not bridge a dropout
    j = np.clip(np.searchsorted(t_s, tq, side="right"), 1, t_s.size - 1)
    inside &= ok[j - 1] & ok[j]
    out[inside] = Slerp(t_s[ok], Rotation.from_matrix(C_true[ok]))(tq[inside]).as_matrix()
    return out


def share_in_band(e_deg, C, sig_rpy_deg, p=0.95):
    """(share of epochs whose error is inside the p-ellipsoid of its covariance (3 dof), mean NEES per dof)."""
    P = attitude_cov_from_euler_sigmas(C, sig_rpy_deg)
    e = np.radians(e_deg)
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(P, e[..., None])[..., 0])
    return float(np.mean(nees < chi2.ppf(p, 3))), float(np.mean(nees) / 3.0)


def axis_nees(e_deg, C, sig_rpy_deg):
    """(tilt NEES per dof (2 dof: the NED north/east components), heading NEES (1 dof: down)), means over the
    epochs, of the errors against their covariance rebuilt from the written Euler sigmas: which axis is too
    cautious (< 1) or too bold (> 1)."""
    P = attitude_cov_from_euler_sigmas(C, sig_rpy_deg)
    e = np.radians(e_deg)
    tilt = np.einsum("ni,ni->n", e[:, :2], np.linalg.solve(P[:, :2, :2], e[:, :2, None])[..., 0]) / 2.0
    return float(np.mean(tilt)), float(np.mean(e[:, 2] ** 2 / P[:, 2, 2]))


def euler_nees(e_deg, C, sig_rpy_deg):
    """(3,) mean NEES of the roll, pitch and yaw errors, each against its own written sigma (1 dof each): the
    exact test of what the trajectory states. The error in Euler angles is M^-1 phi (`euler_error_map`, the
    map the written sigmas come from, `euler_sigmas_deg`). `share_in_band`/`axis_nees` rebuild a NED
    covariance from the three sigmas as if the Euler errors were independent, which they are not away from
    level: at the hand-held trials' pitches the rebuilt heading variance takes the roll sigma's share
    (sin(pitch)^2 sigma_roll^2) and comes out larger than the one the solution holds (02: RMS 2.3 deg
    rebuilt against 0.7 written into its own P)."""
    d = np.linalg.solve(euler_error_map(C), np.radians(e_deg)[..., None])[..., 0]
    return np.mean(d**2 / np.radians(sig_rpy_deg) ** 2, axis=0)


#: bands (Hz) of the hand-model check: below the fit's band, then across it
HAND_BANDS_HZ = ((0.05, 0.3), (0.3, 0.6), (0.6, 1.0), (1.0, 2.0), (2.0, 5.0))


def band_sums(f_hz, psd, bands=HAND_BANDS_HZ):
    """(len(bands),) the power of a one-sided PSD on the uniform frequency grid f_hz in each band [lo, hi)."""
    return np.array([psd[(f_hz >= lo) & (f_hz < hi)].sum() * (f_hz[1] - f_hz[0]) for lo, hi in bands])


def band_power(t_s, acc_ned_mps2, moving_fraction):
    """((m/s^2)^2) mean per-axis power of an NED acceleration in each band while moving (Welch, 20 s segments,
    divided by the moving fraction as `motion.fit_oscillator` does), and the spectrum's frequencies f (Hz)."""
    dt = float(np.median(np.diff(t_s)))
    a = np.where(np.isfinite(acc_ned_mps2), acc_ned_mps2, 0.0)
    f, S = welch(a - a.mean(axis=0), fs=1.0 / dt, nperseg=int(round(20.0 / dt)), axis=0)
    return band_sums(f, S.mean(axis=1) / moving_fraction), f


def truth_acc_ned(t_s, truth):
    """(N,3) m/s^2 the optical truth's kinematic NED acceleration at the IMU times: positions (NED about the
    first valid one) interpolated over dropouts, differentiated twice (Savitzky-Golay, cubic, 0.15 s)."""
    ok = np.all(np.isfinite(truth.lla), axis=1)
    p = lla_to_ned(truth.lla, truth.lla[ok][0])
    p = np.stack([np.interp(t_s, truth.t_s[ok], p[ok, i]) for i in range(3)], axis=1)
    dt = float(np.median(np.diff(t_s)))
    return savgol_filter(p, int(round(0.15 / dt)) | 1, 3, deriv=2, delta=dt, axis=0)


def main():
    from vqf import offlineVQF

    T = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # VQF's ENU-type frame -> NED
    ratios, ratios_al, hand_rows = [], [], []
    print(f"{'trial':40s} {'tpos':>6s} {'vqf':>6s} {'ratio':>6s}  {'heading off removed':>19s}  in 95% band (NEES/dof)"
          f"   | truth tau ms  tpos   vqf  ratio  in 95% band (NEES/dof; tilt, heading), truth on the IMU's time tags"
          f"   | NEES roll pitch yaw (written sigmas)   | lf1 fwd/bwd scale tilt/heading (no truth)")
    for d in sorted(REAL.glob("broad_*")):
        s = load_session(d)
        tr = s.truth
        t = s.imu.t_s
        k = np.clip(np.round(np.interp(t, tr.t_s, np.arange(tr.t_s.size))).astype(int), 0, tr.t_s.size - 1)
        C_true = euler_to_dcm(*np.radians(tr.rpy_deg[k]).T)
        moving = tr.extra["movement"][k] == 1
        mov = moving & np.all(np.isfinite(tr.rpy_deg[k]), axis=1)
        tau = truth_time_offset_s(t, s.imu.gyro_b_rps, C_true, mov)
        C_al = shift_truth(C_true, t, tau)
        mov_al = moving & np.all(np.isfinite(C_al.reshape(-1, 9)), axis=1)
        with tempfile.TemporaryDirectory() as tmp:
            rs = process_session(d, "target-fkf", Path(tmp) / "run")
            traj = pd.read_parquet(rs.run_dir / "trajectory.parquet")
            results = json.loads((rs.run_dir / "summary.json").read_text())["results"]
            fb = results.get("forward_backward_consistency", {}).get("lf1", {})
        fit = results.get("motion_fit")
        if fit is not None:
            g = traj[traj.solution == "gyro"]
            C_g = euler_to_dcm(*np.radians(g[["roll", "pitch", "yaw"]].to_numpy()).T)
            log_pw, f = band_power(t, np.einsum("nij,nj->ni", C_g, s.imu.acc_b_mps2), fit["moving_fraction"])
            true_pw, _ = band_power(t, truth_acc_ned(t, tr), fit["moving_fraction"])
            fit_pw = band_sums(f, oscillator_psd(f, fit["freq_hz"], fit["damping"], fit["q_m2ps3"]))
            hand_rows.append((d.name, log_pw / fit_pw, true_pw / fit_pw))
        q = traj[traj.solution == "fkf"]
        C_all = euler_to_dcm(*np.radians(q[["roll", "pitch", "yaw"]].to_numpy()).T)
        sig_all = q[["sigma_roll", "sigma_pitch", "sigma_yaw"]].to_numpy()
        r = offlineVQF(np.ascontiguousarray(s.imu.gyro_b_rps), np.ascontiguousarray(s.imu.acc_b_mps2),
                       np.ascontiguousarray(s.imu.mag_b_ut), float(np.median(np.diff(t))))
        C_vqf_all = T @ quat_to_dcm(r["quat9D"])
        C, sig, C_vqf = C_all[mov], sig_all[mov], C_vqf_all[mov]
        e_ours, e_vqf = error_deg(C, C_true[mov]), error_deg(C_vqf, C_true[mov])
        ours, vqf = rms_deg(e_ours), rms_deg(e_vqf)
        off = total_rms_deg(C, C_true[mov]), total_rms_deg(C_vqf, C_true[mov])
        ratios.append(ours / vqf)
        inside, nees_dof = share_in_band(e_ours, C, sig)
        e_al, e_vqf_al = error_deg(C_all[mov_al], C_al[mov_al]), error_deg(C_vqf_all[mov_al], C_al[mov_al])
        ours_al, vqf_al = rms_deg(e_al), rms_deg(e_vqf_al)
        ratios_al.append(ours_al / vqf_al)
        inside_al, nees_al = share_in_band(e_al, C_all[mov_al], sig_all[mov_al])
        nt_al, nh_al = axis_nees(e_al, C_all[mov_al], sig_all[mov_al])
        ne_al = euler_nees(e_al, C_all[mov_al], sig_all[mov_al])
        print(f"{d.name:40s} {ours:6.3f} {vqf:6.3f} {ours / vqf:6.3f}  {off[0]:9.3f}/{off[1]:.3f}  {inside:.3f} ({nees_dof:.2f})"
              f"   | {tau * 1e3:11.2f} {ours_al:6.3f} {vqf_al:5.3f} {ours_al / vqf_al:6.3f}  "
              f"{inside_al:.3f} ({nees_al:.2f}; {nt_al:.2f}, {nh_al:.2f})"
              f"   | {ne_al[0]:.2f} {ne_al[1]:.2f} {ne_al[2]:.2f}"
              f"   | {fb.get('tilt', np.nan):7.1f}/{fb.get('heading', np.nan):.1f}")
    print(f"mean ratio {np.mean(ratios):.3f}, max {np.max(ratios):.3f} (tpos below VQF where < 1); on the IMU's time tags: "
          f"mean {np.mean(ratios_al):.3f}, max {np.max(ratios_al):.3f}")
    print("\nhand model: acceleration power per band over the fitted oscillator's (log: the gyro-only attitude's C f + g, "
          "what the chain fits; truth: the optical positions twice differentiated)")
    print(f"{'trial':40s} " + " ".join(f"{f'{lo:g}-{hi:g} Hz':>15s}" for lo, hi in HAND_BANDS_HZ))
    for name, log_r, true_r in hand_rows:
        print(f"{name:40s} " + " ".join(f"{a:6.2f} / {b:6.2f}" for a, b in zip(log_r, true_r)) + "   (log / truth)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
