"""The PDF: page 1, then the sections of each kind of run packed onto pages (at most `MAX_PAGES`
by default), the Allan page of a log at rest long enough (`_static_noise`), the `--full` appendix, and a footer
with the provenance and page numbers on every page (vector output through matplotlib)."""

from __future__ import annotations

import logging
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

from tpos_cli.report import tables, timeplots
from tpos_cli.report.appendix import appendix_sections
from tpos_cli.report.context import ReportContext
from tpos_cli.report.layout import footer
from tpos_cli.report.rest import rest_stretches, solution_velocity
from tpos_cli.report.sections import PAGE_BOTTOM, PAGE_TOP, Section, compose
from tpos_cli.report.stages import StageClock, timed
from tpos_cli.report.summary import summary_section

MAX_PAGES = 8
# Text extents measured from unhinted glyph outlines, as the PDF draws them (matplotlib lays out the
# glyphs it writes without hinting; its default measures hinted ones, which places right-aligned and
# centred text by a width that is not the drawn one, and costs ~30 % more per measured string).
# Deflate level 3 instead of 6: the drive hour's ~0.9 MB of page streams compress in 15 ms instead of
# 38 ms, for a file ~6 % larger (zlib on the streams captured from a report, /work/notes/report5.md).
PDF_RC = {"text.hinting": "no_hinting", "pdf.compression": 3}
# Pages whose every string is in the PDF's standard encoding (cp1252: Latin letters, ± ° µ ² ×) draw
# their text in the standard Helvetica, which every PDF viewer has, instead of an embedded DejaVu
# Sans: no glyph layout per string (about a tenth of the time: 0.10 against 0.92 s for 700 strings),
# about a third of a report's drawing. Mathtext ($...$) keeps its embedded fonts. Tick labels come
# from formatters at draw time: plain ASCII with the hyphen minus below.
CORE_FONT_RC = {"pdf.use14corefonts": True, "axes.unicode_minus": False}


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


def _static_noise(ctx: ReportContext):
    """(NoiseFigures, (w0, w1) logger clock) of the longest stretch at rest by the IMU
    (`noise.longest_static_window`) and, where the best solution has a velocity, by that velocity
    too (`rest.rest_stretches`: the IMU test alone also passes driving straight at constant speed);
    None when no such stretch lasts `noise.MIN_STATIC_S`."""
    from tpos_cli.noise import MIN_STATIC_S, identify_noise, longest_static_window, session_noise
    from tpos_cli.session import load_imu

    vel = solution_velocity(ctx.run.trajectory, ctx.best)
    if vel is None:
        return session_noise(ctx.session if ctx.session.imu is not None else replace(ctx.session, imu=load_imu(ctx.session)))
    stretches = rest_stretches(*vel, MIN_STATIC_S)  # usually none (a drive) or a few stops
    if len(stretches) == 0:
        return None
    imu, t0 = load_imu(ctx.session), ctx.session.t0_s  # read only now (build._load_session)
    best = (0, 0)
    for a, b in stretches:
        i0, i1 = int(np.searchsorted(imu.t_s, a - t0, side="left")), int(np.searchsorted(imu.t_s, b - t0, side="right"))
        j0, j1 = longest_static_window(imu.t_s[i0:i1], imu.gyro_b_rps[i0:i1], imu.acc_b_mps2[i0:i1])
        if j1 > j0 and (best == (0, 0) or imu.t_s[i0 + j1 - 1] - imu.t_s[i0 + j0] > imu.t_s[best[1] - 1] - imu.t_s[best[0]]):
            best = (i0 + j0, i0 + j1)
    i0, i1 = best
    if i1 - i0 < 100 or imu.t_s[i1 - 1] - imu.t_s[i0] < MIN_STATIC_S:
        return None
    nf = identify_noise(imu.t_s[i0:i1], imu.gyro_b_rps[i0:i1], imu.acc_b_mps2[i0:i1])
    return nf, (float(imu.t_s[i0] + t0), float(imu.t_s[i1 - 1] + t0))


def _allan_section(ctx: ReportContext) -> Section | None:
    if ctx.session is None or ctx.session_note:
        return None
    static = _static_noise(ctx)  # a log at rest for >= 100 s: its IMU noise figures
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
        f"Overlapping Allan deviation per axis (IEEE Std 952-1997 Annex C) over the longest stretch at rest, "
        f"{w0 - ctx.t_ref:.1f}-{w1 - ctx.t_ref:.1f} s after the first IMU sample.",
        new_page=True,
    )


def write_pdf(path: Path, ctx: ReportContext, summary: dict, clock: StageClock | None = None) -> list[str]:
    """Write the report to `path`; returns the page names in order (sections joined by "+").
    Stages timed on `clock`: the section plan, each figure, the Allan static window, PDF writing."""
    import matplotlib

    matplotlib.use("Agg")
    with matplotlib.rc_context(PDF_RC):
        return _write_pdf(path, ctx, summary, clock)


def _write_pdf(path: Path, ctx: ReportContext, summary: dict, clock: StageClock | None) -> list[str]:
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
    for k, (_, fig) in enumerate(pages):
        footer(
            fig,
            f"{ctx.name} | pipeline {s.get('pipeline')} | config {str(s.get('config_sha256'))[:12]} | "
            f"report {summary['report_utc']} | page {k + 1} of {n}",
        )
    with (
        timed(clock, "PDF writing"),
        core_fonts_if_they_fit([fig for _, fig in pages]),
        PdfPages(
            path,
            metadata={
                "Title": f"tpos report: {ctx.name}",
                "Creator": f"tpos {summary['tpos_version']}",
                "Subject": f"config sha256 {s.get('config_sha256')}",
            },
        ) as pdf,
    ):
        for _, fig in pages:
            pdf.savefig(fig)
    return [name for name, _ in pages]


def _in_core_font(text: str) -> bool:
    """True when `text` draws in a standard PDF font: mathtext (an even number of "$", drawn with
    its own embedded fonts) or every character in cp1252, the fonts' WinAnsi encoding."""
    if text.count("$") >= 2 and text.count("$") % 2 == 0:
        return True
    try:
        text.encode("cp1252")
    except UnicodeEncodeError:
        return False
    return True


class _RegularIsMedium:
    """Drops matplotlib's "Failed to find font weight normal for Helvetica, now using medium": the
    standard Helvetica's metrics file names its regular weight Medium, which is the font wanted."""

    @staticmethod
    def filter(record) -> bool:
        return not str(record.msg).startswith("findfont: Failed to find font weight")


@contextmanager
def core_fonts_if_they_fit(figures: list):
    """Draw `figures` with `CORE_FONT_RC` when every string they hold fits a standard PDF font
    (`_in_core_font`), else as they are (embedded DejaVu Sans: any Unicode, e.g. a session named in
    Greek or Japanese)."""
    import matplotlib
    from matplotlib.text import Text

    fits = all(_in_core_font(t.get_text()) for fig in figures for t in fig.findobj(Text))
    if not fits:
        yield False
        return
    log = logging.getLogger("matplotlib.font_manager")
    quiet = _RegularIsMedium()
    log.addFilter(quiet)
    try:
        with matplotlib.rc_context(CORE_FONT_RC), _standard_font_metrics_only():
            yield True
    finally:
        log.removeFilter(quiet)


@contextmanager
def _standard_font_metrics_only():
    """matplotlib's font manager with only the metrics files of the standard PDF fonts in its list.
    Its look-up in that directory (one per font size and weight of the pages, ~20) tests each of the
    ~60 metrics files it knows against the directory with pathlib and skips the others: ~5 ms a look-up
    (0.1 s of a report). Listing the directory's own files first gives the same fonts in the same order,
    so the same choice; the full list is back afterwards."""
    from matplotlib import font_manager, get_data_path

    manager = font_manager.fontManager
    full = manager.afmlist
    core_dir = Path(get_data_path(), "fonts", "pdfcorefonts")  # the PDF backend's standard-font directory
    manager.afmlist = [f for f in full if core_dir in Path(f.fname).parents]  # the test matplotlib applies
    try:
        yield
    finally:
        manager.afmlist = full
