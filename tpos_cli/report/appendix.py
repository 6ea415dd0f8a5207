"""The `--full` appendix: the accuracy of every segment, every innovation stream, every shot of
every solution, and the tables laid out like the papers' (titles name the quantity; the note says
whose layout it follows)."""

from __future__ import annotations

import numpy as np

from tpos_cli.io.columns import Columns, as_text, flags, groups
from tpos_cli.report import layout as L
from tpos_cli.report.context import ReportContext
from tpos_cli.report.format import length_unit
from tpos_cli.report.sections import Section
from tpos_cli.report.timeplots import PANEL_H, draw_nis, panel_axes

ROWS = 52
FONT = 6.6
PAPER_LAYOUTS = {
    "paper000_table4": (
        "Target error per attitude source",
        "Mean and SD of the 3-D target error over all shots with surveyed truth (the layout of Table 4 of the target-positioning paper).",
    ),
    "paper002_table1": (
        "Horizontal error components",
        "Error range and variance of east (x) and north (y) and the largest and average "
        "horizontal error (the layout of Table 1 of the ranging paper; its axes are assumed east and north).",
    ),
}


def _chunks(df, n: int = ROWS):
    """Consecutive parts of at most `n` rows of a `Columns` (the accuracy table) or a DataFrame (the shots)."""
    if isinstance(df, Columns):
        return [df.take(np.arange(i, min(i + n, len(df)))) for i in range(0, len(df), n)]
    return [df.iloc[i : i + n] for i in range(0, len(df), n)]


def _long_table(name: str, title: str, subtitle: str, df, columns) -> list[Section]:
    """A table of many rows as consecutive sections of `ROWS` rows; the subtitle on the first."""
    out = []
    for k, part in enumerate(_chunks(df)):
        cols = columns(part)

        def draw(fig, top, bottom, cols=cols):
            L.draw_table(fig, top, cols, fontsize=FONT)

        out.append(Section(name, title + (f" ({k + 1})" if k else ""), L.table_height(len(part), FONT) + 0.01, draw, "" if k else subtitle))
    return out


def segment_sections(ctx: ReportContext) -> list[Section]:
    t = ctx.acc.table
    keep = t.take(np.isin(t["quantity"], ["pos_3d_m", "pos_h_m", "pos_v_m", "roll_deg", "pitch_deg", "yaw_deg", "att_deg"]) & (t["n"] > 0))

    def columns(part):
        cols = [
            L.Column("solution", list(part["solution"]), align="left"),
            L.Column("target", [v or "-" for v in part["target"]], align="left"),
            L.Column("segment", list(part["segment"]), align="left"),
            L.Column("quantity", list(part["quantity"]), align="left"),
            L.Column("n", [str(v) for v in part["n"]]),
        ]
        return cols + [L.Column(s, L.fmt_num(part[s], 4), "m or deg") for s in ("mean", "sd", "rms", "max_abs", "p95")]

    return _long_table(
        "appendix_segments",
        "Appendix: accuracy by segment",
        "Segments: all; outage / gps = inside / outside GPS outages and --mask-gps windows; outage_k = each window; movement = "
        "the truth's movement phase; withheld = epochs judged against withheld GPS fixes. Quantities ending _m are metres, _deg degrees.",
        keep,
        columns,
    )


def innovation_sections(ctx: ReportContext) -> list[Section]:
    inn = ctx.run.innovations
    if inn is None or not len(inn):
        return []
    out = []
    labels = [as_text(inn[c]) for c in ("solution", "kind")]
    for (sol, kind), idx in groups(*labels):
        d = inn.take(idx)

        def draw(fig, top, bottom, d=d, kind=kind):
            (ax,) = panel_axes(fig, 1, top, bottom)
            draw_nis(ax, ctx, d)
            L.style_axis(ax, f"NIS, {kind}")
            ax.set_xlabel(ctx.time_label, fontsize=8)

        out.append(
            Section(
                "appendix_nis",
                f"Appendix: innovations, {sol} {kind}",
                PANEL_H + 0.02,
                draw,
                f"{int((~flags(d, 'accepted')).sum())} of {len(d)} updates rejected (x); band: chi-square 95 %.",
            )
        )
    return out


def shot_sections(ctx: ReportContext) -> list[Section]:
    tg = ctx.run.targets
    if tg is None or not len(tg):
        return []
    unit, sc, dec = length_unit(tg["sigma_n"].to_numpy(float) if "sigma_n" in tg else [0.01])

    def columns(part):
        empty = [""] * len(part)
        cols = [
            L.Column("solution", list(part["solution"].astype(str)), align="left"),
            L.Column("target", list(part["id"].astype(str)), align="left"),
            L.Column("start", L.fmt_num(part["t_start"] - ctx.t_ref, 1) if "t_start" in part else empty, "s"),
            L.Column("latitude", L.fmt_num(part["lat"], 8), "deg"),
            L.Column("longitude", L.fmt_num(part["lon"], 8), "deg"),
            L.Column("height", L.fmt_num(part["h"], 3), "m"),
        ]
        sds = (("sigma_n", "SD N"), ("sigma_e", "SD E"), ("sigma_u", "SD U"))
        return cols + [L.Column(h, L.fmt_num(part[c], dec, sc) if c in part else empty, unit) for c, h in sds]

    return _long_table(
        "appendix_shots", "Appendix: every shot of every solution", "WGS-84, heights above the ellipsoid; SD = 1 sigma.", tg, columns
    )


def layout_sections(ctx: ReportContext) -> list[Section]:
    out = []
    for key, (title, note) in PAPER_LAYOUTS.items():
        df = ctx.acc.paper_tables.get(key)
        if df is None or not len(df):
            continue
        cols = [
            L.Column(c, L.fmt_num(df[c], 0 if df[c].dtype.kind in "iu" else 4))
            if df[c].dtype.kind in "iufb"  # pandas' is_numeric_dtype: bool counts; labels are str in object arrays
            else L.Column(c, [str(v) for v in df[c].tolist()], align="left")
            for c in df.columns
        ]

        def draw(fig, top, bottom, cols=cols):
            L.draw_table(fig, top, cols, fontsize=7.2)

        out.append(Section("appendix_" + key, f"Appendix: {title}", L.table_height(len(df), 7.2) + 0.01, draw, note))
    return out


def appendix_sections(ctx: ReportContext) -> list[Section]:
    return segment_sections(ctx) + innovation_sections(ctx) + shot_sections(ctx) + layout_sections(ctx)
