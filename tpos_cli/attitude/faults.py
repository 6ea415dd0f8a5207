"""Fault detection for the local filters, beyond paper 000 (whose FKF keeps mixing a failed LF1).

A local filter is declared faulty at a sample when
- its own aiding sensor fails a physical check: LF1's field magnitude or dip angle is off the
  undisturbed reference (`AttitudeSolution.mag_ok`; only when LF1 did not already drop those
  samples itself, `mag_gated`: a gated LF1 just coasts on the gyro, and its growing yaw variance
  down-weights it in Eq. 27 by itself), LF2's range differences fail their
  innovation gate (non-planar surface, glass, a beam off the wall); or
- the NIS of its updates, summed over a trailing window, exceeds the chi-square bound of that
  window (a step in the aiding measurement, e.g. the paper's 60 deg yaw fault).
It stays faulty until the physical check has passed for `recover_s` AND its attitude agrees with
the healthy filters again (chi-square(3) test of the difference, `master.difference_cov`). A fault that the
local filter has absorbed (it converged onto the wrong heading) is therefore still excluded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.stats import chi2

from tpos_cli.attitude.local import AttitudeSolution
from tpos_cli.attitude.master import consistency_nis

NIS_DOF = {"acc": 3, "mag": 3, "range": 2, "obs": 2}


@dataclass(frozen=True)
class FaultConfig:
    nis_window_s: float = 1.0
    nis_probability: float = 0.9999
    consistency_probability: float = 0.9999
    recover_s: float = 2.0


@dataclass(frozen=True)
class FaultReport:
    """ok (S, N) bool per local filter and sample; alarm_nis, sensor_bad (S, N) the causes."""

    names: tuple
    ok: np.ndarray
    alarm_nis: np.ndarray
    sensor_bad: np.ndarray

    def weights(self):
        return self.ok.astype(float)


def _nis_alarm(t_s, nis: dict, cfg: FaultConfig) -> np.ndarray:
    """True where a trailing-window sum of NIS exceeds its chi-square quantile."""
    n = t_s.size
    alarm = np.zeros(n, dtype=bool)
    dt = float(np.median(np.diff(t_s))) if n > 1 else 0.01
    W = max(1, int(round(cfg.nis_window_s / dt)))
    for key, v in nis.items():
        if key not in NIS_DOF or v is None:
            continue
        have = np.isfinite(v)
        if not have.any():
            continue
        cs = np.concatenate([[0.0], np.cumsum(np.where(have, v, 0.0))])
        cc = np.concatenate([[0], np.cumsum(have)])
        i = np.arange(n)
        lo = np.maximum(i + 1 - W, 0)
        s = cs[i + 1] - cs[lo]
        c = cc[i + 1] - cc[lo]
        bound = np.where(c > 0, chi2.ppf(cfg.nis_probability, np.maximum(c, 1) * NIS_DOF[key]), np.inf)
        alarm |= (c > 0) & (s > bound)
    return alarm


def detect(sols: list[AttitudeSolution], cfg: FaultConfig = FaultConfig(), range_gate_chi2: float = 0.0,
           acc_bias_var: float = 0.0) -> FaultReport:
    """Run the detector over local solutions sharing one time axis; see the module docstring. `acc_bias_var`
    (m/s^2)^2: the accelerometer bias the solutions carry as a sensitivity (`master.consistency_nis`)."""
    S = len(sols)
    t = sols[0].t_s
    n = t.size
    alarm = np.zeros((S, n), dtype=bool)
    bad = np.zeros((S, n), dtype=bool)
    for i, s in enumerate(sols):
        alarm[i] = _nis_alarm(t, s.nis, cfg)
        if s.mag_ok is not None and not s.mag_gated:
            bad[i] |= ~s.mag_ok  # the filter ingested a disturbed field: exclude it meanwhile
        r = s.nis.get("range")
        if r is not None and range_gate_chi2 > 0:
            bad[i] |= np.isfinite(r) & (r > range_gate_chi2)
    thr = chi2.ppf(cfg.consistency_probability, 3)
    cons = np.ones((S, S, n), dtype=bool)
    for i in range(S):
        for j in range(i + 1, S):
            c = consistency_nis(sols[i], sols[j], acc_bias_var) < thr
            cons[i, j] = cons[j, i] = c
    ok = np.ones((S, n), dtype=bool)
    _hold_faults(np.ascontiguousarray(t, dtype=float), alarm | bad, cons, float(cfg.recover_s), ok)
    return FaultReport(names=tuple(s.name for s in sols), ok=ok, alarm_nis=alarm, sensor_bad=bad)


@njit(cache=True)
def _hold_faults(t, trig, cons, recover_s, ok):
    """ok (S, N) in place: a filter turns faulty where `trig` and stays so until `recover_s` after its last
    trigger AND its attitude agrees (`cons` (S, S, N)) with every filter not faulty at that moment (the
    filters taken in order: one that recovers counts for the next)."""
    S, n = trig.shape
    faulty = np.zeros(S, dtype=np.bool_)
    last_bad = np.full(S, -np.inf)
    for k in range(n):
        for i in range(S):
            if trig[i, k]:
                faulty[i] = True
                last_bad[i] = t[k]
        for i in range(S):
            if not faulty[i] or t[k] - last_bad[i] < recover_s:
                continue
            agree = True
            for j in range(S):
                if j != i and not faulty[j] and not cons[i, j, k]:
                    agree = False
                    break
            if agree:
                faulty[i] = False
        for i in range(S):
            ok[i, k] = not faulty[i]
