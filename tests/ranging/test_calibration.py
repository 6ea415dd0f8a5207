"""Range error model fit (paper 002 Eq. 13-16) against simulated calibration data with known f, c_i."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from tpos_cli.errors import InvalidInputError
from tpos_cli.ranging.calibration import fit_range_model, identity_model


def _calibration(rng, f, c, sd0, sd_rel, n_rep=20, nlos_frac=0.0):
    """Paper Sec. 3.3: a node moved in 0.6 m steps to 18.6 m, 20 readings per point, per anchor."""
    dist = np.arange(0.6, 18.6 + 1e-9, 0.6)
    anchor, true_m, meas = [], [], []
    for i, (fi, ci) in enumerate(zip(f, c)):
        d = np.repeat(dist, n_rep)
        noise = rng.normal(0.0, sd0 + sd_rel * d)
        spikes = (rng.random(d.size) < nlos_frac) * rng.uniform(1.0, 3.0, d.size)
        anchor.append(np.full(d.size, i))
        true_m.append(d)
        meas.append(fi * d + ci + noise + spikes)
    return np.concatenate(anchor), np.concatenate(true_m), np.concatenate(meas)


def test_recovers_per_anchor_scale_and_bias():
    rng = np.random.default_rng(5)
    f, c = [1.02, 0.99, 1.01, 1.0], [0.30, -0.2, 0.1, 0.5]
    a, t, m = _calibration(rng, f, c, 0.05, 0.01)
    model = fit_range_model(a, t, m, 4, reject_sigma=0.0)
    # 620 points per anchor, noise <= 0.24 m over 18 m of lever: SE(f) ~ 5e-4, SE(c) ~ 5e-3 m; 5 SE
    assert_allclose(model.scale, f, rtol=0, atol=2.5e-3)
    assert_allclose(model.bias_m, c, rtol=0, atol=0.025)
    # corrected ranges are unbiased: mean error over all points ~ sd / sqrt(2480) ~ 3e-3 m
    err = model.correct(a, m) - t
    assert abs(err.mean()) < 0.01
    # SD law 0.05 + 0.01 d is linear: the fitted curve follows it within ~10 % (20 reps per SD)
    d = np.array([2.0, 9.0, 16.0])
    assert_allclose(model.range_sd_m(d), 0.05 + 0.01 * d, rtol=0.1, atol=0)


def test_range_sd_beyond_the_calibrated_span_follows_the_fitted_line():
    # calibration to 18.6 m; corridor ranges reach ~26 m. The SD law 0.05 + 0.01 d keeps growing:
    # a clamp at the span's end understated a 25 m range's SD by ~25 %
    rng = np.random.default_rng(6)
    a, t, m = _calibration(rng, [1.0] * 4, [0.0] * 4, 0.05, 0.01)
    model = fit_range_model(a, t, m, 4, scale="shared")
    d = np.array([25.0, 30.0])
    assert_allclose(model.range_sd_m(d), 0.05 + 0.01 * d, rtol=0.1, atol=0)
    # inside the span the polynomial itself; below it, the tangent (still positive)
    assert_allclose(model.range_sd_m(np.array([9.0])), np.polyval(model.sd_poly, 9.0), rtol=1e-12)
    assert model.range_sd_m(np.array([0.0]))[0] > 0


def test_shared_scale_matches_eq13():
    rng = np.random.default_rng(6)
    a, t, m = _calibration(rng, [1.015] * 3, [0.2, 0.0, -0.3], 0.05, 0.0)
    model = fit_range_model(a, t, m, 3, scale="shared")
    assert np.all(model.scale == model.scale[0])  # one f (Eq. 13 has no anchor index on f)
    assert_allclose(model.scale, 1.015, atol=1e-3)  # SE(f) ~ 2e-4 with 1860 points
    assert_allclose(model.bias_m, [0.2, 0.0, -0.3], atol=0.015)
    # constant noise: pooled SD is the noise SD within 5 % (1860 dof -> SE 1.6 %)
    assert_allclose(model.pooled_sd_m, 0.05, rtol=0.05)


def test_nlos_spikes_in_calibration_are_rejected():
    rng = np.random.default_rng(7)
    a, t, m = _calibration(rng, [1.01, 1.0], [0.25, -0.1], 0.05, 0.01, nlos_frac=0.03)
    robust = fit_range_model(a, t, m, 2, reject_sigma=4.0)
    plain = fit_range_model(a, t, m, 2, reject_sigma=0.0)
    assert_allclose(robust.bias_m, [0.25, -0.1], atol=0.025)
    # spikes of +1..3 m at 3 % bias the plain LS by ~ +0.06 m; the robust fit removes it
    assert np.all(plain.bias_m - np.array([0.25, -0.1]) > 0.03)
    # every spike (>= 1 m, i.e. >= 4 SD of the largest 0.24 m noise) is rejected
    assert robust.n_rejected.sum() >= 0.9 * 0.03 * t.size


def test_too_few_pairs_is_invalid_input():
    with pytest.raises(InvalidInputError, match="anchor index 1"):
        fit_range_model(np.array([0, 0, 0, 1]), np.array([1.0, 2, 3, 1]), np.array([1.0, 2, 3, 1]), 2)


def test_identity_model():
    model = identity_model(3, 0.1)
    assert_allclose(model.correct(np.array([0, 2]), np.array([5.0, 7.0])), [5.0, 7.0])
    assert_allclose(model.range_sd_m(np.array([1.0, 50.0])), 0.1)
    assert not model.fitted


def test_sd_curve_fisher_scoring_reaches_the_likelihood_minimum():
    """`_ml_sd_poly` against scipy's Nelder-Mead on the same bin likelihood (lines and parabolas)."""
    from scipy.optimize import minimize

    from tpos_cli.ranging.calibration import _bins, _ml_sd_poly

    rng = np.random.default_rng(3)
    dd = np.repeat(np.linspace(0.6, 18.6, 30), 20)
    res = rng.normal(0.0, 0.05 + 0.01 * dd)
    groups = _bins(dd)
    d = np.array([dd[g].mean() for g in groups])
    var = np.array([res[g].var(ddof=1) for g in groups])
    dof = np.array([g.size - 1.0 for g in groups])

    def nll(c):
        v = np.polyval(c, d) ** 2
        return 0.5 * float(np.sum(dof * (np.log(v) + var / v)))

    for deg in (1, 2):
        start = np.polyfit(d, np.sqrt(var), deg, w=np.sqrt(dof / var))
        ref = minimize(nll, start, method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-14, "maxiter": 20000}).x
        got = _ml_sd_poly(d, var, dof, start)
        assert nll(got) <= nll(ref) + 1e-9
        np.testing.assert_allclose(np.polyval(got, d), np.polyval(ref, d), rtol=1e-6)
