"""Sections and their packing onto A4 pages.

A section is a heading (title, grey subtitle) and a content band of known height that a closure
draws. `compose` fills each page from the top with as many sections as fit, so a short table does
not leave a page 70 % blank and a page is only started when the next section needs the room.
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable
from dataclasses import dataclass

from matplotlib.figure import Figure

from tpos_cli.report import layout as L
from tpos_cli.report.stages import StageClock, timed

PAGE_TOP = 0.972
PAGE_BOTTOM = 0.035
SECTION_GAP = 0.022
TITLE_H = 0.022
SUBTITLE_LINE_H = 0.0125
SUBTITLE_WRAP = 125


@dataclass(frozen=True)
class Section:
    """`draw(fig, top, bottom)` fills the content band; `height` is its figure fraction."""

    name: str
    title: str
    height: float
    draw: Callable[[Figure, float, float], None]
    subtitle: str = ""
    new_page: bool = False  # always start a page (page 1, full-page figures)
    floating: bool = False  # may fill the free space of an earlier page (tables of figures)

    def heading_height(self) -> float:
        n = len(textwrap.wrap(self.subtitle, SUBTITLE_WRAP)) if self.subtitle else 0
        return TITLE_H + n * SUBTITLE_LINE_H + 0.006


def _heading(fig: Figure, s: Section, top: float, first: bool) -> float:
    fig.text(L.MARGIN_L, top, s.title, ha="left", va="top", fontsize=13 if first else 11.5, weight="bold")
    y = top - TITLE_H
    if s.subtitle:
        lines = textwrap.wrap(s.subtitle, SUBTITLE_WRAP)
        fig.text(L.MARGIN_L, y, "\n".join(lines), ha="left", va="top", fontsize=7.8, color=L.GREY, linespacing=1.25)
        y -= len(lines) * SUBTITLE_LINE_H
    return y - 0.006


def compose(sections: list[Section], clock: StageClock | None = None) -> list[tuple[str, Figure]]:
    """Pages holding the sections: the fixed ones in order, each page filled from the top; then each
    floating section on the page with the most room below its content (else on a new page at the end).
    Returns (page name = its sections' names joined by "+", figure). Each section's drawing is timed
    on `clock` as "figure: NAME"."""
    pages: list[list] = []  # [names, figure, free y]

    def place(s: Section, page: list | None) -> None:
        if page is None:
            page = [[], Figure(figsize=L.A4_IN, dpi=L.RASTER_DPI), PAGE_TOP]
            pages.append(page)
        first = not page[0]
        page[0].append(s.name)
        top = _heading(page[1], s, page[2], first)
        bottom = max(top - s.height, PAGE_BOTTOM)
        with timed(clock, f"figure: {s.name}"):
            s.draw(page[1], top, bottom)
        page[2] = bottom - SECTION_GAP

    def fits(s: Section, page: list) -> bool:
        return s.heading_height() + s.height <= page[2] - PAGE_BOTTOM

    for s in (x for x in sections if not x.floating):
        last = pages[-1] if pages else None
        place(s, last if last is not None and not s.new_page and fits(s, last) else None)
    for s in (x for x in sections if x.floating):
        # the page with the most room that takes it (page 1 is the summary: nothing joins it), so
        # that free space spreads instead of one page filling and another staying blank
        room = [p for p in pages[1:] if fits(s, p)]
        place(s, max(room, key=lambda p: p[2]) if room else None)
    return [("+".join(names), fig) for names, fig, _ in pages]
