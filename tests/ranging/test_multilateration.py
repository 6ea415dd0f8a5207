"""Least-squares horizontal fix from anchor ranges."""

import numpy as np
from numpy.testing import assert_allclose

from tpos_cli.ranging.multilateration import ls_fix

ANCHORS = np.array([[0.0, 0.0, -2.5], [0.0, 20.0, -2.0], [3.0, 10.0, -2.5], [3.0, 30.0, -2.2]])


def test_exact_ranges_give_exact_fix():
    p = np.array([1.2, 12.5, -0.3])
    r = np.linalg.norm(ANCHORS - p, axis=1)
    fix = ls_fix(ANCHORS, r, np.full(4, 0.1), np.array([0.0, 10.0, -0.3]))
    assert fix.ok
    assert_allclose(fix.pos_ned_m, p, atol=1e-7)  # Gauss-Newton to tol 1e-6 m, quadratic convergence
    assert fix.residual_rms_m < 1e-7


def test_noisy_fix_is_consistent_with_its_covariance():
    rng = np.random.default_rng(11)
    p = np.array([1.5, 15.0, -0.3])
    r0 = np.linalg.norm(ANCHORS - p, axis=1)
    errs, covs = [], []
    for _ in range(400):
        fix = ls_fix(ANCHORS, r0 + rng.normal(0, 0.05, 4), np.full(4, 0.05), np.array([1.0, 14.0, -0.3]))
        errs.append(fix.pos_ned_m[:2] - p[:2])
        covs.append(fix.cov_ne_m2)
    errs = np.array(errs)
    nees = np.mean([e @ np.linalg.solve(c, e) for e, c in zip(errs, covs)])
    assert 1.7 < nees < 2.3  # mean NEES of 2 dof over 400 runs: SD 0.1, +-3 SD band


def test_too_few_ranges_or_bad_geometry():
    assert not ls_fix(ANCHORS[:2], np.array([5.0, 5.0]), np.full(2, 0.1), np.zeros(3)).ok
    line = np.array([[0.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 20.0, 0.0]])  # collinear with p
    p = np.array([0.0, 5.0, 0.0])
    fix = ls_fix(line, np.linalg.norm(line - p, axis=1), np.full(3, 0.1), np.array([0.5, 4.0, 0.0]))
    assert not fix.ok


def test_fix_sensitivity_matches_finite_differences():
    """The fix rows for the FLOOR and CAL states equal the fix's change under a small floor error
    or per-anchor range bias (the LS fix is linear in them to first order)."""
    from tpos_cli.ranging.filter import fix_events

    anchors = np.array([[0.0, -3.0, -2.5], [10.0, 3.0, -2.4], [20.0, -3.0, -2.6], [30.0, 3.0, -2.5]])
    node = np.array([12.0, 0.5, 0.0])
    sd = np.array([0.05, 0.06, 0.07, 0.08])
    r = np.linalg.norm(anchors - node, axis=1)
    fix = ls_fix(anchors, r, sd, node + [0.3, -0.2, 0.0])
    ev, missing = fix_events(np.zeros(4), np.arange(4), r, sd, anchors, node[2], 4, 0.02)  # one epoch, one fix
    assert missing == 0 and len(ev) == 1
    np.testing.assert_allclose(ev.z[0, :2], fix.pos_ned_m[:2], atol=1e-9)
    np.testing.assert_allclose(ev.R[0, :2, :2], fix.cov_ne_m2, rtol=1e-9)
    S = ev.sens[0]
    h = 1e-4
    for i in range(4):  # bias on anchor i's range: fix moves by K[:, i] h
        rb = r.copy()
        rb[i] += h
        moved = ls_fix(anchors, rb, sd, node).pos_ned_m[:2] - fix.pos_ned_m[:2]
        np.testing.assert_allclose(moved / h, S[:, 1 + i], atol=1e-3)  # second-order term ~ h / range
    # floor error +h (the fix holds down at node_d + h, truth at node_d): fix moves by -K h_d h;
    # the filter's z = INS - fix sees +K h_d per unit floor error
    moved = ls_fix(anchors, r, sd, node + [0.0, 0.0, h]).pos_ned_m[:2] - fix.pos_ned_m[:2]
    np.testing.assert_allclose(-moved / h, S[:, 0], atol=1e-3)
