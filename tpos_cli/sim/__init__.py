"""Simulator of sessions with exact truth (`tpos simulate`): scenarios `drive`, `target`, `ranging`.

In-memory API (each returns a frozen `SimResult`; `sim.write(path)` writes a contract session):

    from tpos_cli.sim import simulate_drive, simulate_target, simulate_ranging
    sim = simulate_drive(duration_s=120.0, seed=0, grade="mems", outages=((40.0, 30.0),), noise_free=False)
    sim.truth.t_s, sim.truth.lla, sim.truth.vel_ned_mps, sim.truth.rpy_rad, sim.truth.C_nb   # exact truth
    sim.imu.gyro_b_rps, sim.imu.acc_b_mps2          # body FRD, with the grade's errors
    sim.imu.gyro_true_b_rps, sim.imu.acc_true_b_mps2  # exact: mean rates over (t_{k-1}, t_k]
    sim.imu.errors.gyro_bias_rps ...                # the error series that were added
    sim.gps.t_s, sim.gps.lla, sim.gps.vel_ned_mps, sim.gps.sigma_neu_m, sim.gps_outages_s
    sim = simulate_drive(300.0, seed=0, gps_rate_hz=4.0, gps_rtk=True)  # RTK-like fixes (rtk.py)
    sim.gps.rtk.regime, sim.gps.rtk.offset_neu_m, sim.gps.rtk.float_s  # fixed/float/multipath per row, drawn offsets
    sim = simulate_target(duration_s=90.0, seed=0, motion="shots", mag_disturbance_ut=50.0)
    sim.ranges.range_m (K, 3), sim.targets, sim.shots, sim.imu.mag_b_ut
    sim = simulate_ranging(duration_s=60.0, seed=0)
    sim.anchors, sim.anchor_ranges (long format, with range_true_m and nlos_m), sim.range_calibration
    sim.write("out/session", fmt="parquet")         # or tpos_cli.sim.writer.write_session(sim, path)

Times `t_s` are relative to the first IMU sample; files carry t = t_s + `t0_s`. `grade` is `paper`
(the scenario paper's figures), `mems` or `perfect` (`sensor_errors.py`); `noise_free=True` is
`perfect`. The truth is built from analytic motion profiles (`profiles.py`) and integrated on the
WGS-84 ellipsoid with Earth rotation (`kinematics.py`), so noise-free IMU integrates back onto it.
"""

from tpos_cli.sim.drive import simulate_drive
from tpos_cli.sim.ranging import simulate_ranging
from tpos_cli.sim.result import SimResult
from tpos_cli.sim.target import simulate_target
from tpos_cli.sim.writer import write_session

SCENARIOS = {"drive": simulate_drive, "target": simulate_target, "ranging": simulate_ranging}

__all__ = ["SCENARIOS", "SimResult", "simulate_drive", "simulate_ranging", "simulate_target", "write_session"]
