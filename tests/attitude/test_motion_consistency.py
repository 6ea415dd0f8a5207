"""NEES/NIS of the local filters with the bounded-motion model, forward and smoothed (simulated truth).

The device is turned by hand AND moved: a bounded displacement (three sinusoids per axis, 0.2-0.45
Hz, about 0.1 m and 0.2 m/s SD, the model's `motion_sd_m` / `motion_sd_mps`), so the specific force
carries linear accelerations that only the motion model explains. No still periods: gravity is
never measured directly.
"""

from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from scipy.stats import chi2

from tests.attitude.gen import make
from tests.attitude.test_local import _back_setup, _nees, _rpy, _setup
from tpos_cli.attitude import _kernels as K
from tpos_cli.attitude import faults
from tpos_cli.attitude.local import range_differences, run_full
from tpos_cli.attitude.smoother import smooth_full

SEEDS = 24  # 24 runs x 6 epochs: the 95 % band of the mean NEES is [2.61, 3.41] for 3 dof


def _hand(seed, sd_m=0.1):
    r = np.random.default_rng(1000 + seed)
    f = r.uniform(0.2, 0.45, (3, 3))
    ph = r.uniform(0, 2 * np.pi, (3, 3))
    a = np.full((3, 3), sd_m * np.sqrt(2.0 / 3.0))  # three sinusoids per axis: SD sd_m
    return lambda t: np.sum(a * np.sin(2 * np.pi * f * t + ph), axis=1)


@cache
def _runs():
    nees, nis = {}, {}
    for seed in range(SEEDS):
        rng = np.random.default_rng(100 + seed)
        g = make(_rpy, duration_s=30.0, seed=seed, bias_rps=rng.normal(0, 3e-5, 3), pos_fn=_hand(seed))
        st = replace(_setup(g, rng), motion_sd_mps=0.2, motion_sd_m=0.1, motion_interval_s=1.0)
        still = np.zeros(g.t.size, dtype=bool)
        rd = range_differences(g.t, g.t[::10], g.ranges[::10])
        u1 = K.USE_ACC | K.USE_MAG | K.USE_MOTION
        u2 = K.USE_RANGE | K.USE_ACC | K.USE_MOTION
        idx = np.arange(500, g.t.size, 500)  # every 5 s: errors this far apart are nearly independent
        bst = _back_setup(g, rng, st)

        def smoothed(name, t, gyro, acc, mag, r, st, u, still, bst=bst):
            return smooth_full(name, t, gyro, acc, mag, r, st, u, bst, still=still)

        for name, fn, mag, r, u in (("lf1", run_full, g.mag, None, u1), ("lf2", run_full, None, rd, u2),
                                    ("lf1_smoothed", smoothed, g.mag, None, u1),
                                    ("lf2_smoothed", smoothed, None, rd, u2)):
            sol = fn(name, g.t, g.gyro, g.acc, mag, r, st, u, still=still)
            nees.setdefault(name, []).append(_nees(sol, g.C)[idx])
            if fn is run_full:
                for k, v in sol.nis.items():
                    if np.isfinite(v).any():
                        nis.setdefault(k, []).append(v[np.isfinite(v)])
    return {k: np.concatenate(v) for k, v in nees.items()}, {k: np.concatenate(v) for k, v in nis.items()}


def test_nees_nis_with_motion_model_forward_and_smoothed_never_over_confident():
    nees, nis = _runs()
    for k, v in nees.items():
        hi = chi2.ppf(0.975, 3 * v.size) / v.size  # upper end of the two-sided 95 % band of the mean
        assert v.mean() < hi, (k, v.mean(), hi)
    for k, v in nis.items():
        dof = faults.NIS_DOF[k]
        m = max(1, v.size // 10)  # samples 10 ms apart, correlated through the state: 1 in 10 independent
        lo, hi = chi2.ppf([0.025, 0.975], dof * m) / m
        assert lo < v.mean() < hi, (k, v.mean(), lo, hi)


@pytest.mark.xfail(reason="known gap (issue 12): with the bounded-motion epoch model the local filters are "
                          "conservative on this sinusoidal hand (mean NEES lf1 2.49, lf2 ~2.4, band 2.61-3.41)",
                   strict=False)
def test_nees_with_motion_model_not_conservative():
    nees, _ = _runs()
    for k, v in nees.items():
        lo = chi2.ppf(0.025, 3 * v.size) / v.size
        assert lo < v.mean(), (k, v.mean(), lo)
