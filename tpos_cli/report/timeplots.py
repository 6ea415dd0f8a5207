"""Sections of plots against time: accuracy, consistency, GPS quality, attitude, sensors, anchors.

Every time axis is seconds (or minutes, for logs over 20 minutes) since the first IMU sample, and
shades the GPS outages, the shots (named along the top) and the detected disturbances; a rug marks
the epochs the chain flagged. Legends sit above the axes, never over the data. A quantity the run
or session does not hold gets no panel; a constant one is stated in a line instead of plotted.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from tpos_cli.io.columns import as_text, column, flags, no_value
from tpos_cli.report import layout as L
from tpos_cli.report import qc
from tpos_cli.report.context import ReportContext
from tpos_cli.report.fixes import fix_names
from tpos_cli.report.health import nis_band
from tpos_cli.report.sections import Section
from tpos_cli.report.summary import consistency_text
from tpos_cli.report.tables import NIS_TABLE_NOTE, nis_columns

PANEL_H = 0.18  # one time panel with its share of legend and tick-label space, figure fraction
LEGEND_H = 0.028  # a legend line above an axis
TICKS_H = 0.022  # tick labels under an axis
XLABEL_H = 0.045  # tick labels and the time label under the last axis
STARTUP_S = 10.0  # a filter's start-up (initial covariance) left out of the limits of accuracy axes, s


def panel_axes(fig: Figure, n: int, top: float, bottom: float, legend_each: bool = False) -> list:
    """n stacked time axes in [bottom, top]: room for a legend above the first (above each with
    `legend_each`), tick labels under each and the time label under the last."""
    gap = TICKS_H + (LEGEND_H if legend_each else 0.012)
    h = (top - bottom - LEGEND_H - XLABEL_H - gap * (n - 1)) / n
    y0 = top - LEGEND_H
    return [fig.add_axes([0.11, y0 - (k + 1) * h - k * gap, 0.84, h]) for k in range(n)]


def mark_time(ax, ctx: ReportContext, legend: bool = True, label_shots: bool = False) -> None:
    """Shade GPS outages, --mask-gps windows, shots and disturbances; a rug of flagged epochs."""
    scale = ctx.time_scale
    label = "GPS outage / masked" if len(ctx.run.mask_windows) else "GPS outage"
    L.shade(ax, ctx.run.outage_windows, ctx.t_ref, scale, L.OUTAGE_COLOR, label if legend else None)
    if ctx.shots is not None and len(ctx.shots.t0):
        w = np.column_stack([ctx.shots.t0, ctx.shots.t1])
        L.shade(ax, w, ctx.t_ref, scale, L.SHOT_COLOR, "shot" if legend else None, alpha=0.6)
        if label_shots:
            L.label_windows(ax, w, ctx.shots.ids, ctx.t_ref, scale)
    if ctx.mag is not None and len(ctx.mag.disturbed):
        L.shade(ax, ctx.mag.disturbed, ctx.t_ref, scale, L.DISTURB_COLOR, "magnetic disturbance" if legend else None, alpha=0.55)
    best = ctx.series.get(ctx.best) if ctx.best else None
    if best is not None and best.flag.any():
        L.rug(ax, best.t[best.flag], ctx.t_ref, scale, "#ff7f0e", "fwd/bwd disagreement flagged" if legend else None)
    ax.set_xlim(*ctx.time_limits)


def draw_nis(ax, ctx: ReportContext, d, color: str = L.COLORS[0], label: str = "accepted", band: bool = True) -> None:
    """NIS of one stream of updates (innovations rows) on a log axis: accepted as dots, rejected as
    x, the chi-square 95 % band of their size behind them."""
    x = ctx.x(column(d, "t"))
    nis = np.asarray(column(d, "nis"), dtype=float)
    acc = flags(d, "accepted")
    dof = np.asarray(column(d, "dof"), dtype=float)
    if band and np.isfinite(dof).any():
        lo, hi = nis_band(np.nanmedian(dof))
        ax.axhspan(lo, hi, color="0.88", zorder=0, label=f"95 % band ({np.nanmedian(dof):.0f} dof)")
    L.scatter_points(ax, x[acc], nis[acc], marker=".", ms=2.2, color=color, label=label)
    if (~acc).any():
        rejected = f"rejected ({int((~acc).sum())})" if band else None
        ax.plot(x[~acc], nis[~acc], "x", ms=4, color="#d62728" if band else color, label=rejected)
    ax.set_yscale("log")
    L.log_labels(ax, "y")
    mark_time(ax, ctx, legend=False)


def _finish(axes, ctx: ReportContext, labels, legend_axis: int = 0, raise_legend: bool = False) -> None:
    for ax, lab in zip(axes, labels):
        L.style_axis(ax, lab)
    L.legend_outside(axes[legend_axis], ncol=5, raise_for_labels=raise_legend)
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=True)
    axes[-1].set_xlabel(ctx.time_label, fontsize=8)


def _draw_order(ctx: ReportContext, names):
    """Others first, the best solution last: it is drawn on top."""
    return [n for n in names if n != ctx.best] + [n for n in names if n == ctx.best]


def accuracy_section(ctx: ReportContext) -> Section | None:
    shown = [s for s in ctx.shown() if ctx.series[s].has_position_sigma]
    if not shown or ctx.static_observer:
        return None
    truth = ctx.has_truth and ctx.truth.trajectory is not None and ctx.truth_is_independent
    has_yaw = any(np.isfinite(ctx.series[s].sigma_rpy_deg[:, 2]).any() for s in shown)
    n = 3 if has_yaw else 2
    sub = "Thick: the 95 % bound each solution states (horizontal: semi-major axis of its ellipse; vertical and yaw: 1.96 sigma). " + (
        "Thin: its actual error against truth, which should stay inside its bound about 95 % of the time."
        if truth
        else "No truth: the bounds are the run's own estimate."
    )
    if truth and ctx.truth.trajectory.source == "gps":
        sub += " Errors only at the GPS fixes withheld from the run (--mask-gps)."
    elif truth and not ctx.truth.trajectory.independent.all():
        sub += " Errors only where the truth is not a GPS fix the run used (its rows at withheld fixes, --mask-gps)."
    lines = [f"{s}: inside its own 95 % bound: {consistency_text(ctx, s)}" for s in shown if truth and consistency_text(ctx, s)]

    note_h = 0.035 if lines else 0.0

    def draw(fig, top, bottom):
        axes = panel_axes(fig, n, top, bottom + note_h)
        drawn: list[list] = [[] for _ in axes]  # what each axis shows, for limits a start-up transient does not set

        def plot(k, x, y, **kw):
            L.plot_series(axes[k], x, y, **kw)
            drawn[k].append((x, y))

        for s in _draw_order(ctx, shown):
            ser, c = ctx.series[s], ctx.color(s)
            x = ctx.x(ser.t)
            lw = 1.4 if s == ctx.best else 1.0
            plot(0, x, qc.horizontal_95_m(ser), color=c, lw=lw, label=f"{s}: 95 % bound")
            plot(1, x, qc.Z95 * ser.sigma_neu_m[:, 2], color=c, lw=lw, label=f"{s}: 95 % bound")
            L.plot_series(axes[1], x, -qc.Z95 * ser.sigma_neu_m[:, 2], color=c, lw=lw)
            if has_yaw:
                plot(2, x, qc.Z95 * ser.sigma_rpy_deg[:, 2], color=c, lw=lw)
                L.plot_series(axes[2], x, -qc.Z95 * ser.sigma_rpy_deg[:, 2], color=c, lw=lw)
            se = ctx.errors(s) if truth else None
            if se is not None:
                plot(0, x, np.hypot(se.err_ned_m[:, 0], se.err_ned_m[:, 1]), color=c, lw=0.6, alpha=0.8, label=f"{s}: error")
                plot(1, x, -se.err_ned_m[:, 2], color=c, lw=0.6, alpha=0.8)
                if has_yaw and se.att_err_deg is not None:
                    plot(2, x, se.att_err_deg["yaw_deg"], color=c, lw=0.6, alpha=0.8)
        for k, ax in enumerate(axes):
            mark_time(ax, ctx, legend=k == 0)
        axes[0].set_ylim(bottom=0)
        for k, ax in enumerate(axes):
            L.ylim_past_startup(ax, drawn[k], STARTUP_S / ctx.time_scale, symmetric=k > 0)
        _finish(axes, ctx, ("horizontal, m", "vertical (up), m", "yaw, deg")[:n])
        if lines:
            L.note(fig, bottom + note_h, "; ".join(lines) + ". About 95 % means honest sigmas; much less means the sigmas are too small.")

    return Section("accuracy", "Accuracy over time", n * PANEL_H + 0.04 + note_h, draw, sub)


def separation_section(ctx: ReportContext) -> Section | None:
    seps = ctx.health.separations
    if not seps:
        return None

    def draw(fig, top, bottom):
        axes = panel_axes(fig, len(seps), top, bottom)
        for ax, sep in zip(axes, seps):
            x = ctx.x(sep.t)
            L.plot_series(ax, x, sep.dist_h_m, color=L.COLORS[0], lw=0.9, label=f"{sep.a} minus {sep.b}, horizontal")
            L.plot_series(ax, x, sep.bound99_h_m, color="k", lw=0.9, ls="--", label="99 % bound of the pair")
            mark_time(ax, ctx)
            ax.set_ylim(bottom=0)
            L.ylim_past_startup(ax, [(x, sep.dist_h_m), (x, sep.bound99_h_m)], STARTUP_S / ctx.time_scale)  # either run's start
        _finish(axes, ctx, ["separation, m"] * len(seps))

    return Section(
        "separation",
        "Forward and backward runs",
        len(seps) * PANEL_H + 0.03,
        draw,
        "Two runs of one filter over the same data should lie within the 99 % bound of their combined covariance; "
        "a separation beyond it shows a model or data problem there (the chain flags such epochs).",
    )


def innovations_section(ctx: ReportContext) -> Section | None:
    inn = ctx.run.innovations
    sol = ctx.innovation_solution()
    if sol is None:
        return None
    d_sol = inn.take(as_text(inn["solution"]) == sol)
    kinds = list(dict.fromkeys(as_text(d_sol["kind"]).tolist()))[:3]  # first-appearance order
    table = nis_columns(ctx.health.nis)
    from tpos_cli.report.layout import table_height

    th = table_height(len(ctx.health.nis), 7.2) + 0.02

    def draw(fig, top, bottom):
        axes = panel_axes(fig, len(kinds), top, bottom + th, legend_each=True)
        for ax, kind in zip(axes, kinds):
            draw_nis(ax, ctx, d_sol.take(as_text(d_sol["kind"]) == kind))
            L.legend_outside(ax)
        _finish(axes, ctx, [f"NIS, {k}" for k in kinds])
        L.draw_table(fig, bottom + th, table, fontsize=7.2, highlight=[i for i, c in enumerate(ctx.health.nis["consistent"]) if not c])

    return Section(
        "innovations",
        f"Innovations of the {sol} run",
        len(kinds) * PANEL_H + th + 0.03,
        draw,
        "Normalised innovation squared of every update against the chi-square band of its size; rejected updates marked x. "
        + NIS_TABLE_NOTE,
    )


def gps_section(ctx: ReportContext) -> Section | None:
    g = ctx.gps
    if g is None:
        return None
    panels, constants = [], []
    names = fix_names(g.fix, g.sigma_h_m)
    for label, y, style, fmt in (
        ("fix type", g.fix, "step", "{:.0f}"),
        ("satellites used", g.nsat, "step", "{:.0f}"),
        ("HDOP", g.hdop, "line", "{:.1f}"),
        ("reported horizontal SD, m", g.sigma_h_m, "line", "{:.2f}"),
    ):
        if y is None:
            continue
        v = y[np.isfinite(y)]
        if v.size and np.ptp(v) == 0:
            constants.append(
                f"{label.split(',')[0]} {names.get(int(v[0]), fmt.format(v[0])) if label == 'fix type' else fmt.format(v[0])}"
            )
        else:
            panels.append((label, y, style))
    missing = [n for n, a in (("satellites", g.nsat), ("HDOP", g.hdop), ("reported SD", g.sigma_h_m)) if a is None]
    note = ("Constant over the log: " + ", ".join(constants) + ". " if constants else "") + (
        "Not logged: " + ", ".join(missing) + "." if missing else ""
    )

    note_h = 0.025 if note else 0.0

    def draw(fig, top, bottom):
        if panels:
            axes = panel_axes(fig, len(panels), top, bottom + note_h)
            x = ctx.x(g.t)
            for ax, (label, y, style) in zip(axes, panels):
                b = L.binned_range(g.t, y)
                if b is not None:  # more samples than the width shows: range and median per bin
                    xe = ctx.x(np.append(b.t0_s, b.t0_s[-1] + b.bin_s))
                    ax.fill_between(xe, np.append(b.lo, b.lo[-1]), np.append(b.hi, b.hi[-1]), step="post",
                                    color=L.COLORS[0], alpha=0.25, lw=0, label=f"range {L.bin_label(b.bin_s)}")
                    ax.step(xe, np.append(b.med, b.med[-1]), where="post", color=L.COLORS[0], lw=1.0, label="median")
                else:
                    i = L.decimate(y)
                    if style == "step":
                        ax.step(x[i], y[i], where="post", color=L.COLORS[0], lw=1.0)
                    else:
                        ax.plot(x[i], y[i], color=L.COLORS[0], lw=0.9)
                mark_time(ax, ctx, legend=ax is axes[0])
                if label == "fix type":
                    ax.set_yticks([0, 1, 2], [names[k] for k in (0, 1, 2)])
                    ax.set_ylim(-0.3, 2.3)
            _finish(axes, ctx, [p[0] for p in panels])
        if note:
            L.note(fig, bottom + note_h if panels else top, note)

    return Section(
        "gps",
        "GPS quality",
        len(panels) * 0.15 + (LEGEND_H + XLABEL_H if panels else 0.0) + note_h,
        draw,
        "As the receiver logged it; shaded: GPS outages and --mask-gps windows.",
    )


def attitude_section(ctx: ReportContext) -> Section | None:
    """Attitude errors against truth; without truth (target logs) each solution minus the best one.
    Never yaw on a 0-360 scale: differences, wrap-aware."""
    shown = ctx.shown(3)
    best = ctx.best
    if not shown or best is None:
        return None
    errs = {s: ctx.errors(s) for s in shown}
    truth = any(e is not None and e.att_err_deg is not None for e in errs.values())
    ref = ctx.series[best]
    others = [s for s in shown if s != best and ctx.series[s].t.size == ref.t.size and np.array_equal(ctx.series[s].t, ref.t)]
    if not truth and not (ctx.static_observer and others):
        return None
    title = "Attitude error against truth" if truth else f"Attitude: the solutions against {best}"
    sub = (
        "Solution minus truth, wrap-aware, and the total angle of the error rotation (free of the Euler convention near "
        "pitch +/-90 deg); band: the 95 % bound " + best + " states (1.96 Euler sigma; the total angle's: att95_deg)."
        if truth
        else f"Each solution minus {best}, wrap-aware (no truth); band: the 95 % bound (1.96 sigma) {best} states."
    )
    if ctx.static_observer:
        sub += " Shaded: shots and detected disturbances."
    elif len(ctx.run.outage_windows):
        sub += " Shaded: GPS outages."

    names = ("roll", "pitch", "yaw") + (("total angle",) if truth else ())

    def draw(fig, top, bottom):
        axes = panel_axes(fig, len(names), top, bottom)
        x = ctx.x(ref.t)
        for k, (ax, name) in enumerate(zip(axes, names)):
            band = qc.Z95 * ref.sigma_rpy_deg[:, k] if k < 3 else ref.att95_deg  # the total angle's: one-sided
            if np.isfinite(band).any():
                i = L.decimate(band)
                ax.fill_between(x[i], -band[i] if k < 3 else 0.0 * band[i], band[i], color="0.87", lw=0,
                                label=f"{best}: 95 % bound")
            drawn = [band]
            for s in _draw_order(ctx, shown):
                if truth:
                    e = errs[s]
                    if e is None or e.att_err_deg is None:
                        continue
                    y, xs = e.att_err_deg["att_deg" if k == 3 else f"{name}_deg"], ctx.x(e.t)
                elif s in others:
                    y, xs = (ctx.series[s].rpy_deg[:, k] - ref.rpy_deg[:, k] + 180.0) % 360.0 - 180.0, x
                else:
                    continue
                L.plot_series(ax, xs, y, color=ctx.color(s), lw=1.3 if s == best else 0.8, label=s)
                drawn.append(y)
            L.robust_ylim(ax, drawn, symmetric=k < 3)
            mark_time(ax, ctx, legend=k == 0, label_shots=k == 0)
        _finish(axes, ctx, [f"{n} {'error' if truth else 'difference'}, deg" for n in names], raise_legend=ctx.shots is not None)

    return Section("attitude", title, len(names) * PANEL_H + 0.05, draw, sub)


def sensors_section(ctx: ReportContext) -> Section | None:
    """What the sensors saw during a target session: |B| against the Earth field, the three ranges."""
    s = ctx.session
    if s is None or ctx.session_note or not ctx.static_observer:
        return None
    panels = (["mag"] if ctx.mag is not None else []) + (["ranges"] if s.ranges is not None and len(s.ranges.t_s) else [])
    if not panels:
        return None

    def draw(fig, top, bottom):
        axes = panel_axes(fig, len(panels), top, bottom, legend_each=True)
        labels = []
        for k, (ax, p) in enumerate(zip(axes, panels)):
            if p == "mag":
                m = ctx.mag
                ax.axhspan(
                    m.reference_ut - m.threshold_ut,
                    m.reference_ut + m.threshold_ut,
                    color="#e5f5e0",
                    lw=0,
                    label=f"Earth field {m.reference_ut:.1f} +/- {m.threshold_ut:.1f} uT",
                )
                L.plot_series(ax, ctx.x(m.t), m.norm_ut, color=L.COLORS[0], lw=0.9, label="|B|, 1 s medians")
                labels.append("field magnitude, uT")
            else:
                r = s.ranges
                x = ctx.x(np.asarray(r.t_s) + s.t0_s)
                for j in range(3):
                    L.plot_series(ax, x, r.range_m[:, j], color=L.COLORS[j], lw=0.8, label=f"LR{j + 1}")
                labels.append("range, m")
            mark_time(ax, ctx, legend=k == 0, label_shots=k == 0)
            if k > 0:
                L.legend_outside(ax)
        _finish(axes, ctx, labels, raise_legend=True)

    return Section(
        "sensors",
        "Sensors during the session",
        len(panels) * PANEL_H + 0.04,
        draw,
        "Magnetic field magnitude against the Earth field the alignment measured (a disturbance is marked where the "
        "1 s median leaves the band) and the three rangefinders; shaded: shots (named) and disturbances.",
    )


def anchors_section(ctx: ReportContext) -> Section | None:
    av = ctx.anchors
    if av is None:
        return None
    inn = ctx.run.innovations
    sol = ctx.innovation_solution()
    has_nis = inn is not None and sol is not None and "anchor" in inn.columns

    def draw(fig, top, bottom):
        axes = panel_axes(fig, 2 if has_nis else 1, top, bottom, legend_each=True)
        x = ctx.x(av.t)
        for j in range(len(av.ids)):
            axes[0].plot(
                np.where(av.per_anchor[j], x, np.nan),
                np.full(x.size, j),
                "-",
                lw=5,
                color=L.COLORS[j % len(L.COLORS)],
                solid_capstyle="butt",
            )
        few = qc.windows_from_mask(av.t, av.n_anchors < 3)
        L.shade(axes[0], few, ctx.t_ref, ctx.time_scale, "#fcbba1", "fewer than 3 anchors", alpha=0.7)
        axes[0].set_yticks(range(len(av.ids)), av.ids)
        axes[0].set_ylim(-0.7, len(av.ids) - 0.3)
        mark_time(axes[0], ctx)
        labels = ["anchor ranged"]
        if has_nis:
            named = ~no_value(inn["anchor"])  # pandas' notna
            d = inn.take((as_text(inn["solution"]) == sol) & named)
            ax = axes[1]
            for j, name in enumerate(av.ids):  # one colour per anchor; the band once, behind them all
                draw_nis(ax, ctx, d.take(as_text(d["anchor"]) == name), color=L.COLORS[j % len(L.COLORS)], label=name, band=j == 0)
            L.legend_outside(ax)
            labels.append(f"NIS of ranges ({sol})")
        _finish(axes, ctx, labels)

    return Section(
        "anchors",
        "Anchors and ranges",
        (2 if has_nis else 1) * PANEL_H + 0.03,
        draw,
        "Ranges logged per anchor in 1 s bins (with fewer than 3 anchors a position has a mirror image); NIS of each "
        "range update against its chi-square band, rejected updates marked x.",
    )
