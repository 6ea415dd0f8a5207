"""Scenario `ranging` (paper 002): exact ranges, Eq. 13 error model, NLOS rate, dropouts,
calibration table recovering the model by least squares (Eq. 14-16)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.stats import binom, chi2

from tpos_cli.frames.geodetic import enu_to_lla, lla_to_ecef
from tpos_cli.sim import simulate_ranging
from tpos_cli.sim.ranging import range_sigma_m


@pytest.fixture(scope="module")
def sim():
    return simulate_ranging(60.0, seed=9)


def test_true_ranges_are_ecef_distances(sim):
    ar = sim.anchor_ranges
    i = np.searchsorted(sim.truth.t_s, ar.t_s)
    node = lla_to_ecef(sim.truth.lla[i])
    anc = lla_to_ecef(enu_to_lla(sim.anchors.enu_m, sim.anchors.origin_lla))[ar.anchor]
    assert_allclose(ar.range_true_m, np.linalg.norm(node - anc, axis=1), atol=1e-9)


def test_noise_free_ranges_follow_scale_and_bias():
    s = simulate_ranging(30.0, seed=1, noise_free=True)
    ar = s.anchor_ranges
    assert_allclose(ar.range_m, 1.025 * ar.range_true_m + np.array([0.35, 0.25, 0.40, 0.30])[ar.anchor], atol=1e-12)


def test_noise_is_5cm_plus_1_percent(sim):
    ar = sim.anchor_ranges
    los = ar.nlos_m == 0
    r = (ar.range_m - 1.025 * ar.range_true_m - np.array([0.35, 0.25, 0.40, 0.30])[ar.anchor])[los]
    z = r / range_sigma_m(ar.range_true_m[los])
    q = np.sum(z * z)
    assert chi2.ppf(5e-5, z.size) < q < chi2.ppf(1 - 5e-5, z.size)


def test_nlos_spikes_are_positive_and_about_3_percent(sim):
    ar = sim.anchor_ranges
    k = int((ar.nlos_m > 0).sum())
    n = ar.nlos_m.size
    assert binom.ppf(1e-4, n, 0.03) <= k <= binom.ppf(1 - 1e-4, n, 0.03)
    assert ar.nlos_m.min() >= 0.0 and ar.nlos_m[ar.nlos_m > 0].min() >= 0.5


def test_anchor_2_dropouts_and_10hz(sim):
    ar = sim.anchor_ranges
    a2 = sim.anchors.ids.index("A2")
    t2 = ar.t_s[ar.anchor == a2]
    assert not np.any(((t2 >= 18) & (t2 < 23)) | ((t2 >= 40) & (t2 < 45)))
    t1 = ar.t_s[ar.anchor == 0]
    assert t1.size == 601 and t2.size == 601 - 100
    assert np.all(np.diff(ar.t_s) >= 0)


def test_calibration_table_recovers_scale_and_bias_by_least_squares(sim):
    rc = sim.range_calibration
    assert rc.true_m.size == 4 * 31 * 20
    for a in range(4):
        m = rc.anchor == a
        w = 1.0 / range_sigma_m(rc.true_m[m])
        A = np.column_stack([rc.true_m[m], np.ones(m.sum())]) * w[:, None]
        sol, *_ = np.linalg.lstsq(A, rc.measured_m[m] * w, rcond=None)
        cov = np.linalg.inv(A.T @ A)
        # weighted LS with the true noise model: the estimate lies within 4.5 sigma of the truth
        assert abs(sol[0] - rc.scale) < 4.5 * np.sqrt(cov[0, 0])
        assert abs(sol[1] - rc.bias_m[a]) < 4.5 * np.sqrt(cov[1, 1])


def test_node_stays_in_the_corridor_and_stops(sim):
    from tpos_cli.frames.geodetic import lla_to_enu

    enu = lla_to_enu(sim.truth.lla, sim.anchors.origin_lla)
    assert enu[:, 1].min() > -1.0 and enu[:, 1].max() < 3.0
    assert np.linalg.norm(sim.truth.vel_ned_mps[-1]) == 0.0
    assert np.abs(sim.truth.rpy_rad[:, :2]).max() == 0.0
