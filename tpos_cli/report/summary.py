"""Page 1: the summary a person reads in a minute.

The run's verdict and its reasons; the headline figures (what was measured, how well the run says
it did, how well it did against truth when there is truth); the plan view with 95 % ellipses, a
scale bar and a north arrow (and, for a target log, the target table; for a moving platform the
estimated accuracy over time under the plan); the session and processing provenance in small print.
"""

from __future__ import annotations

import textwrap

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import FancyBboxPatch

from tpos_cli.conventions import output_on_gps_clock
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.io.columns import records
from tpos_cli.report import layout as L
from tpos_cli.report import qc
from tpos_cli.report.context import KIND_TITLES, ReportContext
from tpos_cli.report.fixes import differential_name
from tpos_cli.report.format import fmt_duration, fmt_len, pct
from tpos_cli.report.planview import plan_aspect, plan_view
from tpos_cli.report.sections import PAGE_BOTTOM, PAGE_TOP, Section
from tpos_cli.report.tables import target_columns

PROVENANCE_WRAP = 150
PROVENANCE_FONT = 6.4


def consistency_text(ctx: ReportContext, name: str) -> str:
    se, s = ctx.errors(name), ctx.series.get(name)
    if se is None or s is None or not s.has_position_sigma:
        return ""
    return ", ".join(f"{k} {pct(v)}" for k, v in qc.inside_95(se, s).items() if np.isfinite(v))


def _static_rows(ctx: ReportContext) -> list[tuple[str, str]]:
    """A fixed observer: its targets (if it shot any), where it stood, how well it knew its heading."""
    rows = []
    t = ctx.targets
    best = ctx.series.get(ctx.best) if ctx.best else None
    dur = (ctx.run.summary.get("session") or {}).get("duration_s")
    rows.append(("Session", f"{fmt_duration(float(dur)) if dur else 'n/a'}; attitude solutions {', '.join(ctx.order)} (best: {ctx.best})"))
    if t is not None:
        n_shots = int(t["n_shots"].sum())
        rep = ", ".join(f"{i} x{n}" for i, n in zip(t["id"], t["n_shots"]) if n > 1)
        rows.append(
            ("Targets", f"{len(t)} from {n_shots} shots" + (f" (repeated: {rep})" if rep else "") + f"; solution {ctx.target_solution}")
        )
        h = t["ell95_major_m"].to_numpy(float)
        if np.isfinite(h).any():
            j = int(np.nanargmax(h))
            rows.append(
                ("Target 95 %, horizontal", f"median {fmt_len(np.nanmedian(h))}, largest {fmt_len(h[j])} ({t['id'].iloc[j]})")
            )
            rows.append(("Target 95 %, vertical", f"median {fmt_len(qc.Z95 * np.nanmedian(t['sigma_u']))}"))
    else:
        rows.append(("Targets", "none: an attitude-only session (no shots)"))
    if best is not None and best.is_static and np.isfinite(best.lla[0]).all():
        p = best.lla[0]
        rows.append(
            (
                "Observer",
                f"{abs(p[0]):.6f} {'N' if p[0] >= 0 else 'S'}, {abs(p[1]):.6f} {'E' if p[1] >= 0 else 'W'}, h {p[2]:.3f} m (ellipsoid)",
            )
        )
    # the heading's SD is the attitude error's about down; the Euler yaw SD of a run written before that column
    heading_sd = best.sigma_heading_deg if best is not None and np.isfinite(best.sigma_heading_deg).any() else (
        None if best is None else best.sigma_rpy_deg[:, 2])
    if heading_sd is not None and np.isfinite(heading_sd).any():
        rows.append((f"Heading, 95 % ({best.name})", f"median {qc.Z95 * np.nanmedian(heading_sd):.3f} deg over the session"))
    if ctx.mag is not None:
        m = ctx.mag
        dist = float(np.sum(np.diff(m.disturbed, axis=1))) if len(m.disturbed) else 0.0
        rows.append(
            (
                "Magnetic field",
                f"within {m.threshold_ut:.1f} uT of {m.reference_ut:.1f} uT throughout"
                if dist == 0
                else f"disturbed for {fmt_duration(dist)}, first from {m.disturbed[0, 0] - ctx.t_ref:.0f} s "
                f"(|B| off {m.reference_ut:.1f} uT by more than {m.threshold_ut:.1f} uT)",
            )
        )
    rej = _mag_rejected(ctx)
    if rej is not None:
        # the attitude filter's own test (field norm or dip, tighter than the |B| band above): the
        # figure the verdict quotes, so that page 1 does not say "8 s" beside a verdict of "59 %"
        rows.append(("Magnetometer in the filter", f"{pct(rej)} of its samples rejected as disturbed (field norm or dip off)"))
    return rows


def _verdict_check(ctx: ReportContext, key: str, fields: tuple[str, ...]) -> dict | None:
    """The figures `fields` of the verdict's check `key` (`quality.checks` in summary.json) as
    floats, None when the run has no such check, a field is missing or not a number, or the first
    one is not finite (what page 1 quotes must be the figure the verdict's reason gives)."""
    checks = (ctx.verdict or {}).get("checks")
    c = checks.get(key) if isinstance(checks, dict) else None
    if not isinstance(c, dict):
        return None
    try:
        fig = {f: float(c[f]) for f in fields}
    except (KeyError, TypeError, ValueError):
        return None
    return fig if np.isfinite(fig[fields[0]]) else None


def _mag_rejected(ctx: ReportContext) -> float | None:
    """Share of magnetometer samples the attitude filter rejected (`quality.checks["magnetometer.rejected"]`)."""
    fig = _verdict_check(ctx, "magnetometer.rejected", ("fraction",))
    return None if fig is None else fig["fraction"]


def _stated_gps_accuracy(ctx: ReportContext) -> str | None:
    """For fixes without SDs, the stated accuracy the estimates carry, so that page 1 says why its 95 %
    figures are metres where the track is smooth. The chain's record (`results.alignment.
    gps_considered_error`) holds the considered part `sigma_*_m` and the fix-to-fix scatter `white_*_m`;
    the drive chain took sigma_c^2 = max(stated^2 - white^2 - gm^2, 0), where gm is the Gauss-Markov
    error states' SD (`results.alignment.gps_error_states`, when the run had them). The stated figures
    are read from `stated_*_m` when the record has them, else rebuilt as the root sum of squares of the
    three parts; the error states' share is named when there was one ("GM", short so that page 1 keeps
    its font: the user set gps_error_model = "gauss_markov")."""
    al = (ctx.run.summary.get("results") or {}).get("alignment") or {}
    c, gm = al.get("gps_considered_error"), al.get("gps_error_states")
    if not isinstance(c, dict):
        return None
    gm = gm if isinstance(gm, dict) else {}
    try:
        parts = {ax: (float(c[f"sigma_{ax}_m"]), float(c[f"white_{ax}_m"]), float(gm.get(f"sigma_{ax}_m", 0.0)))
                 for ax in ("h", "v")}
        stated = {ax: float(c[f"stated_{ax}_m"]) if f"stated_{ax}_m" in c else float(np.sqrt(np.sum(np.square(p))))
                  for ax, p in parts.items()}
    except (KeyError, TypeError, ValueError):
        return None
    if not all(np.isfinite(v) for v in stated.values()):
        return None
    shares = f"fix scatter {fmt_len(parts['h'][1])}"
    if parts["h"][2] > 0:  # short: page 1's table keeps its 7.8 pt font
        shares = f"scatter {fmt_len(parts['h'][1])}, GM {fmt_len(parts['h'][2])}"
    return f"none in the log: stated {fmt_len(stated['h'])} h, {fmt_len(stated['v'])} v used ({shares})"


def _moving_rows(ctx: ReportContext) -> list[tuple[str, str]]:
    best = ctx.series[ctx.best]
    rows = []
    dur = float((ctx.run.summary.get("session") or {}).get("duration_s") or (best.t[-1] - best.t[0]))
    ned = lla_to_ned(best.lla[L.decimate(best.lla[:, 0], 20000)], best.lla[0])
    travelled = float(np.nansum(np.hypot(np.diff(ned[:, 0]), np.diff(ned[:, 1]))))
    rows.append(("Duration", f"{fmt_duration(dur)}, {fmt_len(travelled)} travelled"))
    rows.append(("Solution shown", f"{best.name} (best of {', '.join(ctx.order)})"))
    est = next(r for r in records(ctx.estimated) if r["solution"] == best.name)
    if np.isfinite(est["h95_median_m"]):
        rows.append(
            ("Estimated 95 %, horizontal", f"median {fmt_len(est['h95_median_m'])}, 95th percentile {fmt_len(est['h95_p95_m'])}")
        )
        rows.append(
            ("Estimated 95 %, vertical", f"median {fmt_len(est['v95_median_m'])}, 95th percentile {fmt_len(est['v95_p95_m'])}")
        )
        stated = _stated_gps_accuracy(ctx)
        if stated is not None:
            rows.append(("GPS SDs", stated))
    if np.isfinite(est["yaw95_median_deg"]):
        rows.append(("Estimated yaw, 95 %", f"median {est['yaw95_median_deg']:.2f} deg, 95th percentile {est['yaw95_p95_deg']:.2f} deg"))
    return rows


def _flags_check(ctx: ReportContext) -> dict | None:
    """The verdict's forward/backward check (`quality.checks.flags` in summary.json: epochs whose
    whole navigation state the two runs disagree on beyond its chi-square bound), when the run has
    it; page 1 quotes it so that its figure is the one the verdict's reason gives."""
    return _verdict_check(ctx, "flags", ("fraction", "expected"))


def headline_rows(ctx: ReportContext) -> list[tuple[str, str]]:
    """The headline figures of page 1 as (figure, value) lines."""
    if ctx.static_observer:
        rows = _static_rows(ctx)
    elif ctx.best is not None and not ctx.series[ctx.best].is_static:
        rows = _moving_rows(ctx)
    else:
        rows = []
    if ctx.gps is not None:
        g = ctx.gps
        n_fix = int(np.sum(g.fix > 0))
        w = ctx.run.outage_windows
        longest = float(np.max(w[:, 1] - w[:, 0])) if len(w) else 0.0
        m = ctx.run.mask_windows
        # outage windows that overlap a --mask-gps window were made by the user, not by the receiver
        n_masked = int(sum(any(a < b1 and a1 < b for a1, b1 in m) for a, b in w)) if len(m) else 0
        used = (ctx.run.summary.get("results") or {}).get("gps_fixes")
        # a run that thins the fixes (drive-smooth: [drive_smooth] gps_max_rate_hz) says how many it used,
        # so that "14 of 290 rejected" below does not read as 290 of the log's 1174
        used_text = f" ({used} used)" if isinstance(used, int) and 0 < used < n_fix else ""
        differential = differential_name(g.fix, g.sigma_h_m)
        rows.append(
            (
                "GPS",
                f"{n_fix} fixes{used_text}, {pct(np.mean(g.fix[g.fix > 0] == 2)) if n_fix else 'n/a'} {differential}; "
                f"{len(w)} outage{'s' if len(w) != 1 else ''}" + (f", longest {fmt_duration(longest)}" if len(w) else ""),
            )
        )
        if n_masked:
            rows.append(("Withheld with --mask-gps", f"{n_masked} of the {len(w)} outages above"))
    flags = _flags_check(ctx)
    if flags is not None:
        rows.append(
            (
                "Forward/backward agreement",
                f"{pct(flags['fraction'])} of epochs flagged (whole state; {pct(flags['expected'])} expected)",
            )
        )
    for sep in ctx.health.separations:
        ok = np.isfinite(sep.dist_h_m) & np.isfinite(sep.bound99_h_m)
        beyond = float(np.mean(sep.dist_h_m[ok] > sep.bound99_h_m[ok])) if ok.any() else np.nan
        rows.append(
            (
                "Forward/backward, horizontal" if flags is not None else "Forward/backward agreement",
                f"{pct(beyond)} of epochs apart by more than their 99 % bound; largest {fmt_len(np.nanmax(sep.dist_h_m))}",
            )
        )
    sol = ctx.innovation_solution()
    if sol is not None:
        nis = [r for r in records(ctx.health.nis) if r["solution"] == sol]
        rows.append((f"Updates rejected ({sol})", "; ".join(f"{r['kind']} {int(r['n_rejected'])} of {int(r['n'])}" for r in nis)))
    if ctx.gps_agreement_only and ctx.best is not None:
        se = ctx.errors(ctx.best, independent_only=False)
        if se is not None and np.isfinite(se.err_ned_m).any():
            h = np.hypot(se.err_ned_m[:, 0], se.err_ned_m[:, 1])
            rows.append(
                (
                    "Against the GPS fixes used",
                    f"horizontal RMS {fmt_len(np.sqrt(np.nanmean(h**2)))}, vertical RMS "
                    f"{fmt_len(np.sqrt(np.nanmean(se.err_ned_m[:, 2] ** 2)))} (GPS noise, not accuracy)",
                )
            )
    if not ctx.has_truth:
        rows.append(("Truth", "none: a quality-control report (the run's own estimates and checks)"))
        return rows
    if ctx.static_observer and ctx.acc.targets is not None and ctx.target_solution:
        te = ctx.acc.targets[ctx.acc.targets["solution"] == ctx.target_solution]
        if len(te):
            j = int(np.argmax(te["err_3d_m"].to_numpy()))
            rows.append(
                (
                    "Error against surveyed truth",
                    f"RMS 3-D {fmt_len(float(np.sqrt(np.mean(te['err_3d_m'] ** 2))))}, "
                    f"largest {fmt_len(te['err_3d_m'].iloc[j])} ({te['id'].iloc[j]}), {len(te)} shots",
                )
            )
    se = ctx.errors(ctx.best) if ctx.best else None
    if se is not None and not ctx.static_observer:
        e = se.err_ned_m
        h = np.hypot(e[:, 0], e[:, 1])
        tt = ctx.truth.trajectory
        src = "truth" if tt.independent.all() else ("withheld GPS fixes" if tt.source == "gps" else "truth the run did not use")
        rows.append(
            (
                f"Error against {src}",
                f"horizontal RMS {fmt_len(np.sqrt(np.nanmean(h**2)))}, 95th percentile {fmt_len(np.nanpercentile(h, 95))}; "
                f"vertical RMS {fmt_len(np.sqrt(np.nanmean(e[:, 2] ** 2)))}",
            )
        )
        cons = consistency_text(ctx, ctx.best)
        if cons:
            rows.append(("Inside the stated 95 % bound", cons + " (about 95 % if honest)"))
        clk = (ctx.run.summary.get("results") or {}).get("gps_clock_offset")
        if src == "truth" and output_on_gps_clock(clk):
            d = float(clk.get("estimate_s", np.nan))
            rows.append(("Clocks", f"output on the GPS clock ({d:+.3f} s), truth on the logger's (notes)"))
    if se is not None and se.att_err_deg is not None:
        a = se.att_err_deg
        rows.append(
            (
                f"Attitude error ({se.solution})",
                # the total angle first: near pitch +-90 deg roll and yaw errors are large and cancel (BROAD 02:
                # roll 1.14, yaw 1.19, total 0.52 deg)
                "RMS total angle {:.3f} deg (roll {:.3f}, pitch {:.3f}, yaw {:.3f})".format(
                    *(np.sqrt(np.nanmean(a[k] ** 2)) for k in ("att_deg", "roll_deg", "pitch_deg", "yaw_deg"))
                ),
            )
        )
    return rows


def _verdict_box(fig: Figure, ctx: ReportContext, top: float) -> float:
    v = ctx.verdict
    level = v.get("verdict") if v else None
    fig.patches.append(
        FancyBboxPatch(
            (L.MARGIN_L, top - 0.05),
            0.19,
            0.045,
            boxstyle="round,pad=0.004",
            transform=fig.transFigure,
            facecolor=L.VERDICT_COLORS.get(level, L.VERDICT_COLORS[None]),
            edgecolor="none",
        )
    )
    fig.text(
        L.MARGIN_L + 0.095,
        top - 0.0275,
        level.upper() if level else "NO VERDICT",
        ha="center",
        va="center",
        fontsize=15 if level else 12,
        weight="bold",
        color="white",
    )
    fig.text(L.MARGIN_L + 0.095, top - 0.058, "verdict of the run", ha="center", va="top", fontsize=6.8, color=L.GREY)
    if v is None:
        lines = ["No verdict recorded: the run was processed before tpos gave every run a verdict; reprocess it to get one."]
    elif v.get("reasons"):
        lines = [f"- {r}" for r in v["reasons"]]
    else:
        lines = ["Every check passed: innovations, rejections, forward/backward agreement and the session checks are within their bounds."]
    wrapped: list[str] = []
    for ln in lines:
        wrapped += textwrap.wrap(ln, 105, subsequent_indent="  ")
    if len(wrapped) > 6:
        n_more = sum(1 for ln in wrapped[5:] if ln.startswith("- "))
        more = f"{n_more} more reason{'s' if n_more != 1 else ''} and " if n_more else ""
        wrapped = wrapped[:5] + [f"  ... ({more}every reason in full under \"The verdict's checks\")"]
    # one text per line, baselines on a fixed pitch: a multi-line or top-aligned text places each line by its own
    # glyphs' extent, and a line of the rtklibexplorer drive's reasons sat on the next reason (session 26)
    pitch = 7.6 * 1.35 / 72 / L.A4_IN[1]
    ascent = 7.6 * 0.8 / 72 / L.A4_IN[1]  # the first baseline below the top: a capital's height
    for i, ln in enumerate(wrapped):
        fig.text(0.285, top - 0.002 - ascent - i * pitch, ln, ha="left", va="baseline", fontsize=7.6)
    return top - max(0.068, 0.004 + len(wrapped) * pitch)


def provenance_lines(ctx: ReportContext, summary: dict) -> list[str]:
    s = ctx.run.summary
    sess = s.get("session") or {}
    files = ", ".join(f"{k} {v[:10]}" for k, v in sorted((s.get("inputs") or {}).items())) or "not recorded"
    start = (
        ctx.session.meta.start_utc.strftime("%Y-%m-%d %H:%M:%S UTC")
        if ctx.session is not None and ctx.session.meta.start_utc
        else "start time not given"
    )
    truth = "none (quality control only)"
    if ctx.has_truth:
        truth = "; ".join(x.description for x in (ctx.truth.trajectory, ctx.truth.targets) if x is not None)
    lines = [
        f"Session {sess.get('name', '?')} ({ctx.kind}): {summary['session']['path']}; {start}; "
        f"{fmt_duration(float(sess.get('duration_s') or np.nan))}, {sess.get('imu_samples', '?')} IMU samples. "
        f"Input files (sha256): {files}. Verified against the session now: {ctx.inputs_note}.",
        f"Processing: tpos {s.get('tpos_version')}, pipeline {s.get('pipeline')} (chain {s.get('chain')}), config sha256 "
        f"{str(s.get('config_sha256'))[:16]}, run {s.get('created_utc')} into {ctx.run.path}.",
        f"Report: tpos {summary['tpos_version']}, {summary['report_utc']}. Truth: {truth}.",
    ]
    if ctx.notes:
        lines.append("Notes: " + "; ".join(ctx.notes) + ".")
    return lines


def _accuracy_strip(fig: Figure, ctx: ReportContext, top: float, bottom: float) -> None:
    """Estimated 95 % horizontal bound of the best solution over time (and its error with truth)."""
    ax = fig.add_axes([0.10, bottom, 0.64, top - bottom])
    s = ctx.series[ctx.best]
    x = ctx.x(s.t)
    L.plot_series(ax, x, qc.horizontal_95_m(s), color=L.COLORS[0], lw=1.1, label=f"{s.name}: stated 95 % bound")
    se = ctx.errors(s.name)
    if se is not None:
        L.plot_series(ax, x, np.hypot(se.err_ned_m[:, 0], se.err_ned_m[:, 1]), color=L.COLORS[1], lw=0.6, label="error against truth")
    masked = len(ctx.run.mask_windows) > 0
    L.shade(ax, ctx.run.outage_windows, ctx.t_ref, ctx.time_scale, L.OUTAGE_COLOR, "GPS outage / masked" if masked else "GPS outage")
    ax.set_xlim(*ctx.time_limits)
    ax.set_ylim(bottom=0)
    L.style_axis(ax, "horizontal, m")
    ax.set_xlabel(ctx.time_label, fontsize=7.5)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, borderaxespad=0.0)


def _attitude_strip(fig: Figure, ctx: ReportContext, top: float, bottom: float) -> None:
    """Page 1 of an attitude-only log: the best solution's total attitude error against truth (or
    its stated 95 % heading bound without truth) over time."""
    ax = fig.add_axes([0.10, bottom, 0.64, top - bottom])
    s = ctx.series[ctx.best]
    se = ctx.errors(s.name)
    x = ctx.x(s.t)
    # the bound of the total angle the error is (att95_deg); a run written before it has only the Euler yaw SD,
    # singular at pitch +-90 deg (BROAD 02: 204 deg there for a 0.5 deg error), named as what it is
    total = np.isfinite(s.att95_deg).any()
    drawn = [s.att95_deg if total else qc.Z95 * s.sigma_rpy_deg[:, 2]]
    what = "stated 95 % bound, total angle" if total else "stated 95 % bound, Euler yaw"
    if se is not None and se.att_err_deg is not None:
        L.plot_series(
            ax, ctx.x(se.t), se.att_err_deg["att_deg"], color=L.COLORS[0], lw=0.8, label=f"{s.name}: attitude error (total angle)"
        )
        drawn.append(se.att_err_deg["att_deg"])
        ylabel = "attitude error, deg"
    else:
        ylabel = f"attitude 95 % bound ({'total angle' if total else 'Euler yaw'}), deg"
    L.plot_series(ax, x, drawn[0], color="k", lw=1.0, ls="--", label=f"{s.name}: {what}")
    if ctx.mag is not None and len(ctx.mag.disturbed):
        L.shade(ax, ctx.mag.disturbed, ctx.t_ref, ctx.time_scale, L.DISTURB_COLOR, "magnetic disturbance", alpha=0.55)
    ax.set_xlim(*ctx.time_limits)
    ax.set_ylim(bottom=0)
    L.robust_ylim(ax, drawn)
    L.style_axis(ax, ylabel)
    ax.set_xlabel(ctx.time_label, fontsize=7.5)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, borderaxespad=0.0)


def summary_section(ctx: ReportContext, summary: dict) -> Section:
    kind = KIND_TITLES.get(ctx.kind, ctx.kind or "session")
    subtitle = f"{kind}; pipeline {ctx.run.summary.get('pipeline')}; " + (
        "with truth" if ctx.has_truth else "no independent truth: quality control only"
    )

    def draw(fig: Figure, top: float, bottom: float) -> None:
        y = _verdict_box(fig, ctx, top)
        rows = headline_rows(ctx)
        y = L.draw_table(
            fig,
            y - 0.004,
            [L.Column("", [r[0] for r in rows], align="left"), L.Column("", [r[1] for r in rows], align="left")],
            fontsize=7.8,
            header=False,
        )
        wrapped = [w for p in provenance_lines(ctx, summary) for w in textwrap.wrap(p, PROVENANCE_WRAP)]
        prov_h = len(wrapped) * PROVENANCE_FONT * 1.3 / 72 / L.A4_IN[1]
        fig.text(
            L.MARGIN_L, bottom + prov_h, "\n".join(wrapped), ha="left", va="top", fontsize=PROVENANCE_FONT, color="0.3", linespacing=1.3
        )
        low = bottom + prov_h + 0.015
        if ctx.static_observer and ctx.targets is not None:
            n = min(len(ctx.targets), 12)
            cols = [L.Column(c.header, list(c.cells)[:n], c.unit, c.align, c.weight) for c in target_columns(ctx.targets, compact=True)]
            th = L.table_height(n, 7.4) + 0.03
            L.draw_table(
                fig,
                low + th,
                cols,
                fontsize=7.4,
                title="Targets" + (f" (the first {n} of {len(ctx.targets)}; all on page 2)" if n < len(ctx.targets) else ""),
            )
            low += th + 0.01
        if ctx.static_observer and ctx.targets is None:  # an attitude-only log: no plan to draw
            if ctx.best is not None and y - 0.04 - low > 0.15:
                _attitude_strip(fig, ctx, y - 0.04, max(low + 0.03, y - 0.04 - 0.4))
            return
        strip = not ctx.static_observer and ctx.best is not None and ctx.series[ctx.best].has_position_sigma
        caption_h = 0.06  # x label, tick labels and the two-line caption under the plan
        avail = y - 0.02 - low - caption_h
        width = 0.64
        natural = width * L.A4_IN[0] / L.A4_IN[1] * plan_aspect(ctx)  # the box the map needs at equal scale
        plan_h = min(avail - (0.16 if strip else 0.0), max(natural, 0.3))
        if plan_h < 0.12:
            return
        ax = fig.add_axes([0.10, y - 0.02 - plan_h, 0.64, plan_h])
        cap = plan_view(ax, ctx)
        cap_y = y - 0.02 - plan_h - 0.036
        fig.text(0.10, cap_y, "\n".join(textwrap.wrap("Plan: " + cap, 125)), fontsize=6.6, color=L.GREY, va="top")
        if strip:
            s_top = cap_y - 0.03
            if s_top - low > 0.07:
                _accuracy_strip(fig, ctx, s_top, max(low + 0.03, s_top - 0.16))

    return Section("summary", f"tpos report: {ctx.name}", PAGE_TOP - PAGE_BOTTOM - 0.05, draw, subtitle, new_page=True)
