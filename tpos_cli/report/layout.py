"""Drawing primitives of the report: A4 pages, tables typeset for people, time axes, map furniture.

Everything draws onto matplotlib `Figure`s (no pyplot state, no file I/O). Tables are typeset as
one multi-line text per column (fast to draw, aligned on the decimal point by fixed decimals), with
the unit under each header, zebra rows and no grid. Time series are drawn from at most
`MAX_POINTS` vertices per line (per-bin min and max kept, so peaks survive).
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.patches import FancyArrow, Rectangle

A4_IN = (8.27, 11.69)
RASTER_DPI = 150  # resolution of the raster layers (dense markers) inside the vector pages
MAX_POINTS = 1500  # vertices per line: a page-wide axis is ~1000 px at 150 dpi; more draw nothing new
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")
OUTAGE_COLOR = "#f4a6a6"
SHOT_COLOR = "#c6dbef"
DISTURB_COLOR = "#fdd0a2"
GREY = "0.35"
VERDICT_COLORS = {"ok": "#2ca02c", "suspect": "#ff7f0e", "unreliable": "#d62728", None: "0.55"}
MARGIN_L, MARGIN_R = 0.07, 0.95
MAX_WINDOW_LABELS = 30
ROW_PITCH = 1.45  # table row pitch in font sizes


def new_page(title: str, subtitle: str = "") -> Figure:
    """An A4 portrait page with a bold title and an optional grey subtitle (wrapped)."""
    fig = Figure(figsize=A4_IN, dpi=RASTER_DPI)
    fig.text(MARGIN_L, 0.972, title, ha="left", va="top", fontsize=13, weight="bold")
    if subtitle:
        fig.text(MARGIN_L, 0.950, "\n".join(textwrap.wrap(subtitle, 120)), ha="left", va="top", fontsize=8, color=GREY)
    return fig


def footer(fig: Figure, text: str) -> None:
    fig.text(0.5, 0.012, text, ha="center", va="bottom", fontsize=6.5, color="0.45")


def note(fig: Figure, y: float, text: str, width: int = 135, fontsize: float = 7.5, x: float = MARGIN_L) -> float:
    """Wrapped grey text from the top at `y`; returns the y below it."""
    lines = textwrap.wrap(text, width) or [""]
    fig.text(x, y, "\n".join(lines), ha="left", va="top", fontsize=fontsize, color="0.25", linespacing=1.3)
    return y - len(lines) * fontsize * 1.3 / 72.0 / A4_IN[1] - 0.006


# ------------------------------------------------------------------------------------------ tables


@dataclass(frozen=True)
class Column:
    """A table column for people: header, unit (second header line), cells already formatted."""

    header: str
    cells: Sequence[str]
    unit: str = ""
    align: str = "right"  # numbers right-aligned (fixed decimals line up), text left
    weight: float = 1.0  # relative width


def fmt_num(values, decimals: int, scale: float = 1.0, signed: bool = False) -> list[str]:
    """Fixed-decimal strings ("" for NaN/None): never scientific notation."""
    out = []
    for v in np.asarray(values, dtype=float).ravel() * scale:
        out.append("" if not np.isfinite(v) else (f"{v:+.{decimals}f}" if signed else f"{v:.{decimals}f}"))
    return out


def table_height(n_rows: int, fontsize: float = 8.0) -> float:
    """Figure-fraction height of a table of `n_rows` (two header lines)."""
    line = fontsize * ROW_PITCH / 72.0 / A4_IN[1]
    return (n_rows + 2.6) * line


def draw_table(
    fig: Figure,
    top: float,
    columns: Sequence[Column],
    *,
    left: float = MARGIN_L,
    right: float = MARGIN_R,
    fontsize: float = 8.0,
    title: str = "",
    highlight: Sequence[int] = (),
    header: bool = True,
) -> float:
    """Typeset `columns` from `top` down; returns the y below the table. Rows in `highlight` get a
    red mark in the margin; `header=False` draws a key/value list without header lines."""
    line = fontsize * ROW_PITCH / 72.0 / A4_IN[1]  # row pitch in figure fraction
    y = top
    if title:
        fig.text(left, y, title, ha="left", va="top", fontsize=fontsize + 1.5, weight="bold")
        y -= line * 1.5
    n = max((len(c.cells) for c in columns), default=0)
    # natural widths from the longest entry (DejaVu Sans digits are 0.64 em wide, bold headers
    # wider still); a table wider than the page is set in a smaller font, never with columns that
    # run into each other
    chars = np.array([max([1.1 * len(c.header), 0.9 * len(c.unit)] + [len(str(v)) for v in c.cells]) for c in columns], dtype=float)
    weights = np.array([c.weight for c in columns])

    def widths_at(fs: float) -> np.ndarray:
        return (chars * 0.62 * fs + 9.0) / 72.0 / A4_IN[0] * weights

    if widths_at(fontsize).sum() > right - left:
        fontsize = max(5.5, fontsize * (right - left) / widths_at(fontsize).sum())
        line = fontsize * ROW_PITCH / 72.0 / A4_IN[1]
    widths = widths_at(fontsize)
    widths *= min(1.0, (right - left) / widths.sum())
    right = left + widths.sum()
    x0 = left + np.concatenate([[0.0], np.cumsum(widths)[:-1]])
    body_top = y - 2.2 * line if header else y - 0.2 * line
    for r in range(0, n, 2):  # zebra: every other row shaded
        fig.add_artist(
            Rectangle(
                (left, body_top - (r + 1) * line),
                right - left,
                line,
                transform=fig.transFigure,
                facecolor="#f2f2f2",
                edgecolor="none",
                zorder=0,
            )
        )
    if header:
        fig.add_artist(Rectangle((left, body_top), right - left, 0.0008, transform=fig.transFigure, facecolor="0.3", edgecolor="none"))
    pad = 0.006
    for c, xl, w in zip(columns, x0, widths):
        ha = "right" if c.align == "right" else "left"
        xt = xl + w - pad if ha == "right" else xl + pad
        if header:
            fig.text(xt, y, c.header, ha=ha, va="top", fontsize=fontsize, weight="bold")
        if header and c.unit:
            fig.text(xt, y - line, c.unit, ha=ha, va="top", fontsize=fontsize - 1, color=GREY)
        for r, v in enumerate(c.cells):  # one text per cell: matplotlib's multi-line spacing depends on font hinting
            if v != "":
                fig.text(xt, body_top - r * line - 0.5 * line, str(v), ha=ha, va="center_baseline", fontsize=fontsize)
    for r in highlight:
        fig.add_artist(
            Rectangle((left, body_top - (r + 1) * line), 0.004, line, transform=fig.transFigure, facecolor="#d62728", edgecolor="none")
        )
    return body_top - n * line - 0.01


# ------------------------------------------------------------------------------------- time series


def decimate(y, max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of at most ~max_points samples of `y`: per bin the first, min and max (NaN-aware), so
    peaks and line breaks survive. Vectorised: one reshape, no loop over bins."""
    y = np.asarray(y, dtype=float)
    n = y.size
    if n <= max_points:
        return np.arange(n)
    k = int(np.ceil(n / (max_points // 3)))
    nb = int(np.ceil(n / k))
    pad = np.full(nb * k, np.nan)
    pad[:n] = y
    b = pad.reshape(nb, k)
    allnan = np.all(np.isnan(b), axis=1)
    safe_lo = np.where(np.isnan(b), np.inf, b)
    safe_hi = np.where(np.isnan(b), -np.inf, b)
    base = np.arange(nb) * k
    lo = base + np.argmin(safe_lo, axis=1)
    hi = base + np.argmax(safe_hi, axis=1)
    first_nan = base + np.argmax(np.isnan(b), axis=1)  # a NaN in the bin keeps the line broken there
    has_nan = np.any(np.isnan(b), axis=1)
    idx = np.concatenate([base, np.where(allnan, base, lo), np.where(allnan, base, hi), first_nan[has_nan]])
    return np.unique(idx[idx < n])


BIN_STEPS_S = (1.0, 2.0, 5.0, 10.0, 15.0, 30.0, 60.0, 120.0, 300.0, 600.0, 900.0, 1800.0, 3600.0)


@dataclass(frozen=True)
class Binned:
    """A series summarised per time bin: bin starts (s, as the input), min / median / max per bin
    (NaN where a bin holds no finite value), the bin length (s)."""

    t0_s: np.ndarray
    lo: np.ndarray
    med: np.ndarray
    hi: np.ndarray
    bin_s: float


def binned_range(t_s, y, max_bins: int = 240) -> Binned | None:
    """Min, median and max of `y` over time bins of a round length (BIN_STEPS_S) with at most
    `max_bins` bins, or None for a series of at most 2 max_bins samples (a page-wide axis shows
    each of them: draw the samples themselves). A value that flips every sample (satellites used, 8-9-8 ...) drawn as a
    step line over an hour is a solid bar; its range and median per minute read."""
    t_s, y = np.asarray(t_s, dtype=float), np.asarray(y, dtype=float)
    if t_s.size <= 2 * max_bins:
        return None
    span = float(t_s[-1] - t_s[0])
    bin_s = next((b for b in BIN_STEPS_S if span / b < max_bins), span / max_bins)
    k = np.floor((t_s - t_s[0]) / bin_s).astype(np.int64)
    nb = int(k[-1]) + 1
    lo, med, hi = (np.full(nb, np.nan) for _ in range(3))
    starts = np.searchsorted(k, np.arange(nb))  # t sorted: the bins are contiguous runs
    for b, (i, j) in enumerate(zip(starts, np.append(starts[1:], k.size))):
        v = y[i:j][np.isfinite(y[i:j])]
        if v.size:
            lo[b], med[b], hi[b] = v.min(), np.median(v), v.max()
    return Binned(t_s[0] + bin_s * np.arange(nb), lo, med, hi, float(bin_s))


def bin_label(bin_s: float) -> str:
    """'per minute', 'per 5 s' ... for a legend."""
    if bin_s >= 60.0 and bin_s % 60.0 == 0.0:
        m = int(bin_s // 60)
        return "per minute" if m == 1 else f"per {m} min"
    return f"per {bin_s:g} s"


def time_axis(t_s, t_ref: float) -> tuple[np.ndarray, str, float]:
    """x values, label and scale: seconds for logs under 20 minutes, minutes above."""
    t = np.asarray(t_s, dtype=float) - t_ref
    span = float(np.nanmax(t) - np.nanmin(t)) if t.size else 0.0
    if span > 1200.0:
        return t / 60.0, "time since the first IMU sample, min", 60.0
    return t, "time since the first IMU sample, s", 1.0


def plot_series(ax, x, y, **kw) -> None:
    i = decimate(y)
    ax.plot(np.asarray(x)[i], np.asarray(y, dtype=float)[i], **kw)


def scatter_points(ax, x, y, **kw) -> None:
    """Many markers (innovations: one per update, thousands an hour) as one raster layer in the
    vector page: the same picture, a small file that writes and displays fast."""
    ax.plot(x, y, ls="none", rasterized=len(x) > 500, **kw)


def robust_ylim(ax, arrays, symmetric: bool = False, floor: float = 0.0, pct: float = 99.5) -> None:
    """y limits from the `pct` percentile of |values| (times 1.25) so that a few spikes (an Euler
    angle through gimbal lock, a transient) do not flatten everything else; the axis says how many
    samples lie beyond it."""
    v = np.concatenate([np.abs(np.asarray(a, dtype=float)).ravel() for a in arrays]) if arrays else np.empty(0)
    v = v[np.isfinite(v)]
    if v.size < 20:
        return
    _clip_y(ax, v, 1.25 * float(np.percentile(v, pct)), symmetric, floor)


def ylim_past_startup(ax, series, startup: float, symmetric: bool = False, floor: float = 0.0) -> None:
    """y limits from what each (x, y) series shows after its first and before its last `startup` (x
    units): a filter's first epochs carry its initial covariance (metres to tens of metres, for a
    second or two, at the start of a forward run and the end of a backward one), which would
    flatten an hour of centimetres. Everything later, GPS outages included, keeps its full height;
    the axis says how many samples lie beyond it."""
    inner, every = [], []
    for x, y in series:
        x, y = np.asarray(x, dtype=float), np.abs(np.asarray(y, dtype=float))
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        if x.size:
            inner.append(y[(x >= x.min() + startup) & (x <= x.max() - startup)])
            every.append(y)
    if not every or sum(a.size for a in inner) < 20:
        return
    _clip_y(ax, np.concatenate(every), 1.05 * float(np.concatenate(inner).max()), symmetric, floor)


def _clip_y(ax, v: np.ndarray, lim: float, symmetric: bool, floor: float) -> None:
    """Limit the y axis to `lim` (|value|) when the largest |value| `v` goes more than 10 % beyond
    it, with a note of how many lie beyond."""
    if not lim > 0 or float(v.max()) <= 1.1 * lim:
        return
    ax.set_ylim(-lim if symmetric else floor, lim)
    n = int(np.sum(v > lim))
    ax.text(
        0.995,
        0.97,
        f"{n} sample{'s' if n != 1 else ''} beyond this axis (max {v.max():.3g})",
        transform=ax.transAxes,
        ha="right",
        va="top",
        fontsize=6.5,
        color="0.35",
        bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1},
    )


def shade(ax, windows, t_ref: float, scale: float, color: str, label: str | None = None, alpha: float = 0.5) -> None:
    """Shade [t0, t1] windows (logger clock) on a time axis: one artist however many windows (an
    hour-long target log has hundreds of shots), one legend entry."""
    w = (np.asarray(windows, dtype=float).reshape(-1, 2) - t_ref) / scale
    if not len(w):
        return
    boxes = [[(a, 0.0), (a, 1.0), (b, 1.0), (b, 0.0)] for a, b in w]
    ax.add_collection(PolyCollection(boxes, transform=ax.get_xaxis_transform(), facecolors=color, alpha=alpha, lw=0, zorder=0, label=label))


def rug(ax, t_s, t_ref: float, scale: float, color: str, label: str | None = None) -> None:
    """Short ticks along the bottom of the axis at the given times (logger clock)."""
    t = (np.asarray(t_s, dtype=float) - t_ref) / scale
    if t.size == 0:
        return
    if t.size > MAX_POINTS:
        t = np.unique(np.round(t / (np.ptp(t) / MAX_POINTS + 1e-12))) * (np.ptp(t) / MAX_POINTS + 1e-12)
    ax.plot(t, np.zeros_like(t), "|", color=color, ms=7, mew=1.0, transform=ax.get_xaxis_transform(), label=label, clip_on=False)


def label_windows(ax, windows, names, t_ref: float, scale: float) -> None:
    """Names of shot windows written at the top of the axis, centred on each window; none when
    there are more than `MAX_WINDOW_LABELS` (names that overlap tell nothing)."""
    if len(names) > MAX_WINDOW_LABELS:
        return
    for (a, b), n in zip(np.asarray(windows, dtype=float).reshape(-1, 2), names):
        ax.text(
            ((a + b) / 2 - t_ref) / scale,
            1.01,
            str(n),
            transform=ax.get_xaxis_transform(),
            ha="center",
            va="bottom",
            fontsize=6.5,
            color="#08519c",
            clip_on=False,
        )


def legend_outside(ax, ncol: int = 6, raise_for_labels: bool = False) -> None:
    """Legend above the axis, outside the data area (never covers a line); raised above the window
    names `label_windows` writes along the top when `raise_for_labels`."""
    h, lab = ax.get_legend_handles_labels()
    if h:
        ax.legend(
            h,
            lab,
            fontsize=7,
            ncol=min(ncol, len(h)),
            loc="lower left",
            bbox_to_anchor=(0.0, 1.06 if raise_for_labels else 1.0),
            frameon=False,
            borderaxespad=0.2,
            handlelength=1.6,
            columnspacing=1.2,
        )


def decade_label(v: float, _pos=None) -> str:
    """A log-axis tick label in plain ASCII: a power of ten from 0.001 to 1000 as a number, beyond as
    1e-5 / 1e5; else the number. Plain text: matplotlib's default 10^k labels are mathtext, whose
    parser costs a report ~0.1 s to build for a handful of labels; ASCII draws in the PDF's standard
    font (`pdf.CORE_FONT_RC`)."""
    if not (np.isfinite(v) and v > 0):
        return ""
    k = np.log10(v)
    if abs(k - round(k)) < 1e-9 and abs(k) > 3:
        return f"1e{int(round(k))}"
    return f"{v:g}"


def log_labels(ax, which: str = "y") -> None:
    """Decade labels of `decade_label` on the log axes named in `which` ("x", "y" or "xy")."""
    from matplotlib.ticker import FuncFormatter

    for name in which:
        getattr(ax, f"{name}axis").set_major_formatter(FuncFormatter(decade_label))


def log_minor_grid(ax, which: str = "xy", lw: float = 0.3, color: str = "0.69") -> None:
    """Major grid plus the minor grid of log axes (2..9 x 10^k) drawn as one line collection, with
    no minor tick objects: matplotlib builds each tick (two marks, a label, a grid line) as its own
    artists, about 0.3 ms apiece, and a two-axis log-log page holds some 150 minor ticks.
    Call after the data are plotted (the limits must be final); the limits are then fixed."""
    from matplotlib.collections import LineCollection
    from matplotlib.ticker import NullLocator

    ax.grid(True, which="major", lw=lw)
    for name in which:
        lo, hi = sorted(getattr(ax, f"get_{name}lim")())
        if getattr(ax, f"get_{name}scale")() != "log" or not lo > 0:
            continue
        getattr(ax, f"set_{name}lim")(*getattr(ax, f"get_{name}lim")())  # freeze: the grid is drawn for these
        getattr(ax, f"{name}axis").set_minor_locator(NullLocator())
        k = np.arange(np.floor(np.log10(lo)), np.ceil(np.log10(hi)) + 1)
        v = (np.arange(2.0, 10.0)[None, :] * 10.0 ** k[:, None]).ravel()
        v = v[(v > lo) & (v < hi)]
        if name == "x":
            segs, trans = [[(x, 0.0), (x, 1.0)] for x in v], ax.get_xaxis_transform()
        else:
            segs, trans = [[(0.0, y), (1.0, y)] for y in v], ax.get_yaxis_transform()
        ax.add_collection(LineCollection(segs, transform=trans, colors=color, linewidths=lw, zorder=0.5), autolim=False)


def style_axis(ax, ylabel: str) -> None:
    ax.set_ylabel(ylabel, fontsize=8)
    if ax.get_yscale() == "log":
        from matplotlib.ticker import NullLocator

        ax.yaxis.set_minor_locator(NullLocator())  # decades are enough; minor ticks cost time and ink
    ax.tick_params(labelsize=7.5)
    ax.grid(True, lw=0.3, color="0.85")
    for s in ("top", "right"):
        ax.spines[s].set_visible(False)


# ------------------------------------------------------------------------------------ map furniture


def nice_length(max_len: float) -> float:
    """The largest 1-2-5 x 10^k not above max_len."""
    if not np.isfinite(max_len) or max_len <= 0:
        return 1.0
    e = 10.0 ** np.floor(np.log10(max_len))
    for f in (5.0, 2.0, 1.0):
        if f * e <= max_len:
            return f * e
    return e


def length_label(m: float) -> str:
    if m >= 1000.0:
        return f"{m / 1000.0:g} km"
    if m >= 1.0:
        return f"{m:g} m"
    if m >= 0.01:
        return f"{m * 100.0:g} cm"
    return f"{m * 1000.0:g} mm"


def scale_bar(ax, points=None, frac: float = 0.25) -> str:
    """A scale bar on an equal-aspect east/north axis in metres, in the corner (lower left, lower
    right, upper left, in that order of preference; the north arrow prefers the upper right) whose bar
    and label cover fewest of `points` ((N, 2) east, north), so it covers no data where it can.
    Returns the corner used ("lower left", "lower right" or "upper left")."""
    ax.apply_aspect()
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    w, h = x1 - x0, y1 - y0
    L = nice_length(frac * w)
    corners = [(x0 + 0.05 * w, y0 + 0.05 * h), (x1 - 0.05 * w - L, y0 + 0.05 * h), (x0 + 0.05 * w, y1 - 0.10 * h)]
    xs, ys = corners[0]
    if points is not None and len(points):
        p = np.asarray(points, dtype=float)

        def covered(c) -> int:  # points under the bar and its label, with a margin
            a, b = c
            inside_x = (p[:, 0] > a - 0.03 * w) & (p[:, 0] < a + L + 0.03 * w)
            return int(np.sum(inside_x & (p[:, 1] > b - 0.03 * h) & (p[:, 1] < b + 0.08 * h)))

        xs, ys = min(corners, key=covered)  # the first of equals
    where = ("lower left", "lower right", "upper left")[corners.index((xs, ys))]
    ax.plot([xs, xs + L], [ys, ys], color="k", lw=2.5, solid_capstyle="butt", zorder=5)
    ax.plot([xs, xs + L / 2], [ys, ys], color="w", lw=1.2, solid_capstyle="butt", zorder=6)
    ax.text(
        xs + L / 2,
        ys + 0.015 * (y1 - y0),
        length_label(L),
        ha="center",
        va="bottom",
        fontsize=7.5,
        zorder=6,
        bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none", "pad": 1},
    )
    return where


NORTH_ARROW_SPOTS = {"upper right": (0.94, 0.0), "upper left": (0.06, 0.0), "lower right": (0.94, -0.70), "lower left": (0.06, -0.70)}


def north_arrow(ax, points=None, taken: str | None = None) -> str:
    """A north arrow (the map's y axis is true north) in the corner that covers fewest of `points`
    ((N, 2) east, north in data units): the upper right unless data lie under it there, never the
    corner `taken` (the scale bar's, as `scale_bar` returns it). Returns the corner used."""
    spots = [k for k in NORTH_ARROW_SPOTS if k != taken]
    where = spots[0]
    if points is not None and len(points):
        p = np.asarray(points, dtype=float)
        x0, x1 = ax.get_xlim()
        y0, y1 = ax.get_ylim()
        fx, fy = (p[:, 0] - x0) / (x1 - x0), (p[:, 1] - y0) / (y1 - y0)

        def covered(k) -> int:  # points under the arrow and its "N", with a margin (axes fractions)
            x, dy = NORTH_ARROW_SPOTS[k]
            return int(np.sum((np.abs(fx - x) < 0.04) & (fy > 0.74 + dy) & (fy < 0.97 + dy)))

        where = min(spots, key=covered)  # the first of equals
    x, dy = NORTH_ARROW_SPOTS[where]
    ax.add_patch(
        FancyArrow(x, 0.83 + dy, 0.0, 0.09, width=0.012, head_width=0.035, head_length=0.035, transform=ax.transAxes, color="k", zorder=6)
    )
    ax.text(x, 0.80 + dy, "N", transform=ax.transAxes, ha="center", va="top", fontsize=9, weight="bold", zorder=6)
    return where
