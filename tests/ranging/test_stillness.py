"""Stationary intervals' Theil-Sen line against scipy.stats.theilslopes."""

import numpy as np
import pytest
from scipy.stats import theilslopes

from tpos_cli.ranging.stillness import theil_sen


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_theil_sen_matches_scipy(seed):
    rng = np.random.default_rng(seed)
    n = 40 + 30 * seed
    x = np.sort(rng.uniform(0.0, 5.0, n))
    y = 0.03 * x + rng.normal(0.0, 0.05, n)
    y[rng.random(n) < 0.1] += 0.8  # one-sided spikes (NLOS)
    if seed == 2:  # ties in both coordinates
        x = np.round(x, 1)
        y = np.round(y, 2)
    ref = theilslopes(y, x, alpha=0.997)
    got = theil_sen(x, y, 0.997)
    np.testing.assert_allclose(got, (ref.slope, ref.low_slope, ref.high_slope), rtol=1e-12, atol=1e-15)


def test_theil_sen_all_x_equal():
    assert np.all(np.isnan(theil_sen(np.ones(5), np.arange(5.0), 0.95)))
