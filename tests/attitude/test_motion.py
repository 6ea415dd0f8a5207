"""Hand-motion oscillator: the PSD fit (attitude.motion) and the correlated motion model of the kernel."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from scipy.linalg import expm
from scipy.stats import chi2

from tests.attitude.gen import make
from tests.attitude.test_local import _nees, _rpy, _setup
from tpos_cli.attitude import _kernels as K
from tpos_cli.attitude.local import run_full
from tpos_cli.attitude.motion import fit_oscillator, oscillator_psd
from tpos_cli.errors import ProcessingError

SEEDS = 10


def _oscillator_path(freq_hz, zeta, sd_m, duration_s, dt, seed):
    """(t, p, a) exact discrete samples of p'' = -w0^2 p - 2 zeta w0 p' + w (3 axes, stationary start);
    a is the mean acceleration over each interval (velocity difference / dt), the IMU convention."""
    w0 = 2 * np.pi * freq_hz
    q = 4 * zeta * w0**3 * sd_m**2
    F = np.array([[0.0, 1.0], [-w0**2, -2 * zeta * w0]])
    Phi = expm(F * dt)
    # Van Loan discretization of the white-noise input, exact for this linear model
    M = expm(np.block([[-F, np.diag([0.0, q])], [np.zeros((2, 2)), F.T]]) * dt)
    Qd = Phi @ M[0:2, 2:4]
    L = np.linalg.cholesky(0.5 * (Qd + Qd.T))
    r = np.random.default_rng(seed)
    n = int(duration_s / dt)
    x = np.zeros((n, 2, 3))
    x[0] = np.array([[sd_m], [w0 * sd_m]]) * r.normal(size=(2, 3))
    for k in range(1, n):
        x[k] = Phi @ x[k - 1] + L @ r.normal(size=(2, 3))
    p, v = x[:, 0, :], x[:, 1, :]
    a = np.zeros_like(v)
    a[1:] = np.diff(v, axis=0) / dt
    return np.arange(n) * dt, p, a


def test_fit_recovers_the_oscillator_of_a_simulated_hand():
    t, _, a = _oscillator_path(0.6, 0.7071, 0.03, 1200.0, 0.01, seed=3)
    a_meas = a + np.random.default_rng(4).normal(0, 0.02, a.shape)  # accelerometer noise, below the PSD in band
    fit = fit_oscillator(t, a_meas, np.ones(t.size, bool), band_hz=(0.2, 5.0))
    # 60 Welch segments of 20 s give a log-PSD scatter of ~0.13 per bin; the frequency and SD of the
    # fitted roll-off land within 10 % and 15 % (seeded: measured 0.62 Hz and 0.031 m here)
    assert fit.freq_hz == pytest.approx(0.6, rel=0.10)
    assert fit.sd_m == pytest.approx(0.03, rel=0.15)
    assert fit.moving_fraction == 1.0
    # the model PSD is flat (2 q) far above the natural frequency, as white driving noise requires
    assert oscillator_psd(500.0, 0.6, 0.7071, 2.0) == pytest.approx(4.0, rel=1e-6)


def test_fit_resolves_a_band_reaching_below_the_default_segment():
    # a band starting at 0.1 Hz needs Welch segments of >= 4 periods (40 s); with a fixed 20 s segment
    # the fit refused such a band ("too short") even on a 20 min log
    t, _, a = _oscillator_path(0.25, 0.7071, 0.05, 1200.0, 0.01, seed=6)
    a_meas = a + np.random.default_rng(7).normal(0, 0.02, a.shape)
    fit = fit_oscillator(t, a_meas, np.ones(t.size, bool), band_hz=(0.1, 5.0))
    # 30 segments of 40 s (half overlap): log-PSD scatter ~0.18 per bin, so 15 % / 20 % as the test above
    # allows 10 % / 15 % with twice the segments (seeded: measured 0.257 Hz and 0.049 m here)
    assert fit.freq_hz == pytest.approx(0.25, rel=0.15)
    assert fit.sd_m == pytest.approx(0.05, rel=0.20)


def test_fit_refuses_a_psd_without_the_oscillator_shape():
    t = np.arange(60000) * 0.01
    white = np.random.default_rng(5).normal(0, 0.1, (t.size, 3))  # flat PSD: no roll-off anywhere
    with pytest.raises(ProcessingError, match="no hand-motion shape"):
        fit_oscillator(t, white, np.ones(t.size, bool))


def test_oscillator_model_levels_a_moving_device_and_is_not_over_confident():
    nees, tilt = [], []
    for seed in range(SEEDS):
        tp, p, _ = _oscillator_path(0.5, 0.7071, 0.05, 31.0, 0.01, seed=200 + seed)
        spl = CubicSpline(tp, p, axis=0)
        rng = np.random.default_rng(100 + seed)
        g = make(_rpy, duration_s=30.0, seed=seed, bias_rps=rng.normal(0, 3e-5, 3), pos_fn=lambda s: spl(s))
        st = replace(_setup(g, rng), motion_freq_hz=0.5, motion_damping=0.7071, motion_sd_m=0.05)
        still = np.zeros(g.t.size, dtype=bool)  # gravity is never measured directly
        sol = run_full("lf1", g.t, g.gyro, g.acc, g.mag, None, st, K.USE_ACC | K.USE_MAG | K.USE_MOTION, still=still)
        idx = np.arange(500, g.t.size, 500)  # every 5 s: nearly independent errors
        nees.append(_nees(sol, g.C)[idx])
        E = sol.C_nb @ np.swapaxes(g.C, 1, 2)
        tilt.append(np.degrees(np.hypot(E[:, 2, 1], E[:, 2, 0]))[1000:])
    nees = np.concatenate(nees)
    # SEEDS runs x 6 epochs of a 3-dof NEES: below the 97.5 % point of the mean (never over-confident)
    assert nees.mean() < chi2.ppf(0.975, 3 * nees.size) / nees.size, nees.mean()
    # 5 cm of hand motion at 0.5 Hz is 0.5 m/s^2 of acceleration (3 deg of apparent tilt): the model
    # separates it from gravity to better than 0.1 deg RMS after 10 s (measured 0.02 deg)
    assert np.sqrt(np.mean(np.concatenate(tilt) ** 2)) < 0.1


def test_displacement_variance_is_the_closed_form_of_a_white_driven_oscillator():
    from tpos_cli.attitude.motion import displacement_var
    # p'' = -w0^2 p - 2 zeta w0 p' + w, E[w w] = q delta: var p = q / (4 zeta w0^3), var v = w0^2 var p
    vp, vv = displacement_var(0.5, 0.7071, 2.0)
    w0 = 2 * np.pi * 0.5
    assert vp == pytest.approx(2.0 / (4 * 0.7071 * w0**3), rel=1e-12)
    assert vv == pytest.approx(w0**2 * vp, rel=1e-12)


def test_fit_takes_the_accelerometer_noise_floor_out_of_the_hand_motion():
    # a small hand motion (2 mm) under loud accelerometer noise (0.1 m/s^2 per sample): fitted as one
    # oscillator the noise inflates the hand's displacement by ~45 %; with the noise as a known floor
    # the fit lands on the true SD (same 60 Welch segments, same ~15 % tolerance as above)
    t, _, a = _oscillator_path(0.6, 0.4, 0.002, 1200.0, 0.01, seed=3)
    a_meas = a + np.random.default_rng(4).normal(0, 0.1, a.shape)
    loud = fit_oscillator(t, a_meas, np.ones(t.size, bool))
    fit = fit_oscillator(t, a_meas, np.ones(t.size, bool), acc_noise_mps2=0.1)
    assert loud.sd_m > 1.3 * 0.002
    assert fit.sd_m == pytest.approx(0.002, rel=0.15)
    assert fit.freq_hz == pytest.approx(0.6, rel=0.10)
