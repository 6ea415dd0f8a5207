"""Hand-motion oscillator: the PSD fit (attitude.motion) and the correlated motion model of the kernel."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from scipy.linalg import expm, solve_continuous_lyapunov
from scipy.signal import welch
from scipy.stats import chi2

from tests.attitude.gen import make
from tests.attitude.test_local import _nees, _rpy, _setup
from tpos_cli.attitude import _kernels as K
from tpos_cli.attitude.local import run_full
from tpos_cli.attitude.motion import fit_oscillator, oscillator_psd
from tpos_cli.config import TargetFkfParams
from tpos_cli.consistency import effective_sample_size, mean_chi2
from tpos_cli.errors import ProcessingError

SEEDS = 10


def _oscillator_path(freq_hz, zeta, sd_m, duration_s, dt, seed):
    """(t, p, a) exact discrete samples of p'' = -w0^2 p - 2 zeta w0 p' + w (3 axes, stationary start);
    a is the mean acceleration over each interval (velocity difference / dt), the IMU convention."""
    w0 = 2 * np.pi * freq_hz
    F = np.array([[0.0, 1.0], [-w0**2, -2 * zeta * w0]])
    r = np.random.default_rng(seed)
    x0 = np.array([[sd_m], [w0 * sd_m]]) * r.normal(size=(2, 3))
    return _linear_path(F, np.diag([0.0, 4 * zeta * w0**3 * sd_m**2]), x0, duration_s, dt, r)


def _anchored_path(freq_hz, zeta, sd_m, anchor_sd_m, anchor_tau_s, duration_s, dt, seed):
    """(t, p, a) exact discrete samples of a hand that swings about a slowly wandering anchor x (3 axes,
    stationary start): p'' = -w0^2 (p - x) - 2 zeta w0 p' + w, x' = -x / tau + n (first-order Gauss-Markov,
    SD anchor_sd_m); sd_m the oscillator's own SD (its white drive as in `_oscillator_path`)."""
    w0 = 2 * np.pi * freq_hz
    F = np.array([[0.0, 1.0, 0.0], [-w0**2, -2 * zeta * w0, w0**2], [0.0, 0.0, -1.0 / anchor_tau_s]])
    Qc = np.diag([0.0, 4 * zeta * w0**3 * sd_m**2, 2 * anchor_sd_m**2 / anchor_tau_s])
    r = np.random.default_rng(seed)
    P = solve_continuous_lyapunov(F, -Qc)  # the stationary covariance: F P + P F^T + Qc = 0
    return _linear_path(F, Qc, np.linalg.cholesky(P) @ r.normal(size=(3, 3)), duration_s, dt, r)


def _linear_path(F, Qc, x0, duration_s, dt, r):
    """(t, p, a) of x' = F x + white noise of PSD Qc from x0 ((m, 3): states by axis; rows p, v first),
    sampled exactly (Van Loan discretization of the white-noise input); a is the mean acceleration over
    each interval (velocity difference / dt), the IMU convention."""
    m = F.shape[0]
    Phi = expm(F * dt)
    M = expm(np.block([[-F, Qc], [np.zeros((m, m)), F.T]]) * dt)
    Qd = Phi @ M[0:m, m:2 * m]
    L = np.linalg.cholesky(0.5 * (Qd + Qd.T))
    n = int(duration_s / dt)
    x = np.zeros((n, m, 3))
    x[0] = x0
    for k in range(1, n):
        x[k] = Phi @ x[k - 1] + L @ r.normal(size=(m, 3))
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


def _moving_run(path, fit, seed):
    """(g, lf1 solution) of 60 s of the simulated device (`_rpy`) carried along `path` ((t, p, a) of the hand,
    61 s), its filter's hand model the fitted oscillator `fit`, never still."""
    tp, p, _ = path
    spl = CubicSpline(tp, p, axis=0)
    rng = np.random.default_rng(100 + seed)
    g = make(_rpy, duration_s=60.0, seed=seed, bias_rps=rng.normal(0, 3e-5, 3), pos_fn=lambda s: spl(s))
    st = replace(_setup(g, rng), motion_freq_hz=fit.freq_hz, motion_damping=fit.damping, motion_sd_m=fit.sd_m)
    return g, run_full("lf1", g.t, g.gyro, g.acc, g.mag, None, st, K.USE_ACC | K.USE_MAG | K.USE_MOTION,
                       still=np.zeros(g.t.size, dtype=bool))


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


def _two_oscillator_path(duration_s, dt, seed):
    """(t, p, a) of a hand that sways (0.45 Hz, sharp: damping 0.05, 8 cm) and shakes (1.5 Hz, sharp, 1 cm) at
    once, two independent oscillators: an acceleration PSD with two peaks, which one oscillator cannot fit."""
    t, p1, a1 = _oscillator_path(0.45, 0.05, 0.08, duration_s, dt, seed)
    _, p2, a2 = _oscillator_path(1.5, 0.05, 0.01, duration_s, dt, seed + 1000)
    return t, p1 + p2, a1 + a2


def test_fit_is_whittle_s_maximum_likelihood_the_model_s_power_matches_the_log_s_in_band():
    # Whittle's likelihood, sum(log S_model + S_log / S_model) over the band's bins, is stationary in q where the
    # mean of S_log / S_model is 1: the fitted model holds the log's power on average, whatever shape it misses
    # (a least-squares fit of log PSDs holds their geometric mean instead, below it by Jensen's inequality)
    t, _, a = _two_oscillator_path(1200.0, 0.01, seed=21)
    fit = fit_oscillator(t, a, np.ones(t.size, bool))
    f, S = welch(a - a.mean(axis=0), fs=1.0 / np.median(np.diff(t)), nperseg=2000, axis=0)  # the fit's 20 s segments
    band = (f >= 0.3) & (f <= 5.0)
    ratio = S.mean(axis=1)[band] / oscillator_psd(f[band], fit.freq_hz, fit.damping, fit.q_m2ps3)
    assert ratio.mean() == pytest.approx(1.0, rel=1e-9)  # closed-form q: exact to rounding


def test_hand_check_is_not_over_confident_on_a_hand_that_one_oscillator_cannot_fit():
    # the sway-and-shake hand: its one-oscillator fit misses the 1.5 Hz peak; fitted by likelihood the hand
    # check's innovations are still within what the filter states (a log-PSD least-squares fit put q 40 %
    # low: mean NIS 1.12 per dof, above the band)
    t, _, a = _two_oscillator_path(1200.0, 0.01, seed=11)
    a_meas = a + np.random.default_rng(12).normal(0, 0.02, a.shape)
    lo_hz, hi_hz = TargetFkfParams().motion_fit_band_hz  # the default fit, as `tpos process` runs it
    fit = fit_oscillator(t, a_meas, np.ones(t.size, bool), band_hz=(lo_hz, hi_hz), acc_noise_mps2=0.02)
    nis, n_eff = [], 0.0
    for seed in range(4):
        _, sol = _moving_run(_two_oscillator_path(61.0, 0.01, seed=300 + 2 * seed), fit, seed)
        x = sol.nis["acc"][np.isfinite(sol.nis["acc"])][200:]  # after the first 10 s of hand checks
        nis.append(x)
        n_eff += effective_sample_size(x)
    # the verdict's own test of a run's mean NIS (band from the runs' effective sample size), one-sided:
    # a conservative model of a shape it cannot hold is allowed, an over-confident one is not
    m = mean_chi2(np.concatenate(nis), 3.0, n_eff=n_eff)
    assert m.mean <= m.hi, (m, fit)


@pytest.mark.xfail(strict=True, reason=(
    "known gap (issue 13): a hand that swings about a slowly wandering mean position (BROAD's truth: 2-5x the fitted "
    "displacement, 30-95 % of its power below 0.3 Hz) is fitted by one oscillator that lacks the slow part; the filter "
    "takes that displacement for tilt and its attitude sigmas understate the error (measured: the default fit gives "
    "0.50 Hz, damping 0.12, 8 cm; mean NEES 16.5 for 3 dof; on the real trials the hand NIS is up to 2.2x). An anchored "
    "model (the oscillator about a Gauss-Markov mean, sessions 24-25) is consistent with this hand's true parameters "
    "(NEES 1.03 per dof), but fitted in the default band it cannot see the 1 s wander (its correlation time stops at "
    "the band's 0.53 s: mean NEES 4.05 for 3 dof), and it costs accuracy on the real trials (marg_real mean .589 -> "
    ".616): not landed"))
def test_one_oscillator_fitted_to_a_hand_with_a_wandering_mean_is_not_over_confident():
    # a 0.6 Hz swing (3 cm of its own) about a mean position wandering 10 cm with 1 s correlation
    t, _, a = _anchored_path(0.6, 0.3, 0.03, 0.10, 1.0, 1200.0, 0.01, seed=11)
    a_meas = a + np.random.default_rng(12).normal(0, 0.02, a.shape)
    lo_hz, hi_hz = TargetFkfParams().motion_fit_band_hz  # the default fit, as `tpos process` runs it
    fit = fit_oscillator(t, a_meas, np.ones(t.size, bool), band_hz=(lo_hz, hi_hz), acc_noise_mps2=0.02)
    nees = []
    for seed in range(4):
        g, sol = _moving_run(_anchored_path(0.6, 0.3, 0.03, 0.10, 1.0, 61.0, 0.01, seed=300 + seed), fit, seed)
        nees.append(_nees(sol, g.C)[np.arange(1000, g.t.size, 500)])  # every 5 s from 10 s: nearly independent
    nees = np.concatenate(nees)
    # 4 runs x 11 epochs of a 3-dof NEES: below the 97.5 % point of the mean (never over-confident)
    assert nees.mean() < chi2.ppf(0.975, 3 * nees.size) / nees.size, (nees.mean(), fit)
