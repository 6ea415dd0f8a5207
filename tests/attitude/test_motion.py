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


def test_band_pass_displacement_variance_is_the_integral_of_its_psd():
    from scipy.integrate import quad

    from tpos_cli.attitude.motion import displacement_var, hand_psd
    # white force: the closed form q / (4 zeta w0^3), and w0^2 times it for the velocity
    vp, vv = displacement_var(0.5, 0.7071, 2.0)
    w0 = 2 * np.pi * 0.5
    assert vp == pytest.approx(2.0 / (4 * 0.7071 * w0**3), rel=1e-12)
    assert vv == pytest.approx(w0**2 * vp, rel=1e-12)
    # Gauss-Markov force: the Lyapunov solution equals the integral of the one-sided PSD of p (S_a / w^4)
    for fn, fc in ((0.5, 2.0), (1.0, 0.5), (0.4, 9.0)):
        vp, vv = displacement_var(fn, 0.7071, 2.0, fc)
        ip = quad(lambda f: hand_psd(f, fn, 0.7071, 2.0, fc) / (2 * np.pi * f) ** 4, 1e-6, np.inf, limit=400)[0]
        iv = quad(lambda f: hand_psd(f, fn, 0.7071, 2.0, fc) / (2 * np.pi * f) ** 2, 1e-6, np.inf, limit=400)[0]
        assert vp == pytest.approx(ip, rel=1e-5)  # quadrature accuracy, not a model tolerance
        assert vv == pytest.approx(iv, rel=1e-5)


def _band_pass_path(freq_hz, zeta, corner_hz, q, duration_s, dt, seed):
    """Exact discrete samples of p'' = -w0^2 p - 2 zeta w0 p' + u, u' = -wc u + w (3 axes); a as in
    `_oscillator_path`."""
    w0, wc = 2 * np.pi * freq_hz, 2 * np.pi * corner_hz
    F = np.array([[0.0, 1.0, 0.0], [-w0**2, -2 * zeta * w0, 1.0], [0.0, 0.0, -wc]])
    M = expm(np.block([[-F, np.diag([0.0, 0.0, q])], [np.zeros((3, 3)), F.T]]) * dt)
    Phi = expm(F * dt)
    Qd = Phi @ M[0:3, 3:6]
    L = np.linalg.cholesky(0.5 * (Qd + Qd.T))
    r = np.random.default_rng(seed)
    n = int(duration_s / dt)
    x = np.zeros((n, 3, 3))
    for k in range(1, n):
        x[k] = Phi @ x[k - 1] + L @ r.normal(size=(3, 3))
    a = np.zeros((n, 3))
    a[1:] = np.diff(x[:, 1, :], axis=0) / dt
    return np.arange(n) * dt, x[:, 0, :], a


def test_band_pass_fit_recovers_the_corner_and_the_displacement():
    from tpos_cli.attitude.motion import displacement_var
    t, p, a = _band_pass_path(0.6, 0.7071, 2.5, 40.0, 1200.0, 0.01, seed=11)
    a_meas = a + np.random.default_rng(12).normal(0, 0.01, a.shape)
    fit = fit_oscillator(t, a_meas, np.ones(t.size, bool), band_hz=(0.2, 8.0), corner=True)
    # 60 Welch segments (log-PSD scatter ~0.13 per bin) over a 3-parameter fit: frequency and corner
    # within 15 %, displacement SD within 15 % of the model's (seeded)
    assert fit.freq_hz == pytest.approx(0.6, rel=0.15)
    assert fit.corner_hz == pytest.approx(2.5, rel=0.15)
    assert fit.sd_m == pytest.approx(np.sqrt(displacement_var(0.6, 0.7071, 40.0, 2.5)[0]), rel=0.15)
    # a white-driven oscillator needs no corner inside the band: the white model comes back
    t, _, a = _oscillator_path(0.6, 0.7071, 0.03, 1200.0, 0.01, seed=3)
    a_meas = a + np.random.default_rng(4).normal(0, 0.02, a.shape)
    w = fit_oscillator(t, a_meas, np.ones(t.size, bool), band_hz=(0.2, 5.0), corner=True)
    assert w.freq_hz == pytest.approx(0.6, rel=0.10)
