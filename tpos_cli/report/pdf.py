"""The multi-page A4 PDF report (vector output through matplotlib's PdfPages)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from tpos_cli.report import figures as F

PAPER_TITLES = {
    "paper000_table4": "Target positioning error per attitude source (shaped like paper 000 Tables 4-5)",
    "paper002_table1": "Horizontal error components (shaped like paper 002 Table 1; x = east, y = north)",
    "paper003_outages": "Errors inside each GPS outage (paper 003's outage comparison)",
}
PAPER_NOTES = {
    "paper000_table4": "Mean and SD of the 3-D target position error (paper 000 Eq. 28) over all shots with surveyed truth.",
    "paper002_table1": "Error range (min~max) and variance of the east (x) and north (y) error; max and average of the horizontal error. "
    "The paper does not state its axes; east/north is assumed.",
    "paper003_outages": "Horizontal RMS/max and vertical RMS error over the epochs inside each window (forward vs smoothed shows what smoothing buys).",
}


def _fmt_windows(w) -> str:
    w = np.asarray(w, dtype=float).reshape(-1, 2)
    if not w.size:
        return "none"
    s = ", ".join(f"[{a:.1f}, {b:.1f}]" for a, b in w[:8])
    return s + (f" and {len(w) - 8} more" if len(w) > 8 else "")


def cover_lines(run, session, truth, summary) -> list[tuple[str, str]]:
    s = run.summary
    lines = [
        ("Session", f"{session.meta.name} ({session.meta.kind})"),
        ("Session path", str(truth.session_path)),
        ("Run directory", str(run.path)),
        ("Pipeline", str(s.get("pipeline"))),
        ("tpos version", f"report {summary['tpos_version']}, run {s.get('tpos_version')}"),
        ("Config SHA-256", str(s.get("config_sha256"))),
        ("Run created (UTC)", str(s.get("created_utc"))),
        ("Report date (UTC)", summary["report_utc"]),
        ("Truth: trajectory", truth.trajectory.description if truth.trajectory is not None else "none (no trajectory, or no trajectory truth)"),
        ("Truth: targets", truth.targets.description if truth.targets is not None else "none"),
        ("GPS outages", _fmt_windows(run.outage_windows)),
        ("--mask-gps windows", _fmt_windows(run.mask_windows)),
        ("Input files (SHA-256)", ""),
    ]
    for name, h in sorted((s.get("inputs") or {}).items()):
        lines.append((f"  {name}", str(h)))
    warns = list(s.get("warnings") or [])
    if warns:
        lines.append(("Run warnings", f"{len(warns)}: " + "; ".join(warns[:5]) + (" ..." if len(warns) > 5 else "")))
    return lines


def _headline_df(summary) -> pd.DataFrame:
    rows = summary["headline"]
    if not rows:
        return pd.DataFrame()
    df = pd.DataFrame(rows)
    names = {
        "rms_pos_3d_m": "RMS 3-D m", "rms_pos_h_m": "RMS hor. m", "rms_pos_v_m": "RMS vert. m",
        "p95_pos_h_m": "p95 hor. m", "max_pos_3d_m": "max 3-D m", "mean_pos_3d_m": "mean 3-D m", "sd_pos_3d_m": "SD 3-D m",
        "cep_m": "CEP m", "ce90_m": "CE90 m", "rms_roll_deg": "RMS roll deg", "rms_pitch_deg": "RMS pitch deg", "rms_yaw_deg": "RMS yaw deg", "rms_att_deg": "RMS total angle deg",
    }
    df = df.rename(columns=names)
    return df.astype({c: float for c in df.columns if c in names.values()})


def _segment_df(acc) -> pd.DataFrame:
    t = acc.table
    keep = t[(t["quantity"].isin(["pos_3d_m", "pos_h_m", "pos_v_m", "roll_deg", "pitch_deg", "yaw_deg"])) & (t["n"] > 0)]
    out = keep[["solution", "target", "segment", "quantity", "n", "mean", "sd", "rms", "max_abs", "p50", "p95"]].copy()
    out["target"] = out["target"].replace("", "-")
    out["n"] = out["n"].astype(str)
    return out


def write_pdf(path: Path, run, session, truth, acc, health, summary) -> list[str]:
    """Write the report; returns the page titles in order (for tests and the CLI line)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_pdf import PdfPages

    pages: list[tuple[str, object]] = []
    pages.append(("cover", F.text_page("tpos accuracy report", cover_lines(run, session, truth, summary), "what was processed, how, and what it is judged against")))
    conv = summary["conventions"]
    hd = _headline_df(summary)
    if not hd.empty:
        hd = hd.map(lambda v: "" if isinstance(v, float) and not np.isfinite(v) else (f"{v:.4g}" if isinstance(v, float) else str(v)))
        # one column per (solution, trajectory|targets); the "of" row tells the two apart
        hd = hd.set_index("solution").T.reset_index().rename(columns={"index": "statistic"})
    per_page = 5  # more columns do not fit A4 portrait at a readable size
    n_cols = max(hd.shape[1] - 1, 1) if not hd.empty else 1
    for start in range(0, n_cols, per_page):
        part = hd.iloc[:, [0] + list(range(1 + start, min(1 + start + per_page, hd.shape[1])))] if not hd.empty else hd
        k = max(part.shape[1] - 1, 1)
        for fig in F.table_pages("Summary: errors per solution (all epochs / all targets)", part, conv, fontsize=8.5,
                                 col_width=[0.26] + [0.74 / k] * k if not part.empty else None):
            pages.append(("summary", fig))
    for key, df in acc.paper_tables.items():
        for fig in F.table_pages(PAPER_TITLES[key], df, PAPER_NOTES[key]):
            pages.append((key, fig))
    for fig in F.table_pages("Accuracy by segment", _segment_df(acc), "Segments: all; outage / gps = inside / outside GPS outages and --mask-gps windows; "
                             "outage_k = each window; movement = truth's movement phase; withheld = epochs judged against withheld (independent) GPS fixes. " + conv):
        pages.append(("segments", fig))
    if len(health.nis) or len(health.disagreement) or len(health.flags):
        hn = health.nis.copy()
        if len(hn):
            hn["consistent"] = hn["consistent"].map({True: "yes", False: "NO"})
            for c in ("n", "n_accepted", "n_rejected"):
                hn[c] = hn[c].astype(str)
        notes = ("Mean NIS over accepted updates should lie inside [mean_lo, mean_hi] (chi-square, 95 %); frac_above_95 should be near 0.05. ")
        if len(health.disagreement):
            notes += " Forward/backward: " + "; ".join(
                f"{r.a} vs {r.b}: RMS {r.rms_m:.3g} m, max {r.max_m:.3g} m, {r.n_flagged} of {r.n} epochs beyond their 99 % chi-square (3 dof)" for r in health.disagreement.itertuples())
        if len(health.flags):
            notes += " Chain flags: " + "; ".join(f"{r.solution}: {r.n_flagged} of {r.n_epochs} epochs flagged" for r in health.flags.itertuples())
        for fig in F.table_pages("Filter health (no truth needed)", hn, notes, fontsize=7.5):
            pages.append(("health", fig))
    sols = list(acc.solutions)
    if sols:
        t_ref = float(min(se.t[0] for se in sols if se.t.size))
        origin = truth.trajectory.lla[np.all(np.isfinite(truth.trajectory.lla), axis=1)][0]
        for fig in F.trajectory_maps(sols, truth.trajectory, run.outage_windows, origin):
            pages.append(("trajectory", fig))
        pages.append(("position_error", F.position_error_page(sols, run.outage_windows, t_ref)))
        for fig in F.attitude_pages(sols, t_ref, truth.trajectory):
            pages.append(("attitude", fig))
        if any(se.att_err_deg is not None for se in sols):
            note = "; green band: truth's movement phase" if any(se.movement is not None for se in sols) else ""
            pages.append(("attitude_error", F.attitude_error_page(sols, t_ref, note)))
    else:
        t_ref = float(run.trajectory["t"].min()) if run.trajectory is not None else 0.0
    if run.innovations is not None and len(run.innovations):
        for fig in F.nis_pages(run.innovations, t_ref, run.outage_windows):
            pages.append(("nis", fig))
    if acc.targets is not None and len(acc.targets):
        pages.append(("target_scatter", F.target_scatter_page(acc.targets)))
        te = acc.targets.drop(columns=["t_start"]).rename(columns=lambda c: c.replace("_m", " m"))
        for fig in F.table_pages("Per-target errors against surveyed truth", te, "err = solution - surveyed truth (north, east, up); cep_pred = CEP predicted from sigma_n, sigma_e.", fontsize=7):
            pages.append(("targets", fig))
    from tpos_cli.noise import session_noise

    static = session_noise(session)  # a log static for >= 100 s: its IMU noise figures
    if static is not None:
        nf, (w0, w1) = static
        pages.append(("allan", F.allan_page(nf, f"longest static stretch of the session, {w0:.1f}-{w1:.1f} s (logger clock)")))
    n_total = len(pages)
    with PdfPages(path, metadata={"Title": f"tpos report: {session.meta.name}", "Creator": f"tpos {summary['tpos_version']}", "Subject": f"config sha256 {run.summary.get('config_sha256')}"}) as pdf:
        for k, (_, fig) in enumerate(pages):
            fig.text(0.5, 0.012, f"{session.meta.name} | {run.summary.get('pipeline')} | config {str(run.summary.get('config_sha256'))[:12]} | page {k + 1}/{n_total}",
                     ha="center", fontsize=7, color="0.4")
            pdf.savefig(fig)
    return [name for name, _ in pages]
