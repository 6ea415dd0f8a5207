"""The PDF: page 1, then the sections of each kind of run packed onto pages (at most `MAX_PAGES`
by default), the Allan page of a log with a long static stretch, the `--full` appendix, and a footer
with the provenance and page numbers on every page (vector output through matplotlib)."""

from __future__ import annotations

from pathlib import Path

from tpos_cli.report import tables, timeplots
from tpos_cli.report.appendix import appendix_sections
from tpos_cli.report.context import ReportContext
from tpos_cli.report.layout import footer
from tpos_cli.report.sections import PAGE_BOTTOM, PAGE_TOP, Section, compose
from tpos_cli.report.stages import StageClock, timed
from tpos_cli.report.summary import summary_section

MAX_PAGES = 8


def section_plan(ctx: ReportContext, summary: dict) -> list[Section]:
    """The default sections of a run, page 1 first: what matters for its kind, nothing empty."""
    if ctx.static_observer:
        body = [
            tables.targets_section(ctx),
            tables.shots_section(ctx),
            tables.shot_truth_section(ctx),
            timeplots.sensors_section(ctx),
            timeplots.attitude_section(ctx),
            tables.target_truth_section(ctx),
        ]
    elif ctx.kind == "ranging":
        body = [timeplots.accuracy_section(ctx), timeplots.anchors_section(ctx), timeplots.attitude_section(ctx)]
    else:
        body = [
            timeplots.accuracy_section(ctx),
            timeplots.separation_section(ctx),
            timeplots.innovations_section(ctx),
            timeplots.gps_section(ctx),
            timeplots.attitude_section(ctx),
            tables.targets_section(ctx),
            tables.shots_section(ctx),
        ]
    return [summary_section(ctx, summary)] + [s for s in body if s is not None] + tables.figure_sections(ctx)


def _allan_section(ctx: ReportContext) -> Section | None:
    if ctx.session is None or ctx.session_note:
        return None
    from tpos_cli.noise import session_noise

    static = session_noise(ctx.session)  # a log static for >= 100 s: its IMU noise figures
    if static is None:
        return None
    from tpos_cli.report.figures import draw_allan

    nf, (w0, w1) = static

    def draw(fig, top, bottom):
        draw_allan(fig, nf, top - 0.02, bottom)

    return Section(
        "allan",
        "IMU noise: Allan deviation",
        PAGE_TOP - PAGE_BOTTOM - 0.08,
        draw,
        f"Overlapping Allan deviation per axis (IEEE Std 952-1997 Annex C) over the longest static stretch, "
        f"{w0 - ctx.t_ref:.1f}-{w1 - ctx.t_ref:.1f} s after the first IMU sample.",
        new_page=True,
    )


def write_pdf(path: Path, ctx: ReportContext, summary: dict, clock: StageClock | None = None) -> list[str]:
    """Write the report to `path`; returns the page names in order (sections joined by "+").
    Stages timed on `clock`: the section plan, each figure, the Allan static window, PDF writing."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_pdf import PdfPages

    with timed(clock, "section plan"):
        plan = section_plan(ctx, summary)
    pages = compose(plan, clock)
    with timed(clock, "allan: static window"):
        allan = _allan_section(ctx)
    extra = compose([allan], clock) if allan is not None else []
    if len(pages) + len(extra) <= MAX_PAGES:
        pages += extra
        extra = []
    if ctx.full:
        with timed(clock, "section plan"):
            appendix = appendix_sections(ctx)
        pages += extra + compose(appendix, clock)
    n = len(pages)
    s = ctx.run.summary
    with (
        timed(clock, "PDF writing"),
        PdfPages(
            path,
            metadata={
                "Title": f"tpos report: {ctx.name}",
                "Creator": f"tpos {summary['tpos_version']}",
                "Subject": f"config sha256 {s.get('config_sha256')}",
            },
        ) as pdf,
    ):
        for k, (_, fig) in enumerate(pages):
            footer(
                fig,
                f"{ctx.name} | pipeline {s.get('pipeline')} | config {str(s.get('config_sha256'))[:12]} | "
                f"report {summary['report_utc']} | page {k + 1} of {n}",
            )
            pdf.savefig(fig)
    return [name for name, _ in pages]
