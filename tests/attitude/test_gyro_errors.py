"""Gyro scale-factor/misalignment states of the full local filter (FilterSetup.gyro_err_sd)."""

from dataclasses import replace

import numpy as np

from tests.attitude.gen import make
from tests.attitude.test_local import _setup
from tpos_cli.attitude import _kernels as K
from tpos_cli.attitude.local import run_full
from tpos_cli.frames.rotation import dcm_to_rotvec

# scale/misalignment of the size fitted on BROAD's gyro against its optical truth (0.1-0.4 %)
M_TRUE = np.array([[-0.30, 0.07, -0.11], [0.12, -0.16, -0.03], [0.40, -0.07, -0.23]]) * 1e-2


def _rpy(t):
    # brisk hand-held turns (up to ~70 deg/s about each axis), so that every element of M matters
    return np.radians([30 * np.sin(0.7 * t), 25 * np.sin(2 * np.pi * t / 7), 30 + 60 * np.sin(2 * np.pi * t / 11)])


def test_gyro_scale_and_misalignment_recovered_and_attitude_kept():
    g = make(_rpy, duration_s=120.0, seed=3)
    gyro = (g.gyro - g.bias) @ (np.eye(3) + M_TRUE).T + g.bias  # omega_meas = (I + M) omega + b
    st = replace(_setup(g, np.random.default_rng(0)), C0=g.C[0])
    still = np.ones(g.t.size, dtype=bool)  # gravity measured at every sample (no hand motion here)
    use = K.USE_ACC | K.USE_MAG
    plain = run_full("lf1", g.t, gyro, g.acc, g.mag, None, st, use, still=still)
    est = run_full("lf1", g.t, gyro, g.acc, g.mag, None, replace(st, gyro_err_sd=5e-3), use, still=still)

    def rms_deg(sol):
        e = dcm_to_rotvec(sol.C_nb @ np.swapaxes(g.C, 1, 2))
        return float(np.degrees(np.sqrt(np.mean(np.sum(e**2, axis=1)))))

    # without the states the filter's rate-proportional noise (10 ppm here) cannot absorb 0.4 %
    # errors at 70 deg/s; with them the attitude error falls to the sensor-noise level
    assert rms_deg(est) < 0.1 * rms_deg(plain)
    assert rms_deg(est) < 0.05
    # the 120 s of three-axis turning with gravity and field make every element observable: the
    # end estimate is within 0.02 % (5 % of the largest element) of the truth
    assert np.max(np.abs(est.gyro_M[-1] - M_TRUE)) < 2e-4
    assert plain.gyro_M is None
