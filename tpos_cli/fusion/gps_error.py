"""Time-correlated GPS position error: the size of the Gauss-Markov error states, fitted to the log.

Receiver position errors wander (multipath, SBAS corrections, the receiver's own filter): on the
navego rover log the fix-minus-truth error has an SD of about 0.6 m and a 10-s autocorrelation
of 0.6-0.8, while the fix-to-fix scatter that covariance matching (`fusion.gps_noise`) sees is
0.2 m. The filter carries the wander as three first-order Gauss-Markov states (NED, stationary
SD sigma_gm, time constant tau; `fusion._kernels.insgps_kernel` with an 18-state P0), so that
the INS bridges outages relative to the wandering fixes and the reported SDs include the wander.

sigma_gm is fitted by maximum likelihood on the innovations (prediction-error decomposition,
Schweppe 1965; Mehra 1970, Sec. 2): for a linear Gaussian model the innovations nu_k are
independent N(0, S_k), so
    log L(theta) = -1/2 sum_k (log det S_k + nu_k^T S_k^-1 nu_k) + const
is the exact likelihood of the fixes given the IMU, for the parameters theta of the error model.
Here theta = (r, tau): r the ratio of the correlated SD to the white SD of each axis, with the
white SDs from covariance matching; log L is evaluated on a grid of r and tau on decimated filter
passes (their only product is the innovations), and r refined by a parabola in log r around the
best grid point; the states are kept only when a likelihood-ratio test rejects the white model
(2 log L gain above the chi-square 99% quantile at 2 d.o.f.). The caller matches the white part again with the states on. The innovations
see the wander through its change over the INS's own drift horizon, so log L mostly pins the
drift rate sigma^2 / tau; on navego its maximum (tau 100 s, sigma_h 0.43 m) is below the truth
comparison (0.6 m, autocorrelation 0.4 at 30 s) but within a factor 1.5.

What the log cannot tell: an error slower than the log's INS drift horizon (a constant offset
over a whole short log) is indistinguishable from the trajectory; the fit then finds r small and
the reported SDs cannot cover it. That is the fixes' absolute accuracy, which only a reference
(a surveyed point, the receiver's own accuracy figure) can give: `gps_gm_sigma_h_m` sets it.
When the log gives no SDs, the pipeline's stated accuracy (`gps_sigma_h_m`, `gps_sigma_v_m`) is
that figure: `unmodelled_error_sd_m` is the part of it that neither the matched white noise nor the
error states carry, and the chain adds it to the reported position SDs (a considered bias).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tpos_cli.fusion.engine import FilterConfig, InitialState, Measurements
from tpos_cli.fusion.gps_noise import pass_window
from tpos_cli.fusion.insgps import GpsFixes, gps_error_layout, gps_innovations, run_insgps

RATIO_GRID = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0)  # sigma_gm / sigma_white tried
TAU_GRID_S = (10.0, 30.0, 100.0, 300.0)  # time constants tried


@dataclass(frozen=True)
class GpsErrorFit:
    """Outcome of `fit_gps_error`: ratio r (sigma_gm / sigma_white, both groups), the SDs (m)
    sigma_gm_ned_m (3,), tau_s, and the profile: grid (K,) of r, taus (T,) with log-likelihoods
    (T, K) relative to r = 0 (NaN past a row's maximum: not evaluated), over n_fixes fixes."""

    ratio: float
    sigma_gm_ned_m: np.ndarray
    tau_s: float
    grid: np.ndarray
    taus: np.ndarray
    loglik: np.ndarray
    n_fixes: int

    def summary(self) -> dict:
        return {"method": "maximum likelihood of the innovations over sigma_gm / sigma_white (fusion.gps_error)",
                "tau_s": self.tau_s, "ratio": round(float(self.ratio), 3),
                "sigma_h_m": round(float(self.sigma_gm_ned_m[0]), 4), "sigma_v_m": round(float(self.sigma_gm_ned_m[2]), 4),
                "profile": {"ratio": [float(g) for g in self.grid], "tau_s": [float(v) for v in self.taus],
                            "loglik": [[None if not np.isfinite(v) else round(float(v), 2) for v in row]
                                       for row in self.loglik]},
                "fixes": self.n_fixes}


def unmodelled_error_sd_m(stated_ned_m, white_ned_m, gm_ned_m=None) -> np.ndarray:
    """Per-axis SD (m, NED) of the fixes' error that the filter does not model: what the stated
    accuracy leaves once the white SD (covariance matching) and the Gauss-Markov SD are taken out,
        sigma_c^2 = max(sigma_stated^2 - sigma_white^2 - sigma_gm^2, 0).
    Covariance matching sees only the fix-to-fix scatter (0.1 m on comma2k19, 0.2 m on the navego
    rover, whose fixes sit 0.46 and 0.97 m off truth), so the rest of a receiver's error is common
    to neighbouring fixes. A solution tied to the fixes carries it in full (sensitivity 1: the INS
    follows the fixes at every frequency below its drift horizon), so its position covariance
    gets sigma_c^2 added: a considered bias (Schmidt), which widens the SDs and moves no estimate."""
    stated = np.asarray(stated_ned_m, dtype=float)
    rest = stated ** 2 - np.asarray(white_ned_m, dtype=float) ** 2
    if gm_ned_m is not None:
        rest = rest - np.asarray(gm_ned_m, dtype=float) ** 2
    return np.sqrt(np.clip(rest, 0.0, None))


def velocity_span_s(P9, two_sided: bool) -> np.ndarray:
    """(K, 3) span T (s) over which a solution takes its velocity from the fixes, per NED axis, from
    its own position and velocity SDs (P9 without considered errors): a least-squares line through
    N fixes of variance R spread over T has slope variance 12 R / (N T^2) and, at the span's end
    (a filter), position variance 4 R / N, at its centre (a smoother) R / N; so
    T = sqrt(3) sigma_p / sigma_v one-sided, sqrt(12) sigma_p / sigma_v two-sided."""
    d = np.diagonal(np.asarray(P9, dtype=float), axis1=-2, axis2=-1)
    ratio = np.sqrt(np.clip(d[..., 0:3], 0.0, None) / np.clip(d[..., 3:6], 1e-300, None))
    return (np.sqrt(12.0) if two_sided else np.sqrt(3.0)) * ratio


def matched_tau_bound_s(sigma_c_m, white_m, matched_span_s) -> np.ndarray:
    """Least time constant (s, per axis) of a first-order Gauss-Markov error of SD sigma_c
    (`unmodelled_error_sd_m`) that covariance matching would have left out of its white SD
    `white_m`: the matching's filter anchors on the fixes over `matched_span_s` (`velocity_span_s`
    of the forward run), and an error changing over T by
        Var(b(t + T) - b(t)) = 2 sigma_c^2 (1 - exp(-T / tau))
    more than the white variance would have been matched as white; so
        2 sigma_c^2 (1 - exp(-T_m / tau)) <= white^2.
    0 where white^2 >= 2 sigma_c^2 (no bound: any tau fits) or sigma_c is 0."""
    sc2 = np.asarray(sigma_c_m, dtype=float) ** 2
    x = np.asarray(white_m, dtype=float) ** 2 / np.where(sc2 > 0, 2.0 * sc2, 1.0)
    ok = (sc2 > 0) & (x < 1.0)
    return np.where(ok, np.asarray(matched_span_s, dtype=float) / -np.log1p(-np.where(ok, x, 0.5)), 0.0)


def unmodelled_velocity_var(sigma_c_m, tau_s, span_s) -> np.ndarray:
    """Velocity variance ((m/s)^2, per axis) that the fixes' unmodelled error, a first-order
    Gauss-Markov error of SD sigma_c (`unmodelled_error_sd_m`) and time constant tau, gives a
    solution taking its velocity from the fixes over `span_s` (`velocity_span_s`): the slope the
    error puts on the fixes over T,
        Var = 2 sigma_c^2 (1 - exp(-T / tau)) / T^2,
    which falls with tau: with tau the least the matching allows (`matched_tau_bound_s`) it is the
    worst case (tau 0: 2 sigma_c^2 / T^2). A considered error (Schmidt): it widens the velocity SDs
    and moves no estimate; 0 where sigma_c is 0 (a receiver that states its SDs)."""
    T = np.clip(np.asarray(span_s, dtype=float), 1e-9, None)
    tau = np.asarray(tau_s, dtype=float)
    frac = 1.0 - np.exp(-T / np.where(tau > 0, tau, 1.0)) * (tau > 0)
    return 2.0 * np.asarray(sigma_c_m, dtype=float) ** 2 * frac / T ** 2


def innovation_loglik(run, count, gate_1: float = 15.137) -> float:
    """-1/2 sum (log det S + NIS) over the position and velocity parts of the fixes in `count`,
    each NIS capped at gate_1 per degree of freedom (one multipath jump must not decide the fit)."""
    gi = gps_innovations(run, count.size)
    ld = gi.logdet[count]
    nis = gi.nis[count]
    dof = np.column_stack([np.isfinite(gi.innovation[count][:, :3]).sum(axis=1),
                           np.isfinite(gi.innovation[count][:, 3:]).sum(axis=1)])
    ok = np.isfinite(ld) & np.isfinite(nis)
    return float(-0.5 * np.sum((ld + np.minimum(nis, gate_1 * dof))[ok]))


def fit_gps_error(t_s, gyro_b_rps, acc_b_mps2, fixes: GpsFixes, init: InitialState, cfg: FilterConfig, *,
                  taus_s=TAU_GRID_S, after_s: float | None = None, span_s: float = 900.0, rate_hz: float = 25.0,
                  grid=RATIO_GRID, test_probability: float = 0.99, extra: Measurements | None = None) -> GpsErrorFit:
    """Fit the correlated-error SD and time constant by maximum likelihood (module docstring).
    `fixes` carry the white SDs (as matched); the correlated SD per axis is r times the fixes'
    median white SD. `grid` must start with 0 (the white model, the reference of the profile).
    The states are kept (r > 0) only when the best log L beats the white model's by more than
    half the chi-square quantile `test_probability` at 2 d.o.f. (a likelihood-ratio test).
    `extra`: the motion-constraint rows of the final filter (its layout in `cfg`), so that the
    passes see the innovations that filter will see."""
    from scipy.special import chdtri  # not scipy.stats (import time)

    min_gain = 0.5 * float(chdtri(2, 1.0 - test_probability))
    td, gd, ad, fixes, count, rate_d = pass_window(t_s, gyro_b_rps, acc_b_mps2, fixes, after_s, span_s, rate_hz)
    sw = np.median(fixes.sigma_pos_ned_m, axis=0)
    grid = np.asarray(grid, dtype=float)
    taus = np.asarray(taus_s, dtype=float)
    if grid[0] != 0.0:
        raise ValueError("`grid` must start with 0")

    def loglik(r, tau):
        pcfg = dataclasses.replace(cfg, cov_step=max(1, int(round(rate_d))), layout=gps_error_layout(r * sw, tau, cfg.layout))
        return innovation_loglik(run_insgps(td, gd, ad, fixes, init, pcfg, store_rts=False, extra=extra), count)

    ll0 = loglik(0.0, taus[0])  # the white model: tau plays no part
    ll = np.full((taus.size, grid.size), np.nan)
    ll[:, 0] = 0.0
    for it, tau in enumerate(taus):
        for i in range(1, grid.size):
            ll[it, i] = loglik(grid[i], tau) - ll0
            if ll[it, i] < ll[it, i - 1]:
                break  # past the maximum in r (the profile is unimodal): the rest only costs passes
    it, j = np.unravel_index(int(np.nanargmax(ll)), ll.shape)
    if ll[it, j] <= min_gain:
        # likelihood-ratio test against the white model (2 extra parameters): without a clear
        # gain the states would only blur the fixes (on white simulated GPS they cost 15% inside
        # a 30 s outage when fitted to noise)
        return GpsErrorFit(0.0, np.zeros(3), float(taus[it]), grid, taus, ll, int(count.sum()))
    r = float(grid[j])
    y = ll[it]
    if 0 < j < grid.size - 1 and grid[j - 1] > 0:
        # parabola through the three points in log r: its maximum between the neighbours
        x = np.log(grid[j - 1: j + 2])
        yy = y[j - 1: j + 2]
        den = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
        a = (x[2] * (yy[1] - yy[0]) + x[1] * (yy[0] - yy[2]) + x[0] * (yy[2] - yy[1])) / den
        b = (x[2] ** 2 * (yy[0] - yy[1]) + x[1] ** 2 * (yy[2] - yy[0]) + x[0] ** 2 * (yy[1] - yy[2])) / den
        if a < 0:
            r = float(np.exp(np.clip(-b / (2 * a), x[0], x[2])))
    return GpsErrorFit(r, r * sw, float(taus[it]), grid, taus, ll, int(count.sum()))
