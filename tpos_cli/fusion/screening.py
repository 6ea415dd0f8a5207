"""Wild GPS fixes found before the filter (issue 18: one fix kilometres off, even the first).

A fix is wild when its neighbours, which agree among themselves, place it far from where it is:
each of up to `k` fixes on either side predicts it along a local constant-velocity track (the
median of the neighbours' pairwise velocities, which excludes the fix itself), and the fix goes
when the median prediction misses it by more than `abs_m` + `n_sigma` x its horizontal SD. An
isolated jump (a fix moved 11 km, a fix at 0, 0, 0) goes before it can capture the alignment or
the GPS noise estimate; a stretch of many mutually consistent fixes is left to the filter's gate.
"""

from __future__ import annotations

import numpy as np

from tpos_cli.frames.geodetic import lla_to_ned


def _misses(t, ned, usable, cand, k, max_span_s) -> np.ndarray:
    """Horizontal miss (m) of each candidate fix (usable ones) by the median prediction of its
    usable neighbours: the k on either side within max_span_s, all candidates at once (rows of
    2k neighbours, NaN where one is missing)."""
    miss = np.zeros(t.size)
    idx = np.flatnonzero(usable)
    if not cand.size or idx.size < 3:
        return miss
    offs = np.concatenate((np.arange(-k, 0), np.arange(1, k + 1)))
    j = np.searchsorted(idx, cand)[:, None] + offs
    valid = (j >= 0) & (j < idx.size)
    nb = idx[np.clip(j, 0, idx.size - 1)]
    valid &= np.abs(t[nb] - t[cand, None]) <= max_span_s
    a, b = np.triu_indices(offs.size, 1)  # pairs in time order
    dt = t[nb[:, b]] - t[nb[:, a]]
    pair = valid[:, a] & valid[:, b] & (dt > 0)
    rows = (valid.sum(axis=1) >= 2) & pair.any(axis=1)
    if not rows.any():
        return miss
    nb, valid, pair, dt, c = nb[rows], valid[rows], pair[rows], dt[rows], cand[rows]
    vel = (ned[nb[:, b], :2] - ned[nb[:, a], :2]) / np.where(pair, dt, 1.0)[..., None]
    v = np.nanmedian(np.where(pair[..., None], vel, np.nan), axis=1)
    pred = ned[nb, :2] + (t[c, None] - t[nb])[..., None] * v[:, None, :]
    pred = np.nanmedian(np.where(valid[..., None], pred, np.nan), axis=1)
    miss[c] = np.hypot(*(ned[c, :2] - pred).T)
    return miss


def wild_fixes(t_s, lla_deg, sigma_h_m=None, *, k: int = 3, abs_m: float = 10.0, n_sigma: float = 5.0,
               max_span_s: float = 10.0) -> np.ndarray:
    """(M,) bool: the fixes that their neighbours (within k fixes and max_span_s) place more than
    abs_m + n_sigma x sigma_h_m away; non-finite or impossible coordinates are wild too. The worst
    fix of each run of suspects goes first and the rest are tested again without it (a wild fix
    also corrupts its neighbours' tracks)."""
    t = np.asarray(t_s, dtype=float)
    lla = np.asarray(lla_deg, dtype=float)
    n = t.size
    ok = np.isfinite(lla).all(axis=1) & (np.abs(lla[:, 0]) <= 90.0) & (np.abs(lla[:, 1]) <= 180.0)
    bad = ~ok
    if ok.sum() < 4:
        return bad
    # the median fix as origin: a wild first fix must not be the centre of the local frame
    ned = np.full((n, 3), np.nan)
    ned[ok] = lla_to_ned(lla[ok], np.median(lla[ok], axis=0))
    thr = abs_m + n_sigma * (np.zeros(n) if sigma_h_m is None else np.nan_to_num(np.asarray(sigma_h_m, dtype=float)))
    cand = np.flatnonzero(ok)
    while cand.size:
        miss = _misses(t, ned, ~bad, cand, k, max_span_s)
        sus = cand[miss[cand] > thr[cand]]
        if not sus.size:
            break
        # the worst of each run of adjacent suspects
        runs = np.split(sus, np.flatnonzero(np.diff(np.searchsorted(np.flatnonzero(~bad), sus)) > 1) + 1)
        worst = np.array([r[np.argmax(miss[r] - thr[r])] for r in runs])
        bad[worst] = True
        cand = np.setdiff1d(sus, worst)  # only suspects can change their verdict
    return bad
