"""Matplotlib figure builders for the report (A4 portrait pages, no file I/O, Agg backend).

Every builder returns `matplotlib.figure.Figure` objects sized for A4 so that the PDF prints at
100 %; fonts are 8-11 pt, every axis names its quantity and unit. Lines are decimated to at most
`MAX_POINTS` vertices (vector output stays small) keeping each bin's extreme, so peaks survive.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse
from scipy import stats

from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.report.metrics import ellipse_scale

A4_IN = (8.27, 11.69)
MAX_POINTS = 4000
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")
OUTAGE_COLOR = "#f4a6a6"


def new_page(title: str, subtitle: str = "") -> Figure:
    fig = Figure(figsize=A4_IN)
    fig.text(0.5, 0.975, title, ha="center", va="top", fontsize=13, weight="bold")
    if subtitle:
        fig.text(0.5, 0.952, "\n".join(textwrap.wrap(subtitle, 110)), ha="center", va="top", fontsize=8.5, color="0.3")
    return fig


def decimate(t, y, max_points: int = MAX_POINTS):
    """Indices keeping at most ~max_points samples: per bin the min and max of |y| (peaks survive)."""
    n = len(t)
    if n <= max_points:
        return np.arange(n)
    bins = np.linspace(0, n, max_points // 2 + 1).astype(int)
    y = np.asarray(y, dtype=float)
    keep = []
    for a, b in zip(bins[:-1], bins[1:]):
        seg = y[a:b]
        if seg.size == 0:
            continue
        if np.all(np.isnan(seg)):
            keep.append(a)
            continue
        keep += [a + int(np.nanargmin(seg)), a + int(np.nanargmax(seg))]
    return np.unique(keep)


def shade_outages(ax, windows, t_ref: float, label: bool = True) -> None:
    for k, (a, b) in enumerate(np.asarray(windows, dtype=float).reshape(-1, 2)):
        ax.axvspan(a - t_ref, b - t_ref, color=OUTAGE_COLOR, alpha=0.45, lw=0, label="GPS outage" if (label and k == 0) else None)


def time_label(t_ref: float) -> str:
    return f"time since t = {t_ref:.2f} s (logger clock), s"


def _plot_series(ax, t, y, t_ref, **kw):
    i = np.union1d(decimate(t, y), np.flatnonzero(np.isnan(np.asarray(y, dtype=float))))  # keep line breaks
    ax.plot(np.asarray(t)[i] - t_ref, np.asarray(y)[i], lw=0.9, **kw)


def _break_wraps(yaw_deg):
    """NaN at the sample after a 360 -> 0 wrap, so the line is broken instead of drawn across."""
    y = np.array(yaw_deg, dtype=float)
    jump = np.zeros(y.size, dtype=bool)
    jump[1:] = np.abs(np.diff(y)) > 180.0
    y[jump] = np.nan
    return y


def text_page(title: str, lines: list[tuple[str, str]], subtitle: str = "") -> Figure:
    """Key/value lines (a cover); long values wrap."""
    fig = new_page(title, subtitle)
    y = 0.90
    for key, value in lines:
        wrapped = textwrap.wrap(str(value), 82) or [""]
        fig.text(0.08, y, key, fontsize=9.5, weight="bold", va="top")
        for w in wrapped:
            fig.text(0.33, y, w, fontsize=9, va="top", family="monospace" if key.startswith("  ") else None)
            y -= 0.018
        y -= 0.006
        if y < 0.05:
            break
    return fig


def table_pages(title: str, df: pd.DataFrame, notes: str = "", rows_per_page: int = 38, col_width=None, fontsize: float = 8.0) -> list[Figure]:
    """A DataFrame as one or more table pages (strings as given, floats to 4 significant digits)."""
    pages = []
    cells = df.copy()
    for c in cells.columns:
        if pd.api.types.is_float_dtype(cells[c]):
            cells[c] = [("" if not np.isfinite(v) else f"{v:.4g}") for v in cells[c]]
        else:
            cells[c] = cells[c].astype(str)
    chunks = [cells.iloc[i : i + rows_per_page] for i in range(0, max(len(cells), 1), rows_per_page)]
    for k, chunk in enumerate(chunks):
        fig = new_page(title + (f" ({k + 1}/{len(chunks)})" if len(chunks) > 1 else ""))
        ax = fig.add_axes([0.04, 0.08, 0.92, 0.84])
        ax.axis("off")
        if len(chunk):
            tb = ax.table(cellText=chunk.to_numpy(), colLabels=list(chunk.columns), loc="upper center", cellLoc="center", colWidths=col_width)
            tb.auto_set_font_size(False)
            tb.set_fontsize(fontsize)
            tb.scale(1.0, 1.35)
            for (r, _c), cell in tb.get_celld().items():
                if r == 0:
                    cell.set_facecolor("#e8e8e8")
                    cell.set_text_props(weight="bold")
        else:
            ax.text(0.5, 0.9, "(no rows)", ha="center", fontsize=10)
        if notes:
            fig.text(0.06, 0.05, "\n".join(textwrap.wrap(notes, 120)), fontsize=7.5, va="bottom", color="0.25")
        pages.append(fig)
    return pages


def trajectory_maps(solutions, truth_traj, windows, origin_lla, per_page: int = 2) -> list[Figure]:
    """One map per solution (east/north about `origin_lla`), truth in grey, GPS-outage stretches in red."""
    pages = []
    for start in range(0, len(solutions), per_page):
        fig = new_page("Trajectory per solution", "grey: truth; thick red: epochs inside GPS outages / withheld windows")
        chunk = solutions[start : start + per_page]
        for k, se in enumerate(chunk):
            ax = fig.add_axes([0.12, 0.53 - 0.46 * k, 0.8, 0.37])
            if truth_traj is not None:
                ok = np.all(np.isfinite(truth_traj.lla), axis=1)
                tn = lla_to_ned(truth_traj.lla[ok], origin_lla)
                ax.plot(tn[:, 1], tn[:, 0], color="0.6", lw=2.2, label=f"truth ({truth_traj.source})")
            n = lla_to_ned(se.lla, origin_lla)
            i = decimate(se.t, n[:, 0])
            ax.plot(n[i, 1], n[i, 0], color=COLORS[0], lw=0.9, label=se.solution)
            if se.in_outage.any():
                e = np.where(se.in_outage, n[:, 1], np.nan)
                ax.plot(e, np.where(se.in_outage, n[:, 0], np.nan), color="#d62728", lw=2.0, label="in GPS outage")
            ax.plot(n[0, 1], n[0, 0], "k^", ms=6, label="start")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_xlabel("east of origin, m")
            ax.set_ylabel("north of origin, m")
            ax.set_title(f"solution: {se.solution}", fontsize=10)
            ax.grid(True, lw=0.3)
            ax.legend(fontsize=7.5, loc="best")
        pages.append(fig)
    return pages


def position_error_page(solutions, windows, t_ref: float) -> Figure:
    fig = new_page("Position error vs time", "solution minus truth; shaded: GPS outages / withheld windows")
    specs = (("horizontal error, m", lambda e: np.hypot(e[:, 0], e[:, 1])), ("vertical error (up), m", lambda e: -e[:, 2]), ("3-D error, m", lambda e: np.linalg.norm(e, axis=1)))
    axes = [fig.add_axes([0.11, 0.68 - 0.3 * k, 0.83, 0.24]) for k in range(3)]
    for ax, (label, f) in zip(axes, specs):
        shade_outages(ax, windows, t_ref, label=ax is axes[0])
        for c, se in enumerate(solutions):
            _plot_series(ax, se.t, f(se.err_ned_m), t_ref, color=COLORS[c % len(COLORS)], label=se.solution)
        ax.set_ylabel(label)
        ax.grid(True, lw=0.3)
    axes[0].legend(fontsize=7.5, ncol=4, loc="upper left")
    axes[-1].set_xlabel(time_label(t_ref))
    return fig


def attitude_pages(solutions, t_ref: float, truth_traj) -> list[Figure]:
    """Roll, pitch, yaw vs time per solution, truth dashed when it has attitude."""
    pages = []
    names = ("roll, deg", "pitch, deg", "yaw (from true north), deg")
    for se in solutions:
        fig = new_page(f"Attitude vs time: {se.solution}", "black dashed: truth" if se.truth_rpy_deg is not None else "no attitude truth")
        for k in range(3):
            ax = fig.add_axes([0.11, 0.68 - 0.3 * k, 0.83, 0.24])
            y = se.rpy_deg[:, k]
            y = _break_wraps(np.mod(y, 360.0) if k == 2 else y)
            _plot_series(ax, se.t, y, t_ref, color=COLORS[0], label=se.solution, marker="." if se.t.size < 200 else None, ms=2)
            if se.truth_rpy_deg is not None:
                yt = _break_wraps(se.truth_rpy_deg[:, k] if k < 2 else np.mod(se.truth_rpy_deg[:, 2], 360.0))
                _plot_series(ax, se.t, yt, t_ref, color="k", ls="--", label="truth")
            if k == 2:
                ax.set_ylim(-5, 365)
                ax.set_yticks([0, 90, 180, 270, 360])
            ax.set_ylabel(names[k])
            ax.grid(True, lw=0.3)
            if k == 0:
                ax.legend(fontsize=7.5, loc="upper right")
        fig.axes[-1].set_xlabel(time_label(t_ref))
        pages.append(fig)
    return pages


def attitude_error_page(solutions, t_ref: float, movement_note: str = "") -> Figure:
    fig = new_page("Attitude error vs time", "solution minus truth, wrap-aware; near pitch ±90 deg the Euler errors are ill-defined, the total angle is not" + movement_note)
    names = (("roll_deg", "roll error, deg"), ("pitch_deg", "pitch error, deg"), ("yaw_deg", "yaw error, deg"), ("att_deg", "total angle error, deg"))
    for k, (key, label) in enumerate(names):
        ax = fig.add_axes([0.11, 0.74 - 0.225 * k, 0.83, 0.18])
        for c, se in enumerate(solutions):
            if se.att_err_deg is None:
                continue
            _plot_series(ax, se.t, se.att_err_deg[key], t_ref, color=COLORS[c % len(COLORS)], label=se.solution)
            if se.movement is not None and k == 0 and c == 0:
                m = se.movement.astype(float)
                ax.fill_between(se.t - t_ref, 0, 1, where=m > 0.5, color="#cfe8cf", alpha=0.5, transform=ax.get_xaxis_transform(), label="movement phase")
        ax.set_ylabel(label)
        ax.grid(True, lw=0.3)
        if k == 0:
            ax.legend(fontsize=7.5, ncol=4, loc="upper left")
    fig.axes[-1].set_xlabel(time_label(t_ref))
    return fig


def nis_pages(innovations: pd.DataFrame, t_ref: float, windows, per_page: int = 3) -> list[Figure]:
    """NIS per (solution, kind) vs time with the per-update chi-square 2.5-97.5 % band."""
    pages = []
    keys = list(dict.fromkeys(zip(innovations["solution"].astype(str), innovations["kind"].astype(str))))
    for start in range(0, len(keys), per_page):
        fig = new_page("Innovation consistency (NIS)", "NIS = v' S^-1 v per update; band: chi-square(dof) 2.5-97.5 %; red x: rejected")
        for k, (sol, kind) in enumerate(keys[start : start + per_page]):
            d = innovations[(innovations["solution"].astype(str) == sol) & (innovations["kind"].astype(str) == kind)]
            ax = fig.add_axes([0.11, 0.66 - 0.29 * k, 0.83, 0.23])
            t = d["t"].to_numpy(float) - t_ref
            nis = d["nis"].to_numpy(float)
            dof = d["dof"].to_numpy(float)
            acc = d["accepted"].fillna(False).to_numpy(bool)
            shade_outages(ax, windows, t_ref, label=False)
            i = decimate(t, nis)
            ax.plot(t[i][acc[i]], nis[i][acc[i]], ".", ms=2.5, color=COLORS[0], label="accepted")
            if (~acc).any():
                ax.plot(t[~acc], nis[~acc], "x", ms=4, color="#d62728", label="rejected")
            order = np.argsort(t)
            ax.plot(t[order], stats.chi2.ppf(0.975, dof[order]), color="k", lw=0.8, label="chi2 97.5 %")
            ax.plot(t[order], stats.chi2.ppf(0.025, dof[order]), color="k", lw=0.8, ls=":", label="chi2 2.5 %")
            ax.set_yscale("log")
            ax.set_ylabel("NIS (dimensionless)")
            ax.set_title(f"{sol}: {kind} (dof {np.nanmedian(dof) if np.isfinite(dof).any() else float('nan'):.0f}, {int((~acc).sum())} rejected of {len(acc)})", fontsize=9.5)
            ax.grid(True, lw=0.3, which="both")
            ax.legend(fontsize=7, ncol=4, loc="upper right")
            ax.set_xlabel(time_label(t_ref))
        pages.append(fig)
    return pages


def target_scatter_page(te: pd.DataFrame) -> Figure:
    """Horizontal target errors (east, north) per solution with 95 % ellipses from the reported SDs."""
    fig = new_page("Target horizontal errors against surveyed truth", "one point per shot; ellipses: 95 % from sigma_n, sigma_e; truth at the origin")
    ax = fig.add_axes([0.14, 0.3, 0.76, 0.58])
    k95 = ellipse_scale(0.95, 2)
    ext = 0.0
    for c, sol in enumerate(dict.fromkeys(te["solution"])):
        d = te[te["solution"] == sol]
        col = COLORS[c % len(COLORS)]
        ax.plot(d["err_e_m"], d["err_n_m"], "o", ms=5, color=col, label=sol)
        for _, r in d.iterrows():
            if np.isfinite(r["sigma_n_m"]) and np.isfinite(r["sigma_e_m"]):
                ax.add_patch(Ellipse((r["err_e_m"], r["err_n_m"]), 2 * k95 * r["sigma_e_m"], 2 * k95 * r["sigma_n_m"], fill=False, color=col, lw=0.8))
                ext = max(ext, abs(r["err_e_m"]) + k95 * r["sigma_e_m"], abs(r["err_n_m"]) + k95 * r["sigma_n_m"])
        ext = max(ext, float(np.nanmax(np.abs(d[["err_e_m", "err_n_m"]].to_numpy(float)))) if len(d) else 0.0)
    ax.plot(0, 0, "k+", ms=14, mew=1.5, label="surveyed truth")
    ext = 1.15 * ext if ext > 0 else 1.0
    ax.set_xlim(-ext, ext)
    ax.set_ylim(-ext, ext)
    ax.set_aspect("equal")
    ax.set_xlabel("east error, m")
    ax.set_ylabel("north error, m")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=8, loc="upper right")
    return fig


def allan_page(nf, window_note: str = "") -> Figure:
    """Log-log Allan deviation of the gyro and accelerometer axes (`tpos_cli.noise.NoiseFigures`),
    with the read-offs that become the session.toml `[imu]` noise keys."""

    fig = new_page("IMU noise: Allan deviation", "overlapping Allan deviation per axis (IEEE Std 952-1997 Annex C)" + (f"; {window_note}" if window_note else ""))
    specs = ((nf.gyro, lambda a: np.degrees(a) * 3600.0, "gyro Allan deviation, deg/h"), (nf.acc, lambda a: a / G0_MPS2 * 1e3, "accelerometer Allan deviation, mg"))
    for k, (axes3, conv, label) in enumerate(specs):
        ax = fig.add_axes([0.12, 0.56 - 0.4 * k, 0.8, 0.33])
        for i, a in enumerate(axes3):
            ax.loglog(a.tau_s, conv(a.adev), color=COLORS[i], label="xyz"[i])
        ax.set_xlabel("averaging time τ, s")
        ax.set_ylabel(label)
        ax.grid(True, which="both", lw=0.3)
        ax.legend(fontsize=8)
    keys = nf.toml_keys()
    fig.text(0.12, 0.07, "\n".join(textwrap.wrap("[imu] " + ", ".join(f"{k} = {v:g}" for k, v in keys.items()), 110)), fontsize=7.5, va="top")
    return fig
