"""Fuzzy inference (paper 002 Algorithm 1): triangular memberships, centroid defuzzification."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pydantic import ValidationError

from tpos_cli.config import FuzzyParams
from tpos_cli.ranging.fuzzy import fuzzy_system, infer, triangle

PARAMS = {
    "input_range": [0.0, 3.0],
    "output_range": [0.0, 3.0],
    "input_sets": {"LE": [-0.5, 0.5, 1.0], "EQ": [0.5, 1.0, 1.5], "MO": [1.0, 1.5, 3.5]},
    "output_sets": {"LE": [0.2, 0.5, 0.8], "EQ": [0.7, 1.0, 1.3], "MO": [1.2, 1.8, 2.7]},
    "rules": [["LE", "LE"], ["EQ", "EQ"], ["MO", "MO"]],
}
# the centroid is exact (piecewise-linear integration); the oracles are 1e6-point quadratures
ATOL_CENTROID = 1e-5


def test_triangle_breakpoints():
    x = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.2])
    assert_allclose(triangle(x, (0.0, 0.5, 1.0)), [0.0, 0.5, 1.0, 0.5, 0.0, 0.0], atol=1e-15)
    # shoulder: left foot == peak
    assert_allclose(triangle(np.array([0.0, 0.5, 1.0]), (0.0, 0.0, 1.0)), [1.0, 0.5, 0.0], atol=1e-15)


def test_output_at_input_peaks_is_output_set_centroid():
    fis = fuzzy_system(FuzzyParams.model_validate(PARAMS))
    # at each input peak exactly one rule fires with strength 1 (neighbours are 0 there),
    # so the output is the centroid of the whole output triangle: (a + b + c) / 3
    s = infer(fis, np.array([0.5, 1.0, 1.5]))
    expected = [sum(PARAMS["output_sets"][k]) / 3 for k in ("LE", "EQ", "MO")]
    assert_allclose(s, expected, rtol=0, atol=ATOL_CENTROID)


def test_output_between_peaks_two_rules_clipped():
    fis = fuzzy_system(FuzzyParams.model_validate(PARAMS))
    # x = 0.75: LE and EQ both fire at 0.5. Aggregate = max(min(.5, LE), min(.5, EQ)).
    # Exact centroid of that piecewise-linear area, by a 1e6-point independent quadrature:
    y = np.linspace(0, 3, 1_000_001)
    mu = np.maximum(np.minimum(0.5, triangle(y, (0.2, 0.5, 0.8))), np.minimum(0.5, triangle(y, (0.7, 1.0, 1.3))))
    expected = np.sum(mu * y) / np.sum(mu)
    assert_allclose(infer(fis, 0.75), expected, atol=ATOL_CENTROID)
    # by the symmetry of the two clipped sets about 0.75, the centroid is 0.75
    assert_allclose(infer(fis, 0.75), 0.75, atol=ATOL_CENTROID)


def test_monotonic_and_clamped():
    fis = fuzzy_system(FuzzyParams.model_validate(PARAMS))
    x = np.linspace(0.0, 3.0, 301)
    s = infer(fis, x)
    assert np.all(np.diff(s) >= -1e-9)  # "less SD -> less R": the rule base is ordered
    assert_allclose(infer(fis, [-5.0, 10.0]), infer(fis, [0.0, 3.0]), atol=0)


def test_bad_rule_base_rejected():
    bad = {**PARAMS, "rules": [["LE", "XX"]]}
    with pytest.raises(ValidationError, match="undefined set"):
        FuzzyParams.model_validate(bad)
    bad = {**PARAMS, "input_sets": {"LE": [1.0, 0.5, 2.0]}}
    with pytest.raises(ValidationError, match="left <= peak"):
        FuzzyParams.model_validate(bad)
    gap = {**PARAMS, "input_sets": {**PARAMS["input_sets"], "MO": [1.0, 1.5, 2.0]}}
    with pytest.raises(ValidationError, match="no rule fires at input 2"):
        FuzzyParams.model_validate(gap)
    with pytest.raises(ValidationError, match="Extra inputs"):
        FuzzyParams.model_validate({**PARAMS, "extra": 1})


def _centroid_by_quadrature(fis, x, n=1_000_001):
    """Independent oracle: the aggregated membership on a fine grid, centroid by trapezoids."""
    y = np.linspace(*fis.out_range, n)
    agg = np.zeros(n)
    for r_in, r_out in fis.rules:
        w = triangle(np.array([np.clip(x, *fis.in_range)]), fis.in_sets[r_in])[0]
        agg = np.maximum(agg, np.minimum(w, triangle(y, fis.out_sets[r_out])))
    return np.trapezoid(agg * y, y) / np.trapezoid(agg, y)


@pytest.mark.parametrize("sets", ["paper", "shoulders"])
def test_exact_centroid_matches_fine_quadrature(sets):
    p = dict(PARAMS)
    if sets == "shoulders":  # left and right shoulder sets: steps in the aggregated membership
        p = {**PARAMS, "output_sets": {"LE": [0.2, 0.2, 0.8], "EQ": [0.7, 1.0, 1.3], "MO": [1.2, 2.7, 2.7]}}
    fis = fuzzy_system(FuzzyParams.model_validate(p))
    x = np.array([0.0, 0.3, 0.62, 0.75, 0.9, 1.17, 1.5, 2.05, 2.9, 3.0])
    # 1e6 points over 3: trapezoid error at the kinks and steps ~ h = 3e-6
    assert_allclose(infer(fis, x), [_centroid_by_quadrature(fis, v) for v in x], atol=2e-6)
