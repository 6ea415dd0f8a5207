"""GPS noise from the log itself: covariance matching on a cheap first filter pass.

A receiver's stated SDs (or the pipeline's defaults when the log gives none) are rarely its
real noise. The innovations of an INS/GPS filter satisfy E[nu_i^2] = (H P- H^T)_ii + R_ii
(covariance matching, Mehra 1972, Eq. 3.9; paper 003 Eq. 3 gives S = H P- H^T + R), so R can
be read off a first pass. Per group g (horizontal position, vertical position, horizontal
velocity, vertical velocity) the variances used are s_g^2 sigma_i^2 (sigma_i: the fix's SD as
given), and s_g is the fixed point of
    m_g(s) = mean_i  nu_i^2 / (hph_i + s_g^2 sigma_i^2) = 1
where nu and hph come from a filter run with those scales (so a root search over runs, not one
formula: the filter's H P- H^T depends on the R it was run with, and subtracting the H P- H^T of
a run with too large an R from the innovations' scatter drives R to zero). The mean is over the
components whose normalized square stays under the 1-d.o.f. gate (multipath jumps must not
inflate the noise of the other fixes; the truncation bias at the 0.9999 quantile is < 0.1%).
A pass runs on the IMU decimated to about 25 Hz with 1 s covariance steps: its only product is
the innovations.

Time-correlated GPS errors (a receiver's own filter, multipath over minutes) are seen by the
innovations only through their change between fixes: the matched R then describes that part,
which keeps the NIS consistent but says nothing of the slow wander common to all fixes.

Fixes at a stop are matched apart from the moving ones (`rest_intervals_s`): standing, the fix-to-fix
scatter is the receiver's alone (no multipath change with motion, no INS error growth under a ZUPT), a
fraction of the moving scatter (part 1 of the 0708 drive: NIS 0.47 at its stops with one R for both,
2.9 moving), so one R cannot fit both regimes and the rows at stops the moving rows' R leaves under
the NIS band. A regime with too few components (`normalized_square`) takes the other's scales.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tpos_cli.fusion.engine import ENDS_ONLY, FilterConfig, InitialState, Measurements
from tpos_cli.fusion.initial import fixes_before
from tpos_cli.fusion.insgps import GpsFixes, gps_innovations, run_insgps
from tpos_cli.ins.mechanization import decimate_to_rate
from tpos_cli.timebase import in_intervals

GROUPS = ("pos_h", "pos_v", "vel_h", "vel_v")
_COLS = ((0, 1), (2,), (3, 4), (5,))  # innovation columns of each group
_GATE_1DOF = 15.137  # chi-square 1 d.o.f. quantile at 0.9999
# how many SDs of its mean m may sit off 1 before a group's SDs move: the receiver's own figures
# (3: evidence, overridden only on clear disagreement), the pipeline's defaults (1.96: the two-sided
# 95 % level of the NIS check, `chains.drive_smooth.nis_band`)
STATED_SD_Z = 3.0
DEFAULT_SD_Z = 1.96


@dataclass(frozen=True)
class GpsNoise:
    """Outcome of `estimate_gps_noise`: scale (4,) of the SDs per group (`GROUPS`; 1 where not
    estimated), n_used (4,) innovation components per group, passes run, and the median SDs of
    the scaled fixes: sigma (4,) [pos_h m, pos_v m, vel_h m/s, vel_v m/s] (NaN where absent)."""

    scale: np.ndarray
    n_used: np.ndarray
    passes: int
    sigma: np.ndarray
    normalized_square: np.ndarray  # (4,) the last pass's mean nu^2 / (H P- H^T + R) per group
    window_s: tuple  # (first, last) time of the fixes that counted
    # the fixes at stops (`rest_intervals_s`, session s): their own scales (4,) (= `scale` where not
    # estimated), components and last-pass m
    scale_at_rest: np.ndarray = dataclasses.field(default_factory=lambda: np.ones(4))
    n_used_at_rest: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(4, dtype=np.int64))
    normalized_square_at_rest: np.ndarray = dataclasses.field(default_factory=lambda: np.full(4, np.nan))
    rest_intervals_s: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))

    def per_fix(self, t_s) -> np.ndarray:
        """(M, 4) the scale of each fix at times `t_s`: `scale_at_rest` inside a stop, else `scale`."""
        rest = in_intervals(np.asarray(t_s, dtype=float), self.rest_intervals_s, closed=True)
        return np.where(rest[:, None], self.scale_at_rest[None, :], self.scale[None, :])

    def scaled(self, fixes: GpsFixes, inverse: bool = False) -> GpsFixes:
        """`fixes` with each one's SDs multiplied (divided, `inverse`) by its regime's scales."""
        s = self.per_fix(fixes.t_s)
        return scaled_fixes(fixes, 1.0 / s if inverse else s)

    def summary(self) -> dict:
        units = ("m", "m", "mps", "mps")
        out = {f"sigma_{g}_{u}": (None if not np.isfinite(s) else round(float(s), 4))
               for g, u, s in zip(GROUPS, units, self.sigma)}
        out["scale"] = {g: round(float(s), 4) for g, s in zip(GROUPS, self.scale)}
        out["n_used"] = {g: int(n) for g, n in zip(GROUPS, self.n_used)}
        out["passes"] = self.passes
        out["fixes_from_to_s"] = [round(float(v), 2) for v in self.window_s]
        out["last_pass_normalized_square"] = {g: (None if not np.isfinite(v) else round(float(v), 3))
                                              for g, v in zip(GROUPS, self.normalized_square)}
        out["at_rest"] = {"scale": {g: round(float(s), 4) for g, s in zip(GROUPS, self.scale_at_rest)},
                          "n_used": {g: int(n) for g, n in zip(GROUPS, self.n_used_at_rest)},
                          "last_pass_normalized_square": {g: (None if not np.isfinite(v) else round(float(v), 3))
                                                          for g, v in zip(GROUPS, self.normalized_square_at_rest)}}
        return out


def scaled_fixes(fixes: GpsFixes, scale) -> GpsFixes:
    """`fixes` with their SDs multiplied by the group scales (pos_h, pos_v, vel_h, vel_v): (4,), or
    (M, 4) one row per fix."""
    s = np.asarray(scale, dtype=float)
    return dataclasses.replace(fixes, sigma_pos_ned_m=fixes.sigma_pos_ned_m * s[..., [0, 0, 1]],
                               sigma_vel_mps=fixes.sigma_vel_mps * s[..., [2, 2, 3]])


def median_sigmas(fixes: GpsFixes) -> np.ndarray:
    """(4,) median SD per group of the fixes (velocity groups NaN when no fix has that velocity)."""
    vel = np.isfinite(fixes.vel_ned_mps)
    out = np.full(4, np.nan)
    if fixes.t_s.size:
        out[0] = np.median(fixes.sigma_pos_ned_m[:, :2])
        out[1] = np.median(fixes.sigma_pos_ned_m[:, 2])
    if vel[:, 0].any():
        out[2] = np.median(fixes.sigma_vel_mps[vel[:, 0], :2])
    if vel[:, 2].any():
        out[3] = np.median(fixes.sigma_vel_mps[vel[:, 2], 2])
    return out


def normalized_square(nu, hph, var) -> tuple[float, int]:
    """Trimmed mean of nu^2 / (hph + var) over the finite components under the 1-d.o.f. gate
    (1 when the noise model fits), and the number of components used (NaN when < 10)."""
    r = np.asarray(nu, dtype=float) ** 2 / (np.clip(np.asarray(hph, dtype=float), 0.0, None) + np.asarray(var, dtype=float))
    r = r[np.isfinite(r)]
    r = r[r < _GATE_1DOF]
    if r.size < 10:
        return float("nan"), int(r.size)
    return float(np.mean(r)), int(r.size)


def solve_scale(nu, hph, var) -> float:
    """s^2 with mean(nu^2 / (hph + s^2 var)) = 1 over the finite components under the 1-d.o.f.
    gate at the start value s^2 = 1, hph held fixed; NaN when there is no positive root."""
    nu2 = np.asarray(nu, dtype=float) ** 2
    hph = np.clip(np.asarray(hph, dtype=float), 0.0, None)
    var = np.asarray(var, dtype=float)
    ok = np.isfinite(nu2) & np.isfinite(hph) & np.isfinite(var) & (var > 0)
    ok[ok] = nu2[ok] / (hph[ok] + var[ok]) < _GATE_1DOF
    a, b, c = nu2[ok], hph[ok], var[ok]
    if a.size < 10 or np.mean(a / np.maximum(b, 1e-300)) <= 1.0:
        return float("nan")
    lo, hi = 1e-10, 1e10
    for _ in range(100):  # bisection in log s^2: the mean decreases with s^2
        mid = np.sqrt(lo * hi)
        if np.mean(a / (b + mid * c)) > 1.0:
            lo = mid
        else:
            hi = mid
    return float(np.sqrt(lo * hi))


def bracketed(log_s: float, hist) -> float:
    """`log_s` kept inside the bracket the passes `hist` [(log s, log m), ...] found: m falls as s
    grows, so the root lies above the largest log s with m > 1 and below the smallest with m < 1;
    a step that leaves that interval (a secant through two noisy, nearly equal m) is replaced by its
    midpoint (a safeguarded secant, as in Brent's method). Unchanged while one side is missing."""
    below = [ls for ls, lm in hist if lm > 0.0]
    above = [ls for ls, lm in hist if lm < 0.0]
    if not below or not above:
        return log_s
    a, b = max(below), min(above)
    if a < b and not a < log_s < b:
        return 0.5 * (a + b)
    return log_s


def pass_window(t_s, gyro_b_rps, acc_b_mps2, fixes: GpsFixes, after_s: float | None, span_s: float, rate_hz: float):
    """The stretch of log the cheap tuning passes run over: `span_s` from `after_s` (0 = all),
    IMU decimated to about `rate_hz`. Returns (t, gyro, acc, fixes, counted-fix mask, rate):
    only fixes after `after_s` count, unless fewer than 30 would remain."""
    t = np.asarray(t_s, dtype=float)
    start = t[0] if after_s is None else max(after_s, t[0])
    if span_s > 0 and start + span_s < t[-1]:
        i_end = int(np.searchsorted(t, start + span_s)) + 1
        t, gyro_b_rps, acc_b_mps2 = t[:i_end], gyro_b_rps[:i_end], acc_b_mps2[:i_end]
        fixes = fixes_before(fixes, t[-1])
    td, gd, ad, rate_d = decimate_to_rate(t, gyro_b_rps, acc_b_mps2, rate_hz)
    count = np.ones(fixes.t_s.size, dtype=bool)
    if after_s is not None and np.sum(fixes.t_s > after_s) >= 30:
        count = fixes.t_s > after_s
    return td, gd, ad, fixes, count, rate_d


def rows_within(rows: Measurements | None, t_end_s: float) -> Measurements | None:
    """The rows of `rows` a pass ending at `t_end_s` can process (t_s <= t_end_s; a run skips the
    later ones, `fusion.engine.run_filter`), so that each pass merges and sorts only those: the
    same run, the hour's constraint rows cut to the pass's quarter once instead of every pass."""
    if rows is None or not len(rows) or np.max(rows.t_s) <= t_end_s:
        return rows
    return rows.select(np.asarray(rows.t_s) <= t_end_s)


def last_secant(hist, lo: float, hi: float) -> float | None:
    """The log scale of one group after the matching loop stopped within its tolerance: a secant
    step on log m against log s between the group's latest pass and the latest pass at another
    scale (`hist` [(log s, log m), ...] in pass order), at most a factor 1.2 and inside the
    passes' bracket (`bracketed`) and [lo, hi]; None when the group never moved or the secant is
    not usably decreasing. The latest pass at another scale, not the pass before: a group that
    stopped while other groups moved on has its last passes at one scale (on the walk log the
    vertical position was left at m 1.35, its first step's landing inside the 3-SD band)."""
    if not hist:
        return None
    ls1, lm1 = hist[-1]
    other = [h for h in hist if h[0] != ls1]
    if not other:
        return None
    ls0, lm0 = other[-1]
    if (lm1 - lm0) / (ls1 - ls0) >= -0.05:
        return None
    step = -lm1 * (ls1 - ls0) / (lm1 - lm0)
    return bracketed(float(np.clip(ls1 + np.clip(step, -np.log(1.2), np.log(1.2)), lo, hi)), hist)


def estimate_gps_noise(t_s, gyro_b_rps, acc_b_mps2, fixes: GpsFixes, init: InitialState, cfg: FilterConfig, *,
                       after_s: float | None = None, span_s: float = 900.0, rate_hz: float = 25.0,
                       max_passes: int = 6, tol: float = 0.1, scale_bounds=(0.02, 50.0),
                       extra: Measurements | None = None, rest_intervals_s=None) -> GpsNoise:
    """Scales of the fixes' SDs per group from decimated forward passes (see the module docstring).

    Each pass gives, per group, the mean normalized innovation square m(s) (1 when consistent);
    the scale is moved by a secant step on log m against log s (the first step from this pass's
    innovations with its H P- H^T held fixed, every step kept inside the bracket of the passes so far,
    `bracketed`) until every |m - 1| < max(tol, z sqrt(2 / n)), z = `STATED_SD_Z` for SDs the
    receiver stated and `DEFAULT_SD_Z` for the pipeline's defaults. `after_s`: only fixes after this
    time count (the heading may still be converging before); ignored when fewer than 30 fixes would
    remain.
    `span_s`: the passes stop `span_s` after that (0 = whole log): 900 s give some 1800
    horizontal components, a variance to about 3%, and keep the passes cheap on long logs.
    `extra`: the motion-constraint rows of the final filter (its layout in `cfg`): matched on a
    filter without them, R would take the share of the innovations that the constraints remove
    (the final filter's GPS NIS then falls below its band).
    `rest_intervals_s`: the stops ((K, 2), the fixes' clock): their fixes are matched as groups of
    their own (see the module docstring), all of them, `after_s` or not (standing, a heading still
    converging moves no position).
    """
    td, gd, ad, fixes, count, rate_d = pass_window(t_s, gyro_b_rps, acc_b_mps2, fixes, after_s, span_s, rate_hz)
    # RTK float fixes are not white scatter at their stated SD (`fusion.rtk_float`): their offset state
    # carries their error, and they would inflate the matched R of every fix (a few decimetre rows in a
    # centimetre group); the matching sees the fixed epochs only
    fixed_epoch = ~in_intervals(fixes.t_s, cfg.float_intervals_s, closed=True)
    rest_iv = np.zeros((0, 2)) if rest_intervals_s is None else np.asarray(rest_intervals_s, dtype=float).reshape(-1, 2)
    rest = in_intervals(fixes.t_s, rest_iv, closed=True)
    counts = (count & fixed_epoch & ~rest, fixed_epoch & rest)  # per regime: moving, standing
    extra = rows_within(extra, td[-1])
    stated = np.tile(np.asarray(fixes.from_receiver, dtype=bool), 2)
    pcfg = dataclasses.replace(cfg, cov_step=max(1, int(round(rate_d))), nominal_idx=ENDS_ONLY)  # innovations only
    lo, hi = np.log(scale_bounds[0]), np.log(scale_bounds[1])
    # groups 0-3 the moving fixes' (`GROUPS`), 4-7 the same at stops
    log_s = np.zeros(8)
    hist: list[list[tuple[float, float]]] = [[] for _ in range(8)]
    m_last = np.full(8, np.nan)
    n_used = np.zeros(8, dtype=np.int64)

    def per_fix_scale(log_s):
        return np.exp(np.where(rest[:, None], log_s[None, 4:], log_s[None, :4]))

    passes = 0
    nus: list = [None, None]
    for passes in range(1, max_passes + 1):
        fx = scaled_fixes(fixes, per_fix_scale(log_s))
        run = run_insgps(td, gd, ad, fx, init, pcfg, store_rts=False, extra=extra)
        var_all = np.column_stack([fx.sigma_pos_ned_m, fx.sigma_vel_mps]) ** 2
        gi = gps_innovations(run, count.size)
        for r, sel in enumerate(counts):
            nus[r] = (gi.innovation[sel], gi.pvar[sel], var_all[sel])
            for k, cols in enumerate(_COLS):
                j, c = 4 * r + k, list(cols)
                m_last[j], n_used[j] = normalized_square(nus[r][0][:, c], nus[r][1][:, c], nus[r][2][:, c])
                if np.isfinite(m_last[j]):
                    hist[j].append((log_s[j], np.log(m_last[j])))
        # a group moves only when its m is off by more than `tol` and by z SDs of a mean of n
        # chi-square(1) / n values (sqrt(2 / n)): a consistent log keeps its SDs as given. z = 3
        # where the receiver stated them (its figure is evidence); the pipeline's default SDs are
        # a placeholder, kept only while m is consistent at the 95 % level the NIS check uses
        z = np.where(stated, STATED_SD_Z, DEFAULT_SD_Z)
        tol_g = np.maximum(tol, z * np.sqrt(2.0 / np.maximum(n_used, 1)))
        off = np.isfinite(m_last) & (np.abs(m_last - 1.0) >= tol_g)
        if not off.any() or passes == max_passes:
            break
        for j in range(8):
            if not hist[j] or not off[j]:
                continue
            ls1, lm1 = hist[j][-1]
            c = list(_COLS[j % 4])
            nu, hph, var = nus[j // 4]
            s2 = solve_scale(nu[:, c], hph[:, c], var[:, c] / np.exp(2.0 * ls1))
            # first step: the scale matching this pass's innovations with its H P- H^T held fixed;
            # where H P- H^T alone exceeds them (too large an R before), m ~ 1 / s^2
            step = 0.5 * np.log(s2) - ls1 if np.isfinite(s2) else 0.5 * lm1
            if len(hist[j]) >= 2:
                ls0, lm0 = hist[j][-2]
                if ls1 != ls0 and (lm1 - lm0) / (ls1 - ls0) < -0.05:  # a usable decreasing secant
                    step = -lm1 * (ls1 - ls0) / (lm1 - lm0)
            log_s[j] = bracketed(float(np.clip(ls1 + np.clip(step, -np.log(10.0), np.log(10.0)), lo, hi)), hist[j])
    for j in range(8):
        # the loop stops within the tolerance: a last secant step (no further pass) removes most
        # of that remainder for the groups that moved
        last = last_secant(hist[j], lo, hi)
        if last is not None:
            log_s[j] = last
    for k in range(4):  # a regime never matched (too few components) takes the other's scale
        if not hist[4 + k]:
            log_s[4 + k] = log_s[k]
        elif not hist[k]:
            log_s[k] = log_s[4 + k]
    moving = counts[0]
    return GpsNoise(np.exp(log_s[:4]), n_used[:4], passes, median_sigmas(scaled_fixes(fixes, np.exp(log_s[:4]))),
                    m_last[:4], (float(fixes.t_s[moving][0]), float(fixes.t_s[moving][-1])) if moving.any() else (np.nan, np.nan),
                    np.exp(log_s[4:]), n_used[4:], m_last[4:], rest_iv)
