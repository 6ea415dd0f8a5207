"""Statistics against hand-computed values and closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import stats

from tests.report import synth
from tpos_cli.report import metrics

EXACT = dict(rtol=1e-12, atol=1e-12)  # pure arithmetic on a handful of numbers
GEO_ATOL_M = 1e-6  # pymap3d round trips are good to ~1e-9 m; 1 um leaves margin


def test_error_stats_hand_computed():
    s = metrics.error_stats([1.0, -2.0, 3.0, -4.0, np.nan])
    assert s.n == 4  # NaN ignored
    assert_allclose([s.mean, s.sd, s.rms], [-0.5, np.sqrt(7.25), np.sqrt(7.5)], **EXACT)
    assert_allclose(s.rms**2, s.mean**2 + s.sd**2, **EXACT)  # population SD identity
    assert (s.min, s.max, s.max_abs) == (-4.0, 3.0, 4.0)
    # |e| sorted 1,2,3,4: linear percentiles at positions 1.5, 2.7, 2.85
    assert_allclose([s.p50, s.p90, s.p95], [2.5, 3.7, 3.85], **EXACT)


def test_error_stats_empty_is_nan():
    s = metrics.error_stats([np.nan, np.nan])
    assert s.n == 0 and np.isnan(s.mean) and np.isnan(s.p95)


def test_position_errors_recover_offsets():
    p = synth.truth_lla(np.array([0.0, 7.0, 15.0]))
    off = np.array([[3.0, 4.0, -12.0], [-1.0, 2.0, 0.5], [0.0, 0.0, 0.0]])
    err = metrics.position_errors_ned(synth.displaced(p, off), p)
    assert_allclose(err, off, rtol=0, atol=GEO_ATOL_M)
    sp = metrics.split_position_errors(err)
    assert_allclose([sp["pos_3d_m"][0], sp["pos_h_m"][0], sp["pos_v_m"][0]], [13.0, 5.0, 12.0], rtol=0, atol=GEO_ATOL_M)


def test_attitude_errors_wrap_and_total_angle():
    sol = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 359.0], [3.0, 0.0, 0.0]])
    tru = np.array([[0.0, 0.0, 359.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    e = metrics.attitude_errors_deg(sol, tru)
    assert_allclose(e["yaw_deg"], [2.0, -2.0, 0.0], rtol=0, atol=1e-9)
    assert_allclose(e["roll_deg"], [0.0, 0.0, 3.0], rtol=0, atol=1e-9)
    assert_allclose(e["att_deg"], [2.0, 2.0, 3.0], rtol=0, atol=1e-9)  # single-axis rotations


def test_cep_closed_forms():
    # circular: P(R <= r) = 1 - exp(-r^2 / 2 sigma^2)
    assert_allclose(metrics.cep_from_sigmas(2.0, 2.0, 0.5), 2.0 * np.sqrt(2 * np.log(2)), rtol=1e-9)
    assert_allclose(metrics.cep_from_sigmas(2.0, 2.0, 0.9), 2.0 * np.sqrt(2 * np.log(10)), rtol=1e-9)
    # 1-D limit: the 75th percentile of |N(0, sigma)|... i.e. 0.6745 sigma for 50 %
    assert_allclose(metrics.cep_from_sigmas(3.0, 0.0, 0.5), 3.0 * stats.norm.ppf(0.75), rtol=1e-12)


def test_cep_elliptical_matches_sampling():
    rng = np.random.default_rng(7)
    x = rng.normal(size=(200_000, 2)) * [2.0, 0.5]
    r = np.hypot(x[:, 0], x[:, 1])
    # the sample median of 2e5 points has a relative SD of ~0.3 %; 1 % is > 3 sigma
    assert_allclose(metrics.cep_from_sigmas(2.0, 0.5, 0.5), np.median(r), rtol=0.01)
    assert_allclose(metrics.cep_from_sigmas(2.0, 0.5, 0.9), np.percentile(r, 90), rtol=0.01)


def test_nis_stats_hand_computed():
    s = metrics.nis_stats([1.0, 2.0, 3.0, 100.0], 2, [True, True, True, False])
    assert (s.n, s.n_accepted, s.n_rejected) == (4, 3, 1)
    assert_allclose(s.mean_nis, 2.0, **EXACT)
    # sum of 3 accepted NIS ~ chi2(6): bounds on the mean are chi2.ppf(.025/.975, 6) / 3
    assert_allclose([s.mean_lo, s.mean_hi], [stats.chi2.ppf(0.025, 6) / 3, stats.chi2.ppf(0.975, 6) / 3], **EXACT)
    assert s.frac_above_95 == 0.25  # only 100 exceeds chi2.ppf(.95, 2) = 5.99
    assert s.consistent


def test_nis_stats_flags_inconsistent_filter():
    s = metrics.nis_stats(np.full(50, 9.0), 3, True)  # mean 9 for dof 3: far above the band
    assert not s.consistent and s.frac_above_95 == 1.0


def test_disagreement_flags_beyond_sigma():
    d = metrics.disagreement([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]], [[1.0, 1.0, 1.0]] * 2)
    assert d.n == 2 and d.n_flagged == 1  # 25 > chi2.ppf(.99, 3) = 11.3; 0 is not
    assert_allclose([d.rms_m, d.max_m, d.frac_flagged], [np.sqrt(12.5), 5.0, 0.5], **EXACT)
    assert metrics.disagreement([[3.0, 4.0, 0.0]]).n_flagged == 0  # no SDs: nothing to flag against


@pytest.mark.parametrize("prob,k", [(0.95, 2.4477), (0.39346934, 1.0)])
def test_ellipse_scale(prob, k):
    assert_allclose(metrics.ellipse_scale(prob), k, rtol=1e-4)  # table values to 5 digits


def test_euler_to_quat_is_the_dcm_of_the_euler_angles():
    from tpos_cli.frames.rotation import euler_to_dcm, quat_to_dcm

    rng = np.random.default_rng(3)
    rpy = np.column_stack([rng.uniform(-180, 180, 50), rng.uniform(-89, 89, 50), rng.uniform(-180, 180, 50)])
    q = metrics.euler_to_quat(rpy)
    assert_allclose(np.linalg.norm(q, axis=0), 1.0, **EXACT)
    assert_allclose(quat_to_dcm(q.T), euler_to_dcm(*np.radians(rpy).T), rtol=0, atol=1e-12)


def test_total_attitude_angle_against_the_rotation_matrices():
    # independent oracle: the angle of C_truth^T C_sol from its trace (away from 0 and 180 deg,
    # where the arccos is well conditioned), for random attitudes and random errors up to 170 deg
    from tpos_cli.frames.rotation import euler_to_dcm

    rng = np.random.default_rng(4)
    tru = np.column_stack([rng.uniform(-180, 180, 200), rng.uniform(-85, 85, 200), rng.uniform(-180, 180, 200)])
    sol = tru + rng.uniform(-60, 60, (200, 3))
    C = np.einsum("nji,njk->nik", euler_to_dcm(*np.radians(tru).T), euler_to_dcm(*np.radians(sol).T))
    angle = np.degrees(np.arccos(np.clip((np.trace(C, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    ok = (angle > 1.0) & (angle < 170.0)
    e = metrics.attitude_errors_deg(sol, tru)
    assert_allclose(e["att_deg"][ok], angle[ok], rtol=0, atol=1e-9)
    shared = metrics.attitude_errors_deg(sol, tru, truth_quat=metrics.euler_to_quat(tru))
    assert_allclose(shared["att_deg"], e["att_deg"], **EXACT)


def test_total_attitude_angle_small_and_nan():
    e = metrics.attitude_errors_deg([[1e-7, 0.0, 0.0], [np.nan, 0.0, 0.0]], [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert_allclose(e["att_deg"][0], 1e-7, rtol=1e-9)  # no digits lost near zero
    assert np.isnan(e["att_deg"][1])


def test_cep_of_many_rows_equals_each_row_alone():
    # the rows solved together (several chunks of Newton steps) give what each gives alone; the
    # bracketing bisection takes over for extreme ellipses
    rng = np.random.default_rng(5)
    sn = np.r_[rng.uniform(0.01, 5.0, 300), 2.0, 3.0, 0.0, np.nan, -1.0, 1.0]
    se = np.r_[rng.uniform(0.01, 5.0, 300), 2.0, 1e-12, 0.0, 1.0, 1.0, 1e-6]
    many = metrics.cep_from_sigmas(sn, se, 0.9)
    one = np.array([metrics.cep_from_sigmas(a, b, 0.9) for a, b in zip(sn, se)])
    assert_allclose(many, one, rtol=1e-11, equal_nan=True)  # Newton stops at steps under 1e-12 s1
    assert_allclose(many[300], 2.0 * np.sqrt(2 * np.log(10)), rtol=1e-9)
    assert_allclose(many[301], 3.0 * stats.norm.ppf(0.95), rtol=1e-12)  # 1-D limit
    assert many[302] == 0.0 and np.isnan(many[303]) and np.isnan(many[304])
    assert isinstance(metrics.cep_from_sigmas(1.0, 2.0), float)


def test_cep_correlated_is_cep_of_the_principal_sds():
    # rho rotates the ellipse: the CEP is that of its principal SDs
    sn, se, rho = 2.0, 1.0, 0.6
    ev = np.linalg.eigvalsh([[sn * sn, rho * sn * se], [rho * sn * se, se * se]])
    assert_allclose(metrics.cep_from_sigmas(sn, se, 0.5, rho), metrics.cep_from_sigmas(*np.sqrt(ev[::-1]), 0.5), rtol=1e-12)
