"""The verdict on a run: "ok", "suspect" or "unreliable", with one-line reasons and the figures behind them.

Pure: the chain's tables and summary (and the session they came from) in, a frozen `Quality` out;
`Quality.as_dict()` is `summary.json["quality"]`. Every test asks whether a figure is plausible
for a consistent filter on sound data (`consistency`), at a false-alarm probability of 0.1 % per
test, never against values seen on particular logs:

- `nis`: the mean NIS of each solution's updates of each kind against its band for that number of
  updates and the chain's gate (`consistency.mean_nis_band`). Outside: suspect. Unreliable when the mean
  is also more than 9 times its expectation: the errors are then over 3 times the sigmas, so the written
  sigmas (and anything computed from them) are meaningless. A chain that updates at the IMU rate
  (`NisRules.serial`) counts its updates by their effective sample size
  (`consistency.effective_sample_size`: n / τ, τ their integrated autocorrelation time); kinds its gate
  does not apply to (`NisRules.ungated_kinds`) get the plain chi-square band. A run whose prior and
  process noise were divided by an information share beta (the `share` column: a federated local filter,
  paper 000 Eq. 23-24) bounds its errors by design, so its expected mean lies between beta and 1 times
  the chi-square's: the band's low end is scaled by beta. Kinds whose noise is a bound on a motion
  (`NisRules.one_sided_kinds`) are tested on the high side only.
- `rejections`: rejected updates against Binomial(n, 1 - gate). Real environments have outliers
  (multipath, NLOS ranges): suspect only when the rate is, at 99.9 % confidence (Clopper-Pearson),
  above `OUTLIER_ALLOWANCE` on top of the gate's own rate; unreliable when more than half of the
  updates are rejected: the filter no longer follows its aiding.
- `mounting`: the chain's course-against-yaw check while moving (a sideways or reversed IMU).
- `mounting.stated`: a session's `[imu] mounting_rpy_deg` against the mounting the log's travel
  direction gives (`stated_mounting_findings`: wrong by tens of degrees, or written in radians).
- `fusion`: a local filter the federated fusion left out for more than `DISTURBED_ALLOWANCE`.
- `bias`: bias states that settled more than 3.29 of their prior SDs from zero (`bias_findings`).
- `flags`: epochs where the forward and backward runs disagree beyond their covariances (the chain's
  `flag` column, tested at its `flag_probability`), counted with the effective sample size of the flag
  series (`consistency.effective_sample_size`): suspect when significantly more than the flag rate;
  unreliable when more than half of the epochs are flagged.
- `aiding`: a chain that needs GPS, anchor ranges or rangefinders but used none (e.g. a GPS clock
  1e6 s off puts every fix outside the IMU log): unreliable.
- `magnetometer`: the share of magnetometer samples the attitude filter rejected as disturbed;
  a heading neither attitude run confirmed with the field, and a start alignment whose field may
  hold a disturbance (`magnetometer_support_findings`: the target chain's heading-sigma terms).
- convention findings (`conventions.session_findings`: units, axes, clock, magnetometer, baselines)
  and verified advice (`advice`) arrive as `Finding`s and are merged as they are.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tpos_cli import consistency
from tpos_cli.io.columns import Columns, column, flags, groups, is_empty

if TYPE_CHECKING:
    import pandas as pd

LEVELS = ("ok", "suspect", "unreliable")
UNRELIABLE_NIS_RATIO = 9.0  # mean NIS / expected: errors 3x their sigmas
OUTLIER_ALLOWANCE = 0.25  # share of updates a field log may lose to outliers (multipath, NLOS): an
# update built from several measurements is an outlier if any of them is (a fix from 4 ranges with
# 3 % NLOS each: 11 %); more than a quarter rejected is a filter that disagrees with its data
DISTURBED_ALLOWANCE = 0.05  # share of samples a sound, calibrated magnetometer (or a sound local
# filter of the federated fusion) may fall outside the filter's own tolerances
MAJORITY = 0.5
# d.o.f. of innovation kinds whose table has no `dof` column (ranging: scalar ranges, north-east fixes)
KIND_DOF = {"range": 1, "fix": 2}
# chain -> (parameter holding the gate probability, parameter holding the flag probability)
_GATES = {"drive_smooth": ("gate_probability", "flag_probability"),
          "ranging_fatci": ("gate_probability", None),
          "target_fkf": ("range_gate_probability", None)}


@dataclass(frozen=True)
class NisRules:
    """How a chain's mean NIS are judged (`nis_findings`; module docstring), beside its gate.

    `ungated_kinds`: kinds the chain's gate does not apply to (plain chi-square band). `one_sided_kinds`:
    kinds whose noise is a bound on a motion, not a sensor's noise, tested on the high side only.
    `serial`: the updates come at the IMU rate, so each mean counts their effective sample size
    (`consistency.effective_sample_size`; n when the innovations are white, as a consistent filter's are:
    the band is then unchanged). `high_meaning`: what a mean above its band says (the reason's end)."""

    ungated_kinds: tuple[str, ...] = ()
    one_sided_kinds: tuple[str, ...] = ()
    serial: bool = False
    high_meaning: str = "the filter's sigmas understate its errors"


# chain -> its NIS rules where not the defaults. target_fkf: its gate is the range differences' (the accelerometer
# and field updates are not gated on their NIS); its hand model (the velocity change a hand-held device's bounded
# motion allows, `attitude.motion`) is tested on the high side only: a device that moves more smoothly than a hand
# (the simulated target sessions: mean NIS 0.3-0.7 of its expectation on the paper and tactical sims, at rest and
# moving alike, seeds 900-902, notes sig22.md) has sigmas the bound makes cautious, not wrong (chosen after seeing
# those sims: disclosed); the still periods' updates (`hand_still`, where the oscillator is not driven and the bound
# is far above what the accelerometer shows) are judged apart, so that they do not dilute the moving ones; its NIS
# come at the IMU rate (a magnetometer sampled slower than the IMU repeats a sample and its innovation: BROAD's logs
# repeat over a quarter of their field samples); and they are its local filter runs' (each run alone): the delivered
# solution's sigmas are widened by the forward/backward runs' disagreement (`attitude.smoother`), which this test
# does not judge
_NIS_RULES = {"target_fkf": NisRules(
    ungated_kinds=("acc", "mag", "obs"), one_sided_kinds=("hand", "hand_still"), serial=True,
    high_meaning="the attitude filter runs' sigmas understate their errors (each run alone; the delivered "
                 "solution's sigmas are widened by the runs' disagreement, not judged here)")}
# chain -> what aiding it needs, as the innovation kinds that show it was used
_AIDING = {"drive_smooth": ("gps", ("gps_pos", "gps_vel")), "ranging_fatci": ("anchor ranges", ("range", "fix"))}


@dataclass(frozen=True)
class Finding:
    """One check's outcome: its level, a one-line reason (cause and fix) when not ok, its figures."""

    check: str
    level: str = "ok"
    reason: str | None = None
    figures: Mapping = field(default_factory=dict)
    # the column that breaks the session contract (a unit: gyro in deg/s, odometry in km/h), when the
    # evidence names it: invalid input, which `tpos validate` and `tpos process` refuse (exit 2)
    # instead of processing (`conventions.contract_errors`)
    contract_column: str | None = None

    def __post_init__(self):
        if self.level not in LEVELS:
            raise ValueError(f"level {self.level!r} is not one of {LEVELS}")


@dataclass(frozen=True)
class Quality:
    verdict: str
    reasons: tuple[str, ...]
    checks: Mapping[str, dict]
    findings: tuple[Finding, ...] = ()

    def as_dict(self) -> dict:
        """`summary.json["quality"]` (numpy values are converted where the summary is written)."""
        return {"verdict": self.verdict, "reasons": list(self.reasons), "checks": {k: dict(v) for k, v in self.checks.items()}}


def combine(findings: Iterable[Finding]) -> Quality:
    """The worst level decides; reasons listed worst first; figures grouped by check name."""
    fs = list(findings)
    worst = max((LEVELS.index(f.level) for f in fs), default=0)
    reasons = []
    for lvl in reversed(LEVELS[1:]):
        for f in fs:
            if f.level == lvl and f.reason and f.reason not in reasons:
                reasons.append(f.reason)
    checks: dict = {}
    for f in fs:
        entry = checks.setdefault(f.check, {})
        if f.figures:
            entry.update(f.figures)
        if f.level != "ok":
            entry["level"] = max(entry.get("level", "ok"), f.level, key=LEVELS.index)
    return Quality(LEVELS[worst], tuple(reasons), checks, tuple(fs))


def _param(config: Mapping | None, chain: str, key: str | None, default=None):
    if not key or not config:
        return default
    sec = config.get(chain) or {}
    return sec.get(key, default)


def nis_findings(innovations: pd.DataFrame | Columns | None, gate_probability: float | None,
                 model_rel_sd: Mapping[str, float] | None = None, rules: NisRules = NisRules()) -> list[Finding]:
    """Mean NIS and rejections per solution and kind (module docstring); one reason line per kind
    of failure, naming every solution and measurement kind it concerns. `model_rel_sd`: {kind:
    relative SD of its noise variances} when the chain estimated them (`consistency.mean_chi2`).
    `rules`: the chain's `NisRules` (the defaults: every kind gated, two-sided, independent updates).
    A `share` column (information share, module docstring) scales the band's low end."""
    if innovations is None or is_empty(innovations) or "nis" not in innovations:
        return []
    inn = innovations
    kinds = column(inn, "kind")
    dof_all = column(inn, "dof").astype(float) if "dof" in inn else np.array([KIND_DOF.get(k, np.nan) for k in kinds], dtype=float)
    out = []
    high, low, rej = [], [], []
    share_all = column(inn, "share").astype(float) if "share" in inn else np.ones(len(inn))
    nis_all = column(inn, "nis").astype(float)
    acc_all = flags(inn, "accepted") if "accepted" in inn else np.ones(len(inn), bool)
    for (sol, kind), i in groups(column(inn, "solution"), kinds):
        nis, dof, acc = nis_all[i], dof_all[i], acc_all[i]
        ok = np.isfinite(nis) & np.isfinite(dof) & (dof > 0)
        n, a = int(ok.sum()), ok & acc
        if n == 0:
            continue
        name = f"{sol} {kind}"
        gate = None if kind in rules.ungated_kinds else gate_probability
        p_rej = 1.0 - gate if gate is not None else 0.0
        n_eff = consistency.effective_sample_size(nis[a]) if rules.serial else None
        m = consistency.mean_chi2(nis[a], dof[a], gate_probability=gate, n_eff=n_eff,
                                  model_rel_sd=float((model_rel_sd or {}).get(kind, 0.0)))
        share = float(np.min(share_all[i][ok]))
        lo = 0.0 if kind in rules.one_sided_kinds else m.lo * share
        inside = lo <= m.mean <= m.hi
        fig = {"n": n, "n_accepted": int(a.sum()), "dof": float(np.median(dof[ok])), "mean_nis": m.mean,
               "expected": m.expected, "band": [lo, m.hi], "ratio": m.ratio}
        if share < 1.0:
            fig["share"] = share
        count = f"{int(a.sum())} updates"
        if n_eff is not None:
            fig["n_effective"] = n_eff
            count += f", {n_eff:.0f} effective"
        level = "ok"
        if a.sum() and not inside:
            if m.ratio > 1:
                level = "unreliable" if m.ratio > UNRELIABLE_NIS_RATIO else "suspect"
                high.append((level, f"{name} {m.mean:.3g} (band {lo:.2f}-{m.hi:.2f}, {count}: errors "
                                    f"~{np.sqrt(m.ratio):.1f}x the sigmas)"))
            else:
                level = "suspect"
                low.append((level, f"{name} {m.mean:.3g} (band {lo:.2f}-{m.hi:.2f}, {count})"))
        out.append(Finding(f"nis.{sol}.{kind}", level, None, fig))
        k = int((ok & ~acc).sum())
        lb = consistency.rate_lower_bound(k, n)
        pval = consistency.binomial_excess(k, n, p_rej)
        rfig = {"n": n, "rejected": k, "fraction": k / n, "expected": p_rej, "lower_bound": lb, "p_value": pval}
        level = "ok"
        if pval < 1.0 - consistency.SUSPECT_PROB and lb > p_rej + OUTLIER_ALLOWANCE:
            level = "unreliable" if lb > MAJORITY else "suspect"
            rej.append((level, f"{name} {k} of {n} ({100 * k / n:.0f} %, at least {100 * lb:.0f} % at 99.9 % confidence)"))
        out.append(Finding(f"rejections.{sol}.{kind}", level, None, rfig))

    def group(items, check, text):
        if items:
            worst = max((lv for lv, _ in items), key=LEVELS.index)
            out.append(Finding(check, worst, text.format("; ".join(x for _, x in items))))

    group(high, "nis", "mean NIS above its band: {}: " + rules.high_meaning)
    group(low, "nis", "mean NIS below its band: {}: the filter's measurement or process noise is set too large "
                      "(pessimistic sigmas)")
    p_gate = 1.0 - gate_probability if gate_probability is not None else 0.0
    group(rej, "rejections", "updates rejected by the gate beyond the outliers a field log has: {} (the gate "
                             f"alone rejects {100 * p_gate:.2g} %): the filter and its data disagree")
    return out


def mounting_text(off_deg: float, spread_deg: float, moving_s: float | None = None, min_speed_mps: float | None = None,
                  stated: bool = False) -> str:
    """The one sentence for the drive chain's mounting check (`fusion.mounting.course_minus_yaw`): the
    chain's warning and the verdict's reason. off_deg: median course over ground minus yaw while
    moving (deg); spread_deg its spread; moving_s, min_speed_mps: how much motion it rests on;
    stated: the session gives `[imu] mounting_rpy_deg` ("set it" is then no advice: check it)."""
    moving = ("while moving" if moving_s is None or min_speed_mps is None
              else f"while moving faster than {float(min_speed_mps):g} m/s ({float(moving_s):.0f} s)")
    key = "and the session's [imu] mounting_rpy_deg" if stated else "or set [imu] mounting_rpy_deg"
    return (f"mounting: {moving}, course over ground minus yaw is {float(off_deg):+.0f} deg (spread "
            f"{float(spread_deg):.0f} deg): the IMU's forward axis is turned about {-float(off_deg):+.0f} deg from the "
            f"direction of travel, so the attitude is the IMU's, not the vehicle's; check [imu] axes {key} "
            "(a car has little sideslip; a walker or hand-held unit may point elsewhere)")


def mounting_findings(results: Mapping | None) -> list[Finding]:
    """The chain's mounting check (course over ground against yaw while moving)."""
    m = (results or {}).get("mounting_check")
    if not isinstance(m, Mapping) or "warning" not in m:
        return []
    fig = {k: v for k, v in m.items() if k != "message"}
    if not m["warning"]:
        return [Finding("mounting", "ok", None, fig)]
    nan = float("nan")
    text = mounting_text(m.get("course_minus_yaw_median_deg", nan), m.get("spread_deg", nan), m.get("moving_s"),
                         m.get("min_speed_mps"), stated=_stated_mounting(results) is not None)
    return [Finding("mounting", "suspect", text, fig)]


STATED_MOUNTING_Z = 3.29  # two-sided 99.9 %: the module's false-alarm rate per test


def _stated_mounting(results: Mapping | None) -> list[float] | None:
    """The session's `[imu] mounting_rpy_deg` as the drive chain applied it (its constraints record)."""
    c = (results or {}).get("constraints")
    m = c.get("mounting") if isinstance(c, Mapping) else None
    if isinstance(m, Mapping) and m.get("source") == "session" and isinstance(m.get("mounting_rpy_deg"), (list, tuple)):
        return [float(v) for v in m["mounting_rpy_deg"]]
    return None


def mounting_difference_deg(stated_rpy_deg, estimate_rpy_deg) -> tuple[float, float]:
    """(pitch, yaw) in deg of the forward axis a stated mounting gives the vehicle, in the vehicle
    axes of an estimated one (both `[imu] mounting_rpy_deg`: C_vb = euler_to_dcm, v_vehicle = C_vb
    v_body): stated minus estimate for mountings that differ by a pure pitch or yaw; any roll, no
    gimbal lock (the forward axes are compared, not Euler angles)."""
    from tpos_cli.frames.rotation import euler_to_dcm

    C_s = euler_to_dcm(*np.radians(np.asarray(stated_rpy_deg, dtype=float)))
    C_e = euler_to_dcm(*np.radians(np.asarray(estimate_rpy_deg, dtype=float)))
    w = C_e @ C_s[0]  # the stated forward axis (row 0 of C_vb: in body axes) in the estimate's vehicle axes
    return float(np.degrees(np.arctan2(w[2], np.hypot(w[0], w[1])))), float(-np.degrees(np.arctan2(w[1], w[0])))


def stated_mounting_findings(results: Mapping | None, config: Mapping | None = None, chain: str = "drive_smooth") -> list[Finding]:
    """The session's `[imu] mounting_rpy_deg` against the mounting the log's own travel direction
    gives (a first forward run without vehicle constraints, `fusion.constraints.travel_direction`,
    with its SDs; the drive chain records it when the key is given and the platform is decided from
    the log), on a wheeled platform (car, rover: the runs that apply the mounting). The stated
    forward axis more than `STATED_MOUNTING_Z` combined SDs (the estimate's and the chain's prior
    SD of a given mounting, `mounting_sigma_given_deg`) AND more than `mounting_check_deg` (the
    chain's own course-against-yaw bound: a travel direction carries sideslip and road grade, a
    few deg, that its SDs do not) off in pitch or yaw: the vehicle constraints (NHC) were applied
    in the wrong axes and the attitude is not the vehicle's: unreliable. A key whose values, read
    as radians, agree with the log is named as radians. Not an input error (exit 2): the estimate
    rests on the log's motion. Without a travel direction (a platform given: the chain runs no
    first run to decide it), the output's course against yaw (`_stated_mounting_against_course`)."""
    stated = _stated_mounting(results)
    c = (results or {}).get("constraints") or {}
    td = c.get("travel_direction") if isinstance(c, Mapping) else None
    if stated is None or len(stated) != 3 or c.get("platform") not in ("car", "rover"):
        return []  # a walker's unit may point anywhere, and only a wheeled platform's run applies the mounting
    if not isinstance(td, Mapping):  # a platform given (no first run to decide it): the output's course against yaw
        return _stated_mounting_against_course(stated, (results or {}).get("mounting_check"))
    est, sd = td.get("mounting_rpy_deg"), td.get("sigma_rpy_deg")
    if not isinstance(est, (list, tuple)) or len(est) != 3 or not isinstance(sd, (list, tuple)) or len(sd) != 3:
        return []
    given_sd = float(_param(config, chain, "mounting_sigma_given_deg", 0.5))
    bound = float(_param(config, chain, "mounting_check_deg", 20.0))
    sds = [float(np.hypot(float(s), given_sd)) if s is not None and np.isfinite(float(s)) else float("nan") for s in sd[1:]]

    def off(rpy) -> tuple[list[float], bool]:
        d = list(mounting_difference_deg(rpy, est))
        return d, any(abs(x) > bound and abs(x) > STATED_MOUNTING_Z * s for x, s in zip(d, sds) if np.isfinite(s))

    d, bad = off(stated)
    fig = {"stated_rpy_deg": stated, "log_estimate_rpy_deg": list(est), "log_sigma_py_deg": list(sd[1:]),
           "difference_py_deg": [round(x, 2) for x in d], "combined_sigma_py_deg": [round(s, 3) for s in sds],
           "moving_s": td.get("moving_s")}
    if not bad:
        return [Finding("mounting.stated", "ok", None, fig)]
    rad = [float(np.degrees(v)) for v in stated]
    radians = any(stated) and max(abs(v) for v in stated) <= np.pi + 1e-6 and not off(rad)[1]
    fig["radians"] = bool(radians)
    where = " and ".join(f"{abs(x):.0f} deg in {n}" for x, s, n in zip(d, sds, ("pitch", "yaw"))
                         if np.isfinite(s) and abs(x) > bound and abs(x) > STATED_MOUNTING_Z * s)
    fmt = _fmt_list
    text = (f"imu: [imu] mounting_rpy_deg = {fmt(stated)} turns the vehicle's forward axis {where} from the direction the "
            f"log travels in (its mounting from the log: pitch {est[1]:.1f} +- {sds[0]:.1f}, yaw {est[2]:.1f} +- {sds[1]:.1f} deg, "
            f"over {float(td.get('moving_s') or 0):.0f} s of motion): the vehicle constraints were applied in the wrong axes and "
            "the attitude is not the vehicle's; ")
    if radians:
        text += (f"written in radians? {fmt([round(v, 4) for v in stated])} rad = {fmt([round(v, 1) for v in rad])} deg agrees "
                 "with the log: write degrees")
    else:
        text += "check the key (degrees, body to vehicle), or leave it out and the mounting is estimated from the log"
    return [Finding("mounting.stated", "unreliable", text, fig)]


def _fmt_list(v) -> str:
    return "[" + ", ".join(f"{x:g}" for x in v) + "]"


def _stated_mounting_against_course(stated: list[float], check: Mapping | None) -> list[Finding]:
    """`stated_mounting_findings` where the chain recorded no travel direction (a platform given,
    "car" or "rover": no first run decides it): the chain's own course-against-yaw check of its
    output, whose attitude is in the vehicle axes the stated mounting gives (`mounting_check`),
    with its own bound (`mounting_check_deg`, median beyond it over at least 10 s of motion). Its
    warning on a stated mounting: unreliable, naming the key (a yaw statement only: a stated
    pitch the log contradicts is not seen here); the mounting the log implies is about the stated
    yaw minus the median course-minus-yaw. Radians named when the values read as radians put the
    yaw within the bound."""
    if not isinstance(check, Mapping) or not check.get("warning"):
        return []
    med, bound = float(check.get("course_minus_yaw_median_deg", np.nan)), float(check.get("threshold_deg", 20.0))
    if not np.isfinite(med):
        return []
    implied = stated[2] - med

    def wrap(x):
        return (x + 180.0) % 360.0 - 180.0

    radians = any(stated) and max(abs(v) for v in stated) <= np.pi + 1e-6 and abs(wrap(np.degrees(stated[2]) - implied)) <= bound
    fig = {"stated_rpy_deg": stated, "course_minus_yaw_median_deg": med, "log_yaw_deg": round(wrap(implied), 2),
           "radians": bool(radians), "moving_s": check.get("moving_s"), "from": "mounting_check"}
    text = (f"imu: [imu] mounting_rpy_deg = {_fmt_list(stated)} leaves the vehicle's forward axis {abs(med):.0f} deg in yaw "
            f"off the course over ground (median over {float(check.get('moving_s') or 0):.0f} s of motion, spread "
            f"{float(check.get('spread_deg', np.nan)):.0f} deg; the log's yaw of the mounting is about {wrap(implied):.0f} deg): "
            "the vehicle constraints were applied in the wrong axes and the attitude is not the vehicle's; ")
    if radians:
        rad = [round(float(np.degrees(v)), 1) for v in stated]
        text += (f"written in radians? {_fmt_list([round(v, 4) for v in stated])} rad = {_fmt_list(rad)} deg agrees with "
                 "the log: write degrees")
    else:
        text += "check the key (degrees, body to vehicle) and [imu] axes, or leave the key out and the mounting is estimated from the log"
    return [Finding("mounting.stated", "unreliable", text, fig)]


def flag_findings(trajectory: pd.DataFrame | Columns | None, flag_probability: float | None) -> list[Finding]:
    """Forward/backward disagreement flags (the chain's `flag` column) against the flag rate."""
    if trajectory is None or "flag" not in trajectory or flag_probability is None:
        return []
    sols = column(trajectory, "solution") if "solution" in trajectory else None
    sol = "forward" if sols is not None and (sols == "forward").any() else None
    flag = flags(trajectory, "flag")
    if sol:
        flag = flag[sols == sol]
    n = flag.size
    if n == 0:
        return []
    k = int(flag.sum())
    n_eff = consistency.effective_sample_size(flag.astype(float)) if 0 < k < n else float(n)
    if k == n:
        n_eff = 1.0
    frac = k / n
    k_eff = int(round(frac * n_eff))
    p0 = 1.0 - flag_probability
    pval = consistency.binomial_excess(k_eff, max(int(round(n_eff)), 1), p0)
    lb = consistency.rate_lower_bound(k_eff, max(int(round(n_eff)), 1))
    fig = {"epochs": n, "flagged": k, "fraction": frac, "expected": p0, "effective_epochs": n_eff, "p_value": pval,
           "lower_bound": lb}
    level, reason = "ok", None
    if pval < 1.0 - consistency.SUSPECT_PROB:
        level = "unreliable" if lb > MAJORITY else "suspect"
        reason = (f"forward and backward runs disagree beyond their covariances at {100 * frac:.0f} % of epochs "
                  f"(expected {100 * p0:.2g} %): the filter's sigmas are too small for this log, so positions may be "
                  "off by more than their sigmas")
    return [Finding("flags", level, reason, fig)]


def aiding_findings(session, innovations: pd.DataFrame | Columns | None, chain: str) -> list[Finding]:
    """A chain that needs aiding but used none; GPS fixes outside the IMU log."""
    out = []
    g = getattr(session, "gps", None)
    if g is not None and g.valid.any():
        t = g.t_s[g.valid]
        t_imu = session.imu.t_s
        inside = (t >= t_imu[0]) & (t <= t_imu[-1])
        fig = {"fixes": int(t.size), "inside_imu_log": int(inside.sum()),
               "gps_t_s": [float(t[0] + session.t0_s), float(t[-1] + session.t0_s)],
               "imu_t_s": [float(t_imu[0] + session.t0_s), float(t_imu[-1] + session.t0_s)]}
        if inside.mean() < MAJORITY:
            off = float(np.median(t_imu) - np.median(t))
            level = "unreliable" if chain == "drive_smooth" else "suspect"
            out.append(Finding("aiding.gps_time", level,
                               f"gps: {int(t.size - inside.sum())} of {t.size} fixes (t {fig['gps_t_s'][0]:.1f}-{fig['gps_t_s'][1]:.1f} s) "
                               f"fall outside the IMU log ({fig['imu_t_s'][0]:.1f}-{fig['imu_t_s'][1]:.1f} s): the GPS clock is off by "
                               f"about {off:+.4g} s (another time scale, time zone or epoch?); fix the gps t column "
                               "or set [time] gps_offset_s",
                               {**fig, "offset_estimate_s": off}))
        else:
            out.append(Finding("aiding.gps_time", "ok", None, fig))
    if chain in _AIDING:
        what, kinds = _AIDING[chain]
        used = 0
        if innovations is not None and not is_empty(innovations) and "kind" in innovations:
            k = column(innovations, "kind")
            m = np.zeros(len(k), dtype=bool)
            for kind in kinds:
                m |= k == kind
            if "accepted" in innovations:
                m &= flags(innovations, "accepted")
            used = int(m.sum())
        level = "ok" if used else "unreliable"
        out.append(Finding("aiding.used", level,
                           None if used else f"no {what} measurement was used: the solution is dead reckoning from the IMU alone "
                           "(see the other reasons; check the aiding files and their time column)", {"updates_accepted": used}))
    return out


def magnetometer_findings(counts: Mapping | None, imu_samples: int, has_mag: bool) -> list[Finding]:
    """The attitude filter's magnetometer rejections (samples outside its field-norm/dip tolerance)."""
    if not has_mag or not counts or "mag_samples_rejected" not in counts or imu_samples <= 0:
        return []
    k = int(counts["mag_samples_rejected"])
    frac = k / imu_samples
    fig = {"rejected": k, "samples": imu_samples, "fraction": frac}
    if frac > DISTURBED_ALLOWANCE:
        return [Finding("magnetometer.rejected", "suspect",
                        f"magnetometer: the attitude filter rejected {100 * frac:.0f} % of its samples as disturbed (field "
                        "norm or dip off): a magnet, steel or electronics near the sensor; heading there rests on the gyro "
                        "(and on LF2 where rangefinders aim at a wall); keep magnets away, or run `tpos calibrate-mag` if the "
                        "disturbance moves with the device",
                        fig)]
    return [Finding("magnetometer.rejected", "ok", None, fig)]


def unsupported_heading_text(share: float, sigma_deg: float) -> str:
    """The one sentence for LF1's unsupported heading (`chains.target_fkf.unsupported_heading`): the
    chain's warning and the verdict's reason. share: samples on which neither attitude run used the
    field (0-1); sigma_deg: the refused field's RMS disagreement with the heading (deg)."""
    return (f"magnetometer: neither attitude run used the field on {100 * float(share):.0f} % of the samples: the "
            "heading rests on the still windows' alignments carried by the gyro, and the refused field disagrees "
            f"with it by {float(sigma_deg):.1f} deg RMS (added to the heading sigma of lf1); keep magnets and "
            "electronics away from the sensor, or run `tpos calibrate-mag` if the disturbance moves with the device")


def unresolved_offset_text(offset_ut: float, heading_deg: float | None = None) -> str:
    """The one sentence for a disturbance the start alignment's field may hold (`chains.target_fkf.
    unresolved_offset_heading`): the chain's warning and the verdict's reason. offset_ut: its size (uT);
    heading_deg: the heading error it may cause (deg), when known."""
    up_to = "the heading sigma" if heading_deg is None else f"{float(heading_deg):.0f} deg"
    return (f"magnetic survey: the start alignment's field may hold a {float(offset_ut):.1f} uT disturbance (a magnet "
            "attached from the start, or a field off the Earth field's magnitude in the still window): the heading "
            f"may be off by up to {up_to} (added to the heading sigma of lf1); run `tpos calibrate-mag` on a log that "
            "turns the device with the magnet attached")


def magnetometer_support_findings(results: Mapping | None) -> list[Finding]:
    """What the target chain added to LF1's heading sigma (`chains.target_fkf.unsupported_heading`,
    `unresolved_offset_heading`): `magnetometer_unused_share` (samples on which neither attitude run
    used the field) with `unsupported_heading_sigma_deg` (the refused field's RMS disagreement with the
    heading), and `unresolved_offset_ut` (a disturbance the start alignment's field may hold) with
    `unresolved_offset_heading_sigma_deg` (the heading error it may cause), when the run has it."""
    r = results or {}
    out: list[Finding] = []
    share = r.get("magnetometer_unused_share")
    if share is not None:
        share = float(share)
        sd = r.get("unsupported_heading_sigma_deg")
        fig = {"unused_share": share, "unsupported_heading_sigma_deg": sd}
        if sd is not None:  # written only past the chain's own share (`target_fkf.HEADING_UNSUPPORTED_SHARE`)
            out.append(Finding("magnetometer.unused", "suspect", unsupported_heading_text(share, sd), fig))
        else:
            out.append(Finding("magnetometer.unused", "ok", None, fig))
    b = r.get("unresolved_offset_ut")
    if b is not None:
        out.append(Finding("magnetometer.unresolved_offset", "suspect",
                           unresolved_offset_text(b, r.get("unresolved_offset_heading_sigma_deg")),
                           {"unresolved_offset_ut": float(b)}))
    return out


def fusion_findings(results: Mapping | None) -> list[Finding]:
    """The federated filter's fault exclusions: a local filter left out of the fusion for more than
    the outlier allowance disagrees with the other (target chain, `attitude.faults`)."""
    faults = (results or {}).get("faults")
    if not isinstance(faults, Mapping):
        return []
    fig = {k: dict(v) for k, v in faults.items() if isinstance(v, Mapping)}
    bad = {k: v.get("excluded_fraction", 0.0) for k, v in fig.items() if v.get("excluded_fraction", 0.0) > DISTURBED_ALLOWANCE}
    if not bad:
        return [Finding("fusion", "ok", None, fig)]
    what = ", ".join(f"{k.upper()} for {100 * v:.0f} %" for k, v in bad.items())
    return [Finding("fusion", "suspect",
                    f"fusion: the fault detector left out {what} of the log (the local filters disagree): a disturbed "
                    "magnetometer, a wrong rangefinder baseline, or beams off the wall; the fused attitude there rests on "
                    "the other filter", fig)]


BIAS_Z = 3.29  # two-sided 99.9 % of a bias estimate against its prior SD


def bias_findings(results: Mapping | None, config: Mapping | None, chain: str) -> list[Finding]:
    """Bias convergence: an estimated bias state far outside its prior (z > 3.29 prior SDs) means the
    data carry an error the prior says cannot be there (wrong units, a bad calibration).

    Reads the ranging chain's `final_range_bias_m` per solution against `range_bias_sd_m` (its
    random walk neglected: a stricter test), and any chain's `results["bias"]` = {name: {"estimate": [...],
    "prior_sigma": [...]}}."""
    res = results or {}
    items = []
    if chain == "ranging_fatci":
        cfg = (config or {}).get(chain) or {}
        sd0 = float(cfg.get("range_bias_sd_m", float("nan")))
        sols = res.get("solutions") or {}
        for sol, v in sols.items():
            if isinstance(v, Mapping) and "final_range_bias_m" in v and sd0 > 0:
                items.append((f"{sol} range bias", "m", [float(v["final_range_bias_m"])], [sd0],
                              "the range calibration (range_calibration.csv) does not fit these ranges"))
    for name, v in (res.get("bias") or {}).items():
        if isinstance(v, Mapping) and "estimate" in v and "prior_sigma" in v:
            items.append((name, "", list(v["estimate"]), list(v["prior_sigma"]), "check the sensor's units and calibration"))
    out = []
    for name, unit, est, sd, cause in items:
        z = [abs(e) / s for e, s in zip(est, sd) if s and s > 0 and np.isfinite(e)]
        zmax = max(z, default=0.0)
        fig = {"estimate": est, "prior_sigma": sd, "z_max": zmax}
        if zmax > BIAS_Z:
            out.append(Finding(f"bias.{name.replace(' ', '_')}", "suspect",
                               f"{name}: settled at {np.array2string(np.asarray(est), precision=3)} {unit}, {zmax:.1f} prior SDs "
                               f"from zero (prior SD {np.array2string(np.asarray(sd), precision=3)} {unit}): {cause}", fig))
        else:
            out.append(Finding(f"bias.{name.replace(' ', '_')}", "ok", None, fig))
    return out


def assess(session, *, chain: str, config: Mapping | None = None, trajectory: pd.DataFrame | Columns | None = None,
           tables: Mapping | None = None, results: Mapping | None = None, counts: Mapping | None = None,
           findings: Iterable[Finding] = ()) -> Quality:
    """The verdict of one run of `chain` on `session` (module docstring).

    `config` is the resolved pipeline configuration ({section: {key: value}}), `tables` the chain's
    extra tables (its `innovations` table above all), `results` its summary, `counts` the run's
    counts, `findings` those made elsewhere (convention checks, verified advice).
    """
    gate_key, flag_key = _GATES.get(chain, (None, None))
    gate = _param(config, chain, gate_key)
    flag_p = _param(config, chain, flag_key)
    innovations = (tables or {}).get("innovations")
    fs = list(findings)
    fs += stated_mounting_findings(results, config, chain)  # a cause: listed before the symptoms it makes
    fs += nis_findings(innovations, gate, (results or {}).get("noise_model_rel_sd"), _NIS_RULES.get(chain, NisRules()))
    fs += flag_findings(trajectory, flag_p)
    fs += mounting_findings(results)
    fs += fusion_findings(results)
    fs += bias_findings(results, config, chain)
    fs += aiding_findings(session, innovations, chain)
    imu = session.imu
    fs += magnetometer_findings(counts, int(imu.t_s.size), imu.mag_b_ut is not None)
    fs += magnetometer_support_findings(results)
    return combine(fs)
