"""Sections of tables for people: targets and shots, targets against truth, and the figures per
solution (against truth, inside GPS outages, estimated), innovation consistency, verdict checks.

Units sit under each header; lengths are mm or m with fixed decimals chosen per table; no raw
dumps: every table says what it is in its heading.
"""

from __future__ import annotations

import textwrap
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.collections import EllipseCollection

from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.io.columns import Columns, from_records
from tpos_cli.report import layout as L
from tpos_cli.report import qc
from tpos_cli.report.context import ReportContext
from tpos_cli.report.format import checked_start_utc, length_unit, utc_strings
from tpos_cli.report.sections import Section
from tpos_cli.report.solutions import rank_solutions
from tpos_cli.trajectory import CHI2_3DOF_95

if TYPE_CHECKING:
    import pandas as pd

FONT = 7.2
NEES3_99 = 11.345  # chi2_3(0.99): a shot outside its 99 % ellipsoid
MAX_ROWS = 40


def _cut(cols: list[L.Column], n: int) -> list[L.Column]:
    return [L.Column(c.header, list(c.cells)[:n], c.unit, c.align, c.weight) for c in cols]


def _h(n_rows: int, title: bool = False, font: float = FONT) -> float:
    return L.table_height(n_rows, font) + (0.02 if title else 0.0) + 0.01


NIS_TABLE_NOTE = (
    "Mean NIS of every solution and measurement kind against the band the verdict tests it with (99.9 %, allowing for the "
    "gate and for noise figures estimated from the log); a row the verdict does not check has the plain 95 % chi-square band. "
    "A consistent filter also has about 5 % of its updates above the 95 % point."
)


def _cells(t: Columns, names) -> np.ndarray:
    """The cells of several numeric columns row by row (a table's rows one after the other)."""
    return np.column_stack([np.asarray(t[n], dtype=float) for n in names]).ravel()


def nis_columns(t: Columns) -> list[L.Column]:
    return [
        L.Column("solution", list(t["solution"]), align="left"),
        L.Column("kind", list(t["kind"]), align="left"),
        L.Column("updates", [str(int(v)) for v in t["n"]]),
        L.Column("rejected", [str(int(v)) for v in t["n_rejected"]]),
        L.Column("mean NIS", L.fmt_num(t["mean_nis"], 2)),
        L.Column(
            "band of the mean",
            [f"{a} - {b}" if a else "" for a, b in zip(L.fmt_num(t["mean_lo"], 2), L.fmt_num(t["mean_hi"], 2))],
            "the verdict's" if (t["band_source"] == "verdict").all() else "",
        ),
        L.Column("above 95 %", L.fmt_num(100 * t["frac_above_95"], 1), "% (5 expected)"),
        L.Column("mean inside", ["yes" if c else "NO" for c in t["consistent"]], "the band", align="left"),
    ]


def target_columns(t: pd.DataFrame, compact: bool = False) -> list[L.Column]:
    unit, sc, dec = length_unit(np.r_[t["sigma_n"], t["sigma_e"], t["ell95_major_m"]])
    cols = [
        L.Column("target", list(t["id"].astype(str)), align="left"),
        L.Column("latitude", L.fmt_num(t["lat"], 8), "deg"),
        L.Column("longitude", L.fmt_num(t["lon"], 8), "deg"),
        L.Column("height", L.fmt_num(t["h"], 3), "m, ellipsoid"),
        L.Column("SD north", L.fmt_num(t["sigma_n"], dec, sc), unit),
        L.Column("SD east", L.fmt_num(t["sigma_e"], dec, sc), unit),
        L.Column("SD up", L.fmt_num(t["sigma_u"], dec, sc), unit),
        L.Column(
            "95 % ellipse",
            [f"{a} x {b}" if a else "" for a, b in zip(L.fmt_num(t["ell95_major_m"], dec, sc), L.fmt_num(t["ell95_minor_m"], dec, sc))],
            unit,
        ),
        L.Column("axis", L.fmt_num(t["ell95_azimuth_deg"], 0), "deg"),
        L.Column("shots", [str(int(v)) for v in t["n_shots"]]),
    ]
    if not compact:
        zone = t["utm_zone"].iloc[0]
        cols += [
            L.Column("easting", L.fmt_num(t["utm_e_m"], 3), f"m, UTM {zone}"),
            L.Column("northing", L.fmt_num(t["utm_n_m"], 3), f"m, UTM {zone}"),
        ]
    return cols


def targets_section(ctx: ReportContext) -> Section | None:
    t = ctx.targets
    if t is None:
        return None
    n = min(len(t), MAX_ROWS)

    def draw(fig, top, bottom):
        L.draw_table(fig, top, _cut(target_columns(t), n), fontsize=FONT)

    return Section(
        "targets",
        "Targets",
        _h(n),
        draw,
        f"Solution {ctx.target_solution}; repeat shots combined by inverse-covariance weighting. SD = 1 sigma; the 95 % "
        "ellipse's semi-axes and the azimuth of its major axis (clockwise from true north); WGS-84, heights above the "
        "ellipsoid; UTM in one zone for the job." + (f" The first {n} of {len(t)} targets (tpos export lists all)." if n < len(t) else ""),
    )


def shots_section(ctx: ReportContext) -> Section | None:
    if ctx.targets is None or ctx.run.targets is None:
        return None
    sh = ctx.run.targets[ctx.run.targets["solution"] == ctx.target_solution].reset_index(drop=True)
    points = dict(zip(ctx.targets["id"].astype(str), ctx.targets[["lat", "lon", "h"]].to_numpy(float)))
    ids = sh["id"].astype(str).to_numpy()
    lla = sh[["lat", "lon", "h"]].to_numpy(float)
    d = np.full((len(sh), 3), np.nan)
    for tid in dict.fromkeys(ids):  # the shots of each target about its combined point, at once
        p = points.get(tid)
        if p is not None and np.isfinite(p[0]):
            d[ids == tid] = lla_to_ned(lla[ids == tid], p)
    d[:, 2] *= -1.0
    unit, sc, dec = length_unit(np.r_[d.ravel(), sh["sigma_n"].to_numpy(float) if "sigma_n" in sh else []])
    empty = [""] * len(sh)
    cols = [
        L.Column("target", list(sh["id"].astype(str)), align="left"),
        L.Column("shot start", L.fmt_num(sh["t_start"] - ctx.t_ref, 1), "s"),
        L.Column("end", L.fmt_num(sh["t_end"] - ctx.t_ref, 1) if "t_end" in sh else empty, "s"),
    ]
    start_utc = ctx.session.meta.start_utc if ctx.session is not None else None
    start_utc, _ = checked_start_utc(start_utc, sh["t_start"].to_numpy(float))  # none rather than decades ahead
    if start_utc is not None:
        cols.append(
            L.Column(
                "start",
                [u.replace("T", " ").rstrip("Z") for u in utc_strings(sh["t_start"].to_numpy(float), start_utc, 0)],
                "UTC",
                align="left",
            )
        )
    cols += [
        L.Column("range", L.fmt_num(sh["range_m"], 3) if "range_m" in sh else empty, "m"),
        L.Column("dN", L.fmt_num(d[:, 0], dec, sc, signed=True), unit),
        L.Column("dE", L.fmt_num(d[:, 1], dec, sc, signed=True), unit),
        L.Column("dU", L.fmt_num(d[:, 2], dec, sc, signed=True), unit),
    ]
    for c, hdr in (("sigma_n", "SD N"), ("sigma_e", "SD E"), ("sigma_u", "SD U")):
        cols.append(L.Column(hdr, L.fmt_num(sh[c], dec, sc) if c in sh else empty, unit))
    n = min(len(sh), MAX_ROWS)

    def draw(fig, top, bottom):
        L.draw_table(fig, top, _cut(cols, n), fontsize=FONT)

    return Section(
        "shots",
        "Shots",
        _h(n),
        draw,
        "Each shot's time (seconds since the first IMU sample, and UTC when the session gives its start), the range, and "
        "its position about its target's combined point (dN, dE, dU): repeat shots agreeing within their SDs show a sound "
        "combination." + (f" The first {n} of {len(sh)} shots (--full lists all)." if n < len(sh) else ""),
    )


def shot_truth_section(ctx: ReportContext) -> Section | None:
    te = ctx.acc.targets
    if te is None or not ctx.target_solution:
        return None
    te = te[te["solution"] == ctx.target_solution]
    if not len(te):
        return None
    unit, sc, dec = length_unit(np.r_[te["err_3d_m"], te["sigma_n_m"]])
    with np.errstate(invalid="ignore", divide="ignore"):
        nees = (
            (te["err_n_m"] / te["sigma_n_m"]) ** 2 + (te["err_e_m"] / te["sigma_e_m"]) ** 2 + (te["err_u_m"] / te["sigma_u_m"]) ** 2
        ).to_numpy()
    cols = [
        L.Column("target", list(te["id"]), align="left"),
        L.Column("shot start", L.fmt_num(te["t_start"] - ctx.t_ref, 1), "s"),
        L.Column("error north", L.fmt_num(te["err_n_m"], dec, sc, signed=True), unit),
        L.Column("error east", L.fmt_num(te["err_e_m"], dec, sc, signed=True), unit),
        L.Column("error up", L.fmt_num(te["err_u_m"], dec, sc, signed=True), unit),
        L.Column("3-D", L.fmt_num(te["err_3d_m"], dec, sc), unit),
        L.Column("NEES", L.fmt_num(nees, 1), "chi2, 3 dof"),
        L.Column("inside 99 %", ["" if not np.isfinite(v) else "yes" if v <= NEES3_99 else "NO" for v in nees], align="left"),
    ]
    n = min(len(te), MAX_ROWS)

    def draw(fig, top, bottom):
        L.draw_table(fig, top, _cut(cols, n), fontsize=FONT, highlight=[i for i, v in enumerate(nees[:n]) if v > NEES3_99])

    return Section(
        "shot_truth",
        "Shots against surveyed truth",
        _h(n),
        draw,
        f"Solution {ctx.target_solution}, each shot before combination; NEES = error' P^-1 error with P from the shot's SDs "
        "(3 dof): a shot outside its 99 % ellipsoid is marked.",
    )


def target_truth_section(ctx: ReportContext) -> Section | None:
    te = ctx.acc.targets
    if te is None or not len(te):
        return None
    sols = rank_solutions(te["solution"])
    rows = []
    for s in sols:
        d = te[te["solution"] == s]
        with np.errstate(invalid="ignore", divide="ignore"):
            nees = (d["err_n_m"] / d["sigma_n_m"]) ** 2 + (d["err_e_m"] / d["sigma_e_m"]) ** 2 + (d["err_u_m"] / d["sigma_u_m"]) ** 2
        rows.append(
            {
                "solution": s,
                "n": len(d),
                "rms3": np.sqrt(np.mean(d["err_3d_m"] ** 2)),
                "rmsh": np.sqrt(np.mean(d["err_h_m"] ** 2)),
                "rmsu": np.sqrt(np.mean(d["err_u_m"] ** 2)),
                "max3": d["err_3d_m"].max(),
                "nees": np.nanmean(nees) / 3.0,
                "in95": np.mean(nees <= CHI2_3DOF_95),
            }
        )
    r = from_records(rows, list(rows[0]))
    unit, sc, dec = length_unit(np.r_[te["err_h_m"], te["sigma_n_m"]])
    cols = [
        L.Column("solution", list(r["solution"]), align="left"),
        L.Column("shots", [str(v) for v in r["n"]]),
        L.Column("RMS 3-D", L.fmt_num(r["rms3"], dec, sc), unit),
        L.Column("RMS horizontal", L.fmt_num(r["rmsh"], dec, sc), unit),
        L.Column("RMS up", L.fmt_num(r["rmsu"], dec, sc), unit),
        L.Column("largest 3-D", L.fmt_num(r["max3"], dec, sc), unit),
        L.Column("mean NEES/dof", L.fmt_num(r["nees"], 2), "1 expected"),
        L.Column("inside 95 %", L.fmt_num(100 * r["in95"], 0), "% of shots"),
    ]
    plot_h = 0.34
    k95 = float(np.sqrt(qc.CHI2_2_95))
    drawn = [s for s in sols if s in ctx.shown(3)] or sols[:3]  # the table lists every solution

    def draw(fig, top, bottom):
        ax = fig.add_axes([0.13, top - plot_h, 0.5, plot_h - 0.01])
        ext = 0.0
        for s in drawn:
            d = te[te["solution"] == s]
            c = ctx.color(s) if s in ctx.order else L.COLORS[sols.index(s) % len(L.COLORS)]
            ax.plot(d["err_e_m"] * sc, d["err_n_m"] * sc, "o", ms=3.5, color=c, label=s)
            e, n = d["err_e_m"].to_numpy(float), d["err_n_m"].to_numpy(float)
            s_e, s_n = d["sigma_e_m"].to_numpy(float), d["sigma_n_m"].to_numpy(float)
            ok = np.isfinite(s_n) & np.isfinite(s_e) & np.isfinite(e) & np.isfinite(n)
            if ok.any():  # every shot's ellipse as one artist: an hour-long log has hundreds of shots
                ax.add_collection(
                    EllipseCollection(
                        2 * k95 * s_e[ok] * sc,
                        2 * k95 * s_n[ok] * sc,
                        np.zeros(int(ok.sum())),
                        units="xy",
                        offsets=np.column_stack([e[ok], n[ok]]) * sc,
                        offset_transform=ax.transData,
                        facecolors="none",
                        edgecolors=c,
                        linewidths=0.6,
                    )
                )
                ext = max(ext, float(np.max(np.abs(e[ok]) + k95 * s_e[ok])) * sc, float(np.max(np.abs(n[ok]) + k95 * s_n[ok])) * sc)
            ext = max(ext, float(np.nanmax(np.abs(np.r_[e, n]))) * sc)
        ax.plot(0, 0, "k+", ms=12, mew=1.4, label="surveyed point")
        ext = 1.1 * ext if ext > 0 else 1.0
        ax.set_xlim(-ext, ext)
        ax.set_ylim(-ext, ext)
        ax.set_aspect("equal")
        ax.set_xlabel(f"east error, {unit}", fontsize=8)
        ax.set_ylabel(f"north error, {unit}", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, lw=0.3, color="0.88")
        ax.legend(fontsize=7.5, loc="upper left", bbox_to_anchor=(1.03, 1.0), frameon=False)
        # the table starts below the x tick labels and the axis label of the plot
        y = L.draw_table(fig, top - plot_h - 0.045, cols, fontsize=FONT)
        L.note(
            fig,
            y,
            "Mean NEES per dof is about 1, and about 95 % of shots lie inside their 95 % ellipsoid, when the stated SDs are "
            "honest; larger values mean the SDs claim more than the errors show.",
        )

    return Section(
        "target_truth",
        "Targets against surveyed truth, per solution",
        plot_h + 0.045 + _h(len(r)) + 0.04,
        draw,
        "Horizontal error of every shot of the best solutions with its 95 % ellipse (from its SDs); the surveyed point is the "
        "origin. The table lists every solution.",
    )


# ------------------------------------------------------------------------------------ figures


def _accuracy_columns(ctx: ReportContext) -> list[L.Column] | None:
    rows = []
    for se in (ctx.errors(x.solution) for x in ctx.acc.solutions):
        if se is None:
            continue
        s = ctx.series[se.solution]
        if s.is_static:
            continue  # a fixed observer has no position error to speak of
        e = se.err_ned_m
        h = np.hypot(e[:, 0], e[:, 1])
        if not np.isfinite(h).any():
            continue
        f = qc.inside_95(se, s) if s.has_position_sigma else {}
        att = se.att_err_deg
        rows.append(
            {
                "solution": se.solution,
                "n": int(np.isfinite(h).sum()),
                "rmsh": np.sqrt(np.nanmean(h**2)),
                "p95h": np.nanpercentile(h, 95),
                "maxh": np.nanmax(h),
                "rmsv": np.sqrt(np.nanmean(e[:, 2] ** 2)),
                "yaw": np.sqrt(np.nanmean(att["yaw_deg"] ** 2)) if att is not None else np.nan,
                "inh": f.get("horizontal", np.nan),
                "inv": f.get("vertical", np.nan),
            }
        )
    if not rows:
        return None
    r = from_records(rows, list(rows[0]))
    unit, sc, dec = length_unit(_cells(r, ("rmsh", "p95h", "rmsv")))
    return [
        L.Column("solution", list(r["solution"]), align="left"),
        L.Column("epochs", [str(v) for v in r["n"]]),
        L.Column("RMS horizontal", L.fmt_num(r["rmsh"], dec, sc), unit),
        L.Column("95th pct horizontal", L.fmt_num(r["p95h"], dec, sc), unit),
        L.Column("max horizontal", L.fmt_num(r["maxh"], dec, sc), unit),
        L.Column("RMS vertical", L.fmt_num(r["rmsv"], dec, sc), unit),
        L.Column("RMS yaw", L.fmt_num(r["yaw"], 3), "deg"),
        L.Column(
            "inside own 95 %",
            [f"{a} / {b}" if a else "" for a, b in zip(L.fmt_num(100 * r["inh"], 0), L.fmt_num(100 * r["inv"], 0))],
            "% hor. / vert.",
        ),
    ]


def _attitude_columns(ctx: ReportContext) -> list[L.Column] | None:
    """Attitude errors of every solution (the table a target log needs: its solutions are attitudes)."""
    rows = [(se.solution, se.att_err_deg) for se in ctx.acc.solutions if se.att_err_deg is not None]
    if not rows:
        return None

    def rms(a):
        return np.sqrt(np.nanmean(a**2))

    return [
        L.Column("solution", [r[0] for r in rows], align="left"),
        L.Column("RMS roll", L.fmt_num([rms(a["roll_deg"]) for _, a in rows], 4), "deg"),
        L.Column("RMS pitch", L.fmt_num([rms(a["pitch_deg"]) for _, a in rows], 4), "deg"),
        L.Column("RMS yaw", L.fmt_num([rms(a["yaw_deg"]) for _, a in rows], 4), "deg"),
        L.Column("max |yaw|", L.fmt_num([np.nanmax(np.abs(a["yaw_deg"])) for _, a in rows], 4), "deg"),
        L.Column("RMS total angle", L.fmt_num([rms(a["att_deg"]) for _, a in rows], 4), "deg"),
    ]


def _outage_columns(ctx: ReportContext) -> list[L.Column] | None:
    p3 = ctx.acc.paper_tables.get("paper003_outages")
    if p3 is None or not len(p3):
        return None
    unit, sc, dec = length_unit(_cells(p3, ("rms_h_m", "max_h_m")))
    return [
        L.Column("outage", [str(v) for v in p3["outage"]]),
        L.Column("from", L.fmt_num(p3["t0"] - ctx.t_ref, 1), "s"),
        L.Column("length", L.fmt_num(p3["duration_s"], 1), "s"),
        L.Column("solution", list(p3["solution"]), align="left"),
        L.Column("RMS horizontal", L.fmt_num(p3["rms_h_m"], dec, sc), unit),
        L.Column("max horizontal", L.fmt_num(p3["max_h_m"], dec, sc), unit),
        L.Column("RMS vertical", L.fmt_num(p3["rms_v_m"], dec, sc), unit),
        L.Column("max 3-D", L.fmt_num(p3["max_3d_m"], dec, sc), unit),
    ]


def _estimated_columns(ctx: ReportContext) -> list[L.Column] | None:
    t = ctx.estimated
    t = t.take(np.array([np.isfinite(a) or np.isfinite(b) for a, b in zip(t["h95_median_m"], t["yaw95_median_deg"])], dtype=bool))
    if not len(t):
        return None
    cols = [L.Column("solution", list(t["solution"]), align="left"), L.Column("epochs", [str(v) for v in t["n"]])]
    if np.isfinite(t["h95_median_m"]).any():
        unit, sc, dec = length_unit(_cells(t, ("h95_median_m", "v95_median_m")))

        def pair(a, b):
            return [f"{x} / {y}" if x else "" for x, y in zip(L.fmt_num(t[a], dec, sc), L.fmt_num(t[b], dec, sc))]

        cols += [
            L.Column("95 % horizontal", pair("h95_median_m", "h95_p95_m"), f"{unit}, median / p95"),
            L.Column("95 % vertical", pair("v95_median_m", "v95_p95_m"), f"{unit}, median / p95"),
        ]
    cols += [
        L.Column("95 % tilt", L.fmt_num(t["tilt95_median_deg"], 4), "deg, median"),
        L.Column(
            "95 % yaw",
            [f"{a} / {b}" if a else "" for a, b in zip(L.fmt_num(t["yaw95_median_deg"], 4), L.fmt_num(t["yaw95_p95_deg"], 4))],
            "deg, median / p95",
        ),
    ]
    if np.nan_to_num(np.asarray(t["flagged_frac"], dtype=float), nan=0.0).any():
        cols.append(L.Column("flagged", L.fmt_num(100 * t["flagged_frac"], 1), "% of epochs"))
    return cols


def _fx(v: float, decimals: int) -> str:
    """Fixed decimals without a "-0.00"."""
    out = f"{v:.{decimals}f}"
    return out[1:] if out.startswith("-") and float(out) == 0.0 else out


def _calibration_rows(results: dict) -> list[tuple[str, str, str, str]]:
    """(quantity, estimate, 1-sigma, note) of what a drive run calibrated from its own log
    (`summary.json` results: the mounting, the residual misalignment, the GPS lever arm, the
    IMU-GPS clock offset, the odometer scale); rows whose figures the run does not hold are left out."""
    rows = []
    c = results.get("constraints") or {}
    mnt = c.get("mounting") or {}
    if mnt.get("mounting_rpy_deg") is not None:
        sd = mnt.get("sigma_py_deg")
        rows.append(("IMU on the vehicle, roll/pitch/yaw (deg)", " / ".join(_fx(v, 2) for v in mnt["mounting_rpy_deg"]),
                     "- / " + " / ".join(_fx(v, 2) for v in sd) if sd else "", str(mnt.get("source", ""))))
    fwd = c.get("forward") or {}
    rm = fwd.get("residual_misalignment_deg")
    if rm:
        rows.append(("residual misalignment, pitch/yaw (deg)", " / ".join(_fx(v, 3) for v in rm["pitch_yaw"]),
                     " / ".join(f"{v:.3f}" for v in rm["sigma"]), "filter states, forward run's end"))
    la = results.get("lever_arm") or {}
    if la.get("estimated"):
        rows.append(("GPS lever arm, IMU axes (m)", " / ".join(_fx(v, 3) for v in la["estimate_m"]),
                     " / ".join(f"{v:.3f}" for v in la["sigma_forward_right_m"]) + " (fwd/right)",
                     "stated " + " / ".join(f"{v:g}" for v in la["stated_m"]) + "; vertical as stated"))
    elif la:
        rows.append(("GPS lever arm, IMU axes (m)", " / ".join(f"{v:g}" for v in la.get("stated_m", [])), "",
                     "as stated, not estimated (" + str(la.get("decided_by", "")) + ")"))
    clk = results.get("gps_clock_offset") or {}
    if clk:
        rows.append(("IMU-GPS clock offset, positions (s)", f"{clk['estimate_s']:+.4f}", f"{clk['sigma_s']:.4f}",
                     f"a fix stamped t was taken at IMU time t + d; output on the {clk.get('output_clock')} clock"))
        rows.append(("IMU-GPS clock offset, velocities (s)", f"{clk['velocity_estimate_s']:+.4f}", f"{clk['velocity_sigma_s']:.4f}", ""))
    odo = fwd.get("odometer_scale_error")
    if odo:
        rows.append(("odometer scale error", f"{odo['estimate']:+.5f}", f"{odo['sigma']:.5f}", "speed read = (1 + k) x true speed"))
    return rows


def calibration_section(ctx: ReportContext) -> Section | None:
    """A drive run's calibration from its own log (`_calibration_rows`), one table."""
    rows = _calibration_rows((ctx.run.summary or {}).get("results") or {})
    if not rows:
        return None
    cols = [L.Column(h, [r[i] for r in rows], align="left" if i in (0, 3) else "right")
            for i, h in enumerate(("quantity", "estimate", "1 sigma", "note"))]
    return _table_section("calibration", "Estimated from the log",
                          "What the filter calibrated from this log's own data; `summary.json` holds the same figures.", cols,
                          font=7.0)


def _flat(d, prefix: str = "") -> list[str]:
    out = []
    for k, v in (d or {}).items():
        if k == "level":
            continue
        if isinstance(v, dict):
            out += _flat(v, f"{prefix}{k}.")
        elif isinstance(v, bool) or isinstance(v, (int, str)):
            out.append(f"{prefix}{k} {v}")
        elif isinstance(v, float):  # 4 significant digits, never scientific notation
            out.append(f"{prefix}{k} {np.format_float_positional(v, precision=4, unique=False, fractional=False, trim='-')}")
    return out


def _table_section(name: str, title: str, subtitle: str, cols, font: float = FONT, highlight=()) -> Section | None:
    if not cols:
        return None
    n = max(len(c.cells) for c in cols)

    def draw(fig, top, bottom):
        y = L.draw_table(fig, top, cols, fontsize=font, highlight=highlight)
        del y

    return Section(name, title, _h(n, font=font), draw, subtitle, floating=True)


REASON_WRAP = 128  # characters per line of the verdict's reasons at 7.2 pt across the text width


def reason_lines(reasons: list[str], wrap: int = REASON_WRAP) -> list[str]:
    """The verdict's reasons as wrapped lines, each reason a "- " item with its continuation indented."""
    out: list[str] = []
    for r in reasons:
        out += textwrap.wrap(f"- {r}", wrap, subsequent_indent="  ")
    return out


def verdict_checks_section(ctx: ReportContext, only_failed: bool) -> Section | None:
    """The verdict's reasons in full (page 1 has room for six lines of them) and the checks behind
    it with their figures: in the default report those that were not ok (the reasons name them),
    with --full every one."""
    v = ctx.verdict
    checks = v.get("checks") if v else None
    checks = checks if isinstance(checks, dict) else {}
    reasons = [str(r) for r in (v.get("reasons") or [])] if v else []

    def level(n):
        return str(checks[n].get("level", "ok")) if isinstance(checks[n], dict) else ""

    names = [n for n in checks if not only_failed or level(n) not in ("ok", "")][:30]
    if not names and not reasons:
        return None
    figures = [
        textwrap.shorten(", ".join(_flat(checks[n])), 120, placeholder=" ...") if isinstance(checks[n], dict) else str(checks[n])
        for n in names
    ]
    cols = [
        L.Column("check", names, align="left"),
        L.Column("level", [level(n) for n in names], align="left"),
        L.Column("figures", figures, align="left"),
    ] if names else []
    lines = reason_lines(reasons)
    line_h = FONT * 1.35 / 72.0 / L.A4_IN[1]
    text_h = len(lines) * line_h + (0.01 if lines else 0.0)
    highlight = [i for i, n in enumerate(names) if level(n) not in ("ok", "")]

    def draw(fig, top, bottom):
        if lines:
            fig.text(L.MARGIN_L, top, "\n".join(lines), ha="left", va="top", fontsize=FONT, linespacing=1.35)
        if cols:
            L.draw_table(fig, top - text_h, cols, fontsize=7.0, highlight=highlight)

    what = "checks of the run's verdict that were not ok" if only_failed else "checks of the run's verdict"
    sub = (f"The verdict ({v.get('verdict')}) and its reasons in full, then the {what} and the figures behind them."
           if lines else f"The {what} and the figures behind them.")
    height = text_h + (_h(len(names), font=7.0) if names else 0.0)
    return Section("verdict_checks", "The verdict's checks", height, draw, sub, floating=True)


def figure_sections(ctx: ReportContext) -> list[Section]:
    """The figures per solution, each its own section so that they fill the pages' free space."""
    out = []
    if ctx.has_truth:
        out.append(
            _table_section(
                "figures_truth",
                "Against truth, over all epochs",
                "Per solution; 'inside own 95 %' is the share of epochs whose error lies inside the bound the solution states.",
                _accuracy_columns(ctx),
            )
        )
        out.append(
            _table_section(
                "figures_attitude",
                "Attitude against truth",
                "Per solution, wrap-aware, over all epochs.",
                _attitude_columns(ctx) if ctx.static_observer else None,
            )
        )
        out.append(
            _table_section(
                "figures_outages", "Inside each GPS outage", "Per outage (and --mask-gps window) and solution.", _outage_columns(ctx)
            )
        )
    out.append(
        _table_section(
            "figures_estimated",
            "Accuracy the solutions state",
            "Median and 95th percentile over the run of each solution's 95 % bounds (horizontal: ellipse semi-major axis; "
            "vertical, tilt and yaw: 1.96 sigma).",
            _estimated_columns(ctx),
        )
    )
    if ctx.kind == "drive":
        out.append(calibration_section(ctx))
    if len(ctx.health.nis) and ctx.kind not in ("drive", ""):  # a drive shows it under its innovation plots
        out.append(
            _table_section(
                "figures_nis",
                "Innovation consistency",
                NIS_TABLE_NOTE,
                nis_columns(ctx.health.nis),
                highlight=[i for i, c in enumerate(ctx.health.nis["consistent"]) if not c],
            )
        )
    checks = verdict_checks_section(ctx, only_failed=not ctx.full)
    if checks is not None:
        out.append(checks)
    warns = list(ctx.run.summary.get("warnings") or [])
    if warns:
        shown = warns[:12]
        lines = [w for x in shown for w in textwrap.wrap(f"- {x}", 140)]

        def draw(fig, top, bottom):
            fig.text(
                L.MARGIN_L,
                top,
                "\n".join(lines + ([f"  (and {len(warns) - 12} more in summary.json)"] if len(warns) > 12 else [])),
                ha="left",
                va="top",
                fontsize=7,
                linespacing=1.3,
                color="0.2",
            )

        out.append(Section("warnings", "Warnings of the run", (len(lines) + 1) * 7 * 1.3 / 72 / L.A4_IN[1] + 0.01, draw, floating=True))
    return [s for s in out if s is not None]
