"""Least-squares position fix from ranges to anchors (the WSN position of paper 002, Eq. 7-8).

Gauss-Newton on `rho_i = |p - a_i|` for the horizontal position (north, east) with the down
coordinate held at a given value: the anchors of a corridor lie near one plane, so the vertical is
not observable from ranges alone, and a vehicle on a floor knows its height. With that, three
anchors give a fix with one redundant range; the paper's loosely coupled filter needs
"more than three" ranges on a plane (Sec. 2.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.ranging._kernels import FIX_FAILED, FIX_OK, epoch_numbers, gauss_newton_fix


@dataclass(frozen=True)
class Fix:
    """One epoch's fix: pos_ned_m (3,), cov_ne_m2 (2, 2), rms residual, success flag."""

    pos_ned_m: np.ndarray
    cov_ne_m2: np.ndarray
    residual_rms_m: float
    ok: bool
    cov_ned_m2: np.ndarray | None = None


def ls_fix(
    anchors_ned_m: np.ndarray,
    range_m: np.ndarray,
    sigma_m: np.ndarray,
    guess_ned_m: np.ndarray,
    *,
    max_iter: int = 50,
    tol_m: float = 1e-6,
    max_pdop: float = 10.0,
    solve_down: bool = False,
) -> Fix:
    """Weighted Gauss-Newton horizontal fix; down stays at `guess_ned_m[2]` unless `solve_down`.

    anchors_ned_m : (k, 3); range_m, sigma_m : (k,); guess_ned_m : (3,) starting point.
    `ok` is False with fewer than 3 ranges (4 with `solve_down`), on non-convergence or when
    the geometry is poor (sqrt(trace(cov)) / sigma above max_pdop). `cov_ne_m2` is the
    (north, east) block; with `solve_down` the full 3x3 covariance is in `cov_ned_m2`.
    Compiled: `_kernels.gauss_newton_fix`.
    """
    a = np.ascontiguousarray(anchors_ned_m, dtype=float).reshape(-1, 3)
    r = np.ascontiguousarray(range_m, dtype=float)
    s = np.ascontiguousarray(sigma_m, dtype=float)
    p = np.array(guess_ned_m, dtype=float)
    nd = 3 if solve_down else 2
    cov = np.empty((nd, nd))
    status, rms = gauss_newton_fix(a, r, s, r.size, p, nd, int(max_iter), float(tol_m), float(max_pdop), cov,
                                   np.empty((6, max(r.size, 3))), np.empty((2, nd, nd)))
    if status == FIX_FAILED:
        return Fix(np.full(3, np.nan), np.full((2, 2), np.nan), np.nan, False)
    return Fix(p, cov[:2, :2].copy(), float(rms), status == FIX_OK, cov if solve_down else None)


def group_epochs(t_s: np.ndarray, window_s: float) -> np.ndarray:
    """Epoch number of each (time-sorted) range: a new epoch starts more than `window_s` after
    the first range of the current one (anchors answering one poll share an epoch)."""
    return epoch_numbers(np.ascontiguousarray(t_s, dtype=float), float(window_s))


def epoch_bounds(epoch: np.ndarray) -> np.ndarray:
    """Start indices of each epoch of a sorted `group_epochs` result, plus the end: epoch e is
    rows bounds[e]:bounds[e + 1]."""
    return np.flatnonzero(np.diff(epoch, prepend=-1, append=epoch[-1] + 1 if epoch.size else 0))
