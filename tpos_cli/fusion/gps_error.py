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


# Time constant of the correlated part of a receiver's stated error (`stated_split`), a physical
# prior, not fitted: carrier-phase multipath from a reflector h metres from the antenna fades with
# period lambda / (2 h omega_sat) (L1 0.19 m, a satellite's elevation rate omega ~1.5e-4 rad/s:
# 650 s at 1 m, 130 s at 5 m), and residual atmosphere over a short baseline is slower still; 100 s,
# the middle of TAU_GRID_S, is the shorter (cautious) end of that range for an antenna on a vehicle.
STATED_SPLIT_TAU_S = 100.0


@dataclass(frozen=True)
class StatedSplit:
    """Outcome of `stated_split` per group (horizontal, vertical): the white SD and the correlated
    (Gauss-Markov) SD (m) whose variances add up to the stated one, the stated SD (m) and the
    measured half mean square of consecutive fixes' differences at rest (m^2), over n_diffs
    differences (0 for a group not split: its SDs stay white as stated)."""

    white_m: np.ndarray
    gm_m: np.ndarray
    stated_m: np.ndarray
    half_diff_ms: np.ndarray
    n_diffs: np.ndarray
    tau_s: float

    def summary(self) -> dict:
        return {"method": "the receiver's stated SD split into white (the fixes' fix-to-fix scatter at rest) and a "
                          "Gauss-Markov error state (the rest of the stated variance); fusion.gps_error.stated_split",
                "tau_s": self.tau_s,
                **{f"{k}_{g}_m": round(float(v[i]), 4) for k, v in (("white", self.white_m), ("gm", self.gm_m),
                                                                   ("stated", self.stated_m),
                                                                   ("half_diff_rms", np.sqrt(self.half_diff_ms)))
                   for i, g in enumerate(("h", "v"))},
                "differences": {g: int(n) for g, n in zip(("h", "v"), self.n_diffs)}}


def white_variance_at_rest(half_diff_ms, stated_var, dt_s, tau_s) -> np.ndarray:
    """White variance sigma_w^2 of fixes whose error is white plus first-order Gauss-Markov with
    sigma_w^2 + sigma_b^2 = stated_var, from the half mean square D of consecutive fixes'
    differences at rest (the position is constant, so a difference is the error's change):
        D = sigma_w^2 + sigma_b^2 (1 - rho),  rho = exp(-dt / tau)
        => sigma_w^2 = (D - stated_var (1 - rho)) / rho,
    clipped to [0, stated_var] (a scatter above the stated SD leaves it all white)."""
    rho = np.exp(-np.asarray(dt_s, dtype=float) / float(tau_s))
    w2 = (np.asarray(half_diff_ms, dtype=float) - np.asarray(stated_var, dtype=float) * (1.0 - rho)) / rho
    return np.clip(w2, 0.0, np.asarray(stated_var, dtype=float))


def stated_split(t_s, ned_m, sigma_pos_ned_m, intervals_s, stated_groups, *, tau_s: float = STATED_SPLIT_TAU_S,
                 min_fixes: int = 8, floor_m: float = 1e-3, test_probability: float = 0.99) -> StatedSplit:
    """Split the fixes' stated position SD (per group: horizontal N/E pooled, vertical) into a
    white part, the fixes' own fix-to-fix scatter where the platform stood still (the detected
    stops `intervals_s`, (K, 2) s, each with >= `min_fixes` fixes), and a Gauss-Markov part
    carrying the rest of the stated variance (`white_variance_at_rest`): at rest the fixes of a
    receiver stating 10 mm scatter 2-4 mm fix to fix (their slow error is common to the stop), and
    a white model with the stated SD treats each fix as independent, while dropping the rest would
    write sigmas under the receiver's accuracy. The stated SD of the split is the median over the
    stops' fixes. `stated_groups` (2,) bool: the groups whose SDs the receiver stated (a pipeline
    default is no accuracy to split); a group without enough fixes at rest stays white.
    `min_fixes` 8: an SD from 7 differences is good to about 25 % (a generic minimum, not tuned);
    `floor_m` 1 mm: only so that a constant stretch cannot give a zero white SD.
    A group is split only when its scatter at rest is significantly under the stated SD: the white
    hypothesis (all of the stated variance white) is rejected when n_eff D / s^2 falls under the
    chi-square quantile 1 - `test_probability` at n_eff d.o.f., n_eff = n / 1.5 (consecutive
    differences of white errors correlate -0.5, their squares 0.25: the mean of n squares has the
    variance of n / 1.5 independent ones); a white receiver's 15 fixes at rest scatter within
    +-40 % of its SD by chance (a 0.5 m state from 28 differences on a simulated 1.5 m one)."""
    from scipy.special import chdtri  # not scipy.stats (import time)

    t = np.asarray(t_s, dtype=float)
    ned = np.asarray(ned_m, dtype=float)
    sig = np.asarray(sigma_pos_ned_m, dtype=float)
    sq = [[], []]
    stated = [[], []]
    dts = []
    for a, b in np.asarray(intervals_s, dtype=float).reshape(-1, 2):
        idx = np.flatnonzero((t >= a) & (t <= b))
        if idx.size < min_fixes:
            continue
        d = np.diff(ned[idx], axis=0)
        sq[0].append(d[:, :2].ravel() ** 2)
        sq[1].append(d[:, 2] ** 2)
        stated[0].append(sig[idx, :2].ravel())
        stated[1].append(sig[idx, 2])
        dts.append(np.diff(t[idx]))
    white, gm, st, half, n = np.zeros(2), np.zeros(2), np.full(2, np.nan), np.full(2, np.nan), np.zeros(2, dtype=np.int64)
    dt = float(np.median(np.concatenate(dts))) if dts else 1.0
    for g in range(2):
        if not sq[g] or not stated_groups[g]:
            continue
        x = np.concatenate(sq[g])
        x = x[np.isfinite(x)]
        if x.size < min_fixes - 1:
            continue
        half[g] = 0.5 * float(np.mean(x))
        st[g] = float(np.median(np.concatenate(stated[g])))
        n[g] = x.size
        n_eff = x.size / 1.5
        if n_eff * half[g] / st[g] ** 2 >= float(chdtri(n_eff, test_probability)):
            continue  # consistent with white fixes at the stated SD: nothing to split
        w2 = max(float(white_variance_at_rest(half[g], st[g] ** 2, dt, tau_s)), floor_m ** 2)
        white[g] = np.sqrt(min(w2, st[g] ** 2))
        gm[g] = np.sqrt(max(st[g] ** 2 - w2, 0.0))
    return StatedSplit(white, gm, st, half, n, float(tau_s))


def white_sds(sigma_pos_ned_m, split: StatedSplit) -> np.ndarray:
    """(N, 3) the fixes' white position SDs under `split`: each fix keeps its stated variance,
    less the Gauss-Markov part, sigma_w,i^2 = max(sigma_i^2 - sigma_b^2, sigma_w^2) (a float
    stretch stating decimetres stays mostly white; a fix stating less than the split's median
    keeps the measured white SD)."""
    sig = np.asarray(sigma_pos_ned_m, dtype=float)
    gm = split.gm_m[[0, 0, 1]]
    w = split.white_m[[0, 0, 1]]
    out = np.sqrt(np.maximum(sig ** 2 - gm ** 2, w ** 2))
    return np.where(gm > 0, out, sig)
