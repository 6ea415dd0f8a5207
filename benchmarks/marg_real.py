"""Real hand-held MARG logs (BROAD, optical truth): tpos `target-fkf` beside offline VQF, every shared trial.

Metric (issue 13, BROAD's raw figure): RMS of the total attitude error angle |log(C_est C_truth^T)|
over samples with movement == 1 and valid truth, with NO heading-offset removal (the truth frame is
magnetic north: the VQF figures of the issue, 1.01 0.61 1.24 1.47 2.38 1.81 deg, are reproduced exactly);
the offset-removed figure is printed too. VQF runs offline (`offlineVQF`, default parameters, Ts = the
median IMU sample interval) on the same FRD samples. Ours: the `target-fkf` pipeline with its defaults,
one configuration for every trial; truth is read only here, for scoring. Sigma honesty: the share of
motion epochs whose attitude error lies inside the 95 % ellipsoid of its own covariance (3 dof),
rebuilt from the written Euler sigmas (`frames.rotation.attitude_cov_from_euler_sigmas`).

    pip install vqf ; python benchmarks/marg_real.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import chi2

from tpos_cli.frames.rotation import attitude_cov_from_euler_sigmas, dcm_to_rotvec, euler_to_dcm, quat_to_dcm
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


def share_in_band(e_deg, C, sig_rpy_deg, p=0.95):
    """(share of epochs whose error is inside the p-ellipsoid of its covariance (3 dof), mean NEES per dof)."""
    P = attitude_cov_from_euler_sigmas(C, sig_rpy_deg)
    e = np.radians(e_deg)
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(P, e[..., None])[..., 0])
    return float(np.mean(nees < chi2.ppf(p, 3))), float(np.mean(nees) / 3.0)


def main():
    from vqf import offlineVQF

    T = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # VQF's ENU-type frame -> NED
    ratios = []
    print(f"{'trial':40s} {'tpos':>6s} {'vqf':>6s} {'ratio':>6s}  {'tpos/vqf, heading offset removed':>32s}  in 95% band")
    for d in sorted(REAL.glob("broad_*")):
        s = load_session(d)
        tr = s.truth
        t = s.imu.t_s
        k = np.clip(np.round(np.interp(t, tr.t_s, np.arange(tr.t_s.size))).astype(int), 0, tr.t_s.size - 1)
        C_true = euler_to_dcm(*np.radians(tr.rpy_deg[k]).T)
        mov = (tr.extra["movement"][k] == 1) & np.all(np.isfinite(tr.rpy_deg[k]), axis=1)
        with tempfile.TemporaryDirectory() as tmp:
            rs = process_session(d, "target-fkf", Path(tmp) / "run")
            traj = pd.read_parquet(rs.run_dir / "trajectory.parquet")
        q = traj[traj.solution == "fkf"]
        C = euler_to_dcm(*np.radians(q[["roll", "pitch", "yaw"]].to_numpy()).T)[mov]
        sig = q[["sigma_roll", "sigma_pitch", "sigma_yaw"]].to_numpy()[mov]
        r = offlineVQF(np.ascontiguousarray(s.imu.gyro_b_rps), np.ascontiguousarray(s.imu.acc_b_mps2),
                       np.ascontiguousarray(s.imu.mag_b_ut), float(np.median(np.diff(t))))
        C_vqf = (T @ quat_to_dcm(r["quat9D"]))[mov]
        e_ours, e_vqf = error_deg(C, C_true[mov]), error_deg(C_vqf, C_true[mov])
        ours, vqf = rms_deg(e_ours), rms_deg(e_vqf)
        off = total_rms_deg(C, C_true[mov]), total_rms_deg(C_vqf, C_true[mov])
        ratios.append(ours / vqf)
        inside, nees_dof = share_in_band(e_ours, C, sig)
        print(f"{d.name:40s} {ours:6.3f} {vqf:6.3f} {ours / vqf:6.3f}  {off[0]:15.3f}/{off[1]:.3f}"
              f"{'':10s}  {inside:.3f} (NEES/dof {nees_dof:.2f})")
    print(f"mean ratio {np.mean(ratios):.3f}, max {np.max(ratios):.3f} (tpos below VQF where < 1)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
