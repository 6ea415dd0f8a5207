"""The PDF's fonts: the standard Helvetica when every string fits its encoding, else embedded DejaVu Sans."""

from __future__ import annotations

import logging

import matplotlib
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from tpos_cli.report.pdf import _in_core_font, core_fonts_if_they_fit

matplotlib.use("Agg")


def _pdf(tmp_path, text: str) -> bytes:
    fig = Figure(figsize=(4, 3))
    fig.text(0.1, 0.8, text)
    fig.text(0.1, 0.5, r"$\sigma_{yaw}$ 1.2 deg")
    ax = fig.add_axes([0.2, 0.1, 0.6, 0.3])
    ax.plot([-2.0, 1.0], [-1.0, 3.0])
    path = tmp_path / "p.pdf"
    with core_fonts_if_they_fit([fig]), PdfPages(path) as pdf:
        pdf.savefig(fig)
    return path.read_bytes()


def test_cp1252_text_is_drawn_in_the_standard_helvetica_and_mathtext_keeps_its_font(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="matplotlib.font_manager"):
        raw = _pdf(tmp_path, "yaw 1.20 ± 0.05 deg, 3 µs, x²")
    assert b"/BaseFont /Helvetica" in raw
    assert b"DejaVuSans-Oblique" in raw  # the mathtext sigma, embedded
    assert not caplog.records  # Helvetica's regular weight is named Medium: no warning about it
    assert not matplotlib.rcParams["pdf.use14corefonts"]  # restored after the write


def test_text_outside_cp1252_keeps_the_embedded_font(tmp_path):
    raw = _pdf(tmp_path, "session Проезд_03 ≤ 2 m")
    assert b"/BaseFont /Helvetica" not in raw
    assert b"DejaVuSans" in raw


def test_in_core_font():
    assert _in_core_font("1.5 m ± 0.2, 90°, 3 µs, Straße")
    assert _in_core_font(r"$\delta$ offset")
    assert not _in_core_font("τ 10 s") and not _in_core_font("10⁻¹") and not _in_core_font("a − b")


def test_the_standard_fonts_are_found_as_matplotlib_finds_them_and_its_font_list_is_back_after(tmp_path):
    """`core_fonts_if_they_fit` lists only the standard fonts' metrics files while the pages are drawn (a
    faster look-up): each font property picks the same file as matplotlib's look-up over its whole list,
    which is whole again afterwards."""
    from matplotlib import font_manager
    from matplotlib.backends.backend_pdf import RendererPdf
    from matplotlib.font_manager import FontProperties

    manager = font_manager.fontManager
    full = list(manager.afmlist)
    props = [
        FontProperties(family=family, size=size, weight=weight, style=style)
        for family in ("sans-serif", "serif", "monospace", "DejaVu Sans", "Helvetica")
        for size in (6.5, 8.0, 13.0)
        for weight in ("normal", "bold")
        for style in ("normal", "italic")
    ]

    def found():
        manager._findfont_cached.cache_clear()  # each look-up done again over the list in force
        return [manager.findfont(p, fontext="afm", directory=RendererPdf._afm_font_dir) for p in props]

    logging.getLogger("matplotlib.font_manager").disabled = True  # the fallback warnings of absent families
    try:
        expected = found()
        fig = Figure(figsize=(4, 3))
        fig.text(0.1, 0.5, "x")
        with core_fonts_if_they_fit([fig]) as fits:
            assert fits and len(manager.afmlist) < len(full)
            got = found()
    finally:
        logging.getLogger("matplotlib.font_manager").disabled = False
    assert got == expected and len(set(expected)) > 4  # several distinct fonts chosen, all the same
    assert manager.afmlist == full
    manager._findfont_cached.cache_clear()
