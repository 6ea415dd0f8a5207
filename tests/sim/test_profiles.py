"""Smooth profiles: derivatives against finite differences, totals, continuity at ramp ends."""

import numpy as np
from numpy.testing import assert_allclose

from tpos_cli.sim.profiles import SMOOTHSTEP_PEAK_RATE, RampProfile, SineProfile, smoothstep7


def test_smoothstep_ends_and_peak():
    s, ds, d2s = smoothstep7(np.array([0.0, 0.5, 1.0]))
    assert_allclose(s, [0.0, 0.5, 1.0], atol=1e-15)  # polynomial identities
    assert_allclose(ds, [0.0, SMOOTHSTEP_PEAK_RATE, 0.0], atol=1e-15)
    assert_allclose(d2s, [0.0, 0.0, 0.0], atol=1e-15)


def test_ramp_profile_derivatives_match_central_differences():
    p = RampProfile.from_ramps(0.3, [(1.0, 2.0, 1.5), (4.0, 3.0, -0.7)])
    t = np.linspace(-1.0, 9.0, 2001)
    h = 1e-5
    f, f1, f2 = p.eval(t)
    fp, f1p, _ = p.eval(t + h)
    fm, f1m, _ = p.eval(t - h)
    # central differences: truncation ~h^2 f'''/6 ~ 1e-10, rounding ~1e-16/h ~ 1e-11
    assert_allclose(f1, (fp - fm) / (2 * h), atol=1e-8)
    assert_allclose(f2, (f1p - f1m) / (2 * h), atol=1e-7)
    assert_allclose(p.eval(np.array([0.0, 3.0, 3.5, 8.0]))[0], [0.3, 1.8, 1.8, 1.1], atol=1e-15)


def test_ramp_profile_rejects_overlaps():
    import pytest

    with pytest.raises(ValueError, match="overlap"):
        RampProfile.from_ramps(0.0, [(0.0, 2.0, 1.0), (1.0, 1.0, 1.0)])


def test_sine_profile_derivatives():
    p = SineProfile(0.9, 100.0, offset=0.2)
    t = np.linspace(0, 200, 101)
    f, f1, f2 = p.eval(t)
    w = 2 * np.pi / 100.0
    assert_allclose(f1, 0.9 * w * np.cos(w * t), atol=1e-15)
    assert_allclose(f2, -w * w * (f - 0.2), atol=1e-15)
