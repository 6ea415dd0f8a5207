"""Figures shared outside the report's sections: the Allan deviation plot (also `tpos noise --plot`)."""

from __future__ import annotations

import textwrap

import numpy as np
from matplotlib.figure import Figure

from tpos_cli.frames.earth import G0_MPS2
from tpos_cli.report import layout as L
from tpos_cli.report.layout import COLORS, log_labels, new_page


def draw_allan(fig: Figure, nf, top: float, bottom: float) -> None:
    """Log-log Allan deviation of the gyro and accelerometer axes (`tpos_cli.noise.NoiseFigures`) in
    the band [bottom, top] of `fig`, with the read-offs that become the session.toml `[imu]` keys."""
    specs = (
        (nf.gyro, lambda a: np.degrees(a) * 3600.0, "gyro Allan deviation, deg/h"),
        (nf.acc, lambda a: a / G0_MPS2 * 1e3, "accelerometer Allan deviation, mg"),
    )
    h = (top - bottom - 0.19) / 2  # two axes; room for their tick and axis labels and the keys line
    for k, (axes3, conv, label) in enumerate(specs):
        ax = fig.add_axes([0.12, top - (k + 1) * h - k * 0.075, 0.72, h])
        for i, a in enumerate(axes3):
            ax.loglog(a.tau_s, conv(a.adev), color=COLORS[i], label="xyz"[i])
        log_labels(ax, "xy")
        ax.set_xlabel("averaging time, s", fontsize=8)
        ax.set_ylabel(label, fontsize=8)
        ax.tick_params(labelsize=7.5)
        L.log_minor_grid(ax, "xy")
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    keys = nf.toml_keys()
    fig.text(
        0.12,
        bottom + 0.035,
        "\n".join(textwrap.wrap("[imu] " + ", ".join(f"{k} = {v:g}" for k, v in keys.items()), 110)),
        fontsize=7.5,
        va="top",
    )


def allan_page(nf, window_note: str = "") -> Figure:
    """The Allan deviation plot on its own A4 page."""
    fig = new_page(
        "IMU noise: Allan deviation",
        "overlapping Allan deviation per axis (IEEE Std 952-1997 Annex C)" + (f"; {window_note}" if window_note else ""),
    )
    draw_allan(fig, nf, 0.9, 0.05)
    return fig
