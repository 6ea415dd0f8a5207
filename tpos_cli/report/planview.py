"""The plan view of page 1: where the platform went (or stood) and where the targets are.

East/north metres about a local origin (pymap3d), equal scale, with a scale bar and a north arrow.
A moving platform shows its best track (GPS-outage stretches in red, start and end marked) and any
anchors; a fixed observer shows its lines of sight instead of a one-point "trajectory". Targets and
sampled track epochs carry their 95 % ellipses; ellipses too small to see at the map's scale are
drawn enlarged by a stated 1-2-5 factor.
"""

from __future__ import annotations

import numpy as np
from matplotlib.patches import Ellipse

from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.report import layout as L
from tpos_cli.report.targets import horizontal_ellipse

MIN_ELLIPSE_FRAC = 0.012  # an ellipse under ~1.2 % of the map width (~2 mm on paper) is enlarged
MAX_ELLIPSE_FRAC = 0.05  # ... but none to a semi-axis over 5 % of it
N_TRACK_ELLIPSES = 12


def _enlargement(major_m: np.ndarray, extent_m: float) -> float:
    """The 1-2-5 factor that draws the median ellipse at least `MIN_ELLIPSE_FRAC` of the map wide,
    but no ellipse wider than `MAX_ELLIPSE_FRAC` of it: one GPS-outage epoch among a dozen has an
    ellipse tens of times the median, which the median's factor would draw across the whole map.
    Never below 1 (an ellipse is not drawn smaller than it is)."""
    m = major_m[np.isfinite(major_m)]
    if not m.size or extent_m <= 0:
        return 1.0
    need = MIN_ELLIPSE_FRAC * extent_m / max(float(np.median(m)), 1e-9)
    if need <= 1.0:
        return 1.0
    e = 10.0 ** np.ceil(np.log10(need))
    f_need = next((f * e for f in (0.2, 0.5, 1.0) if f * e >= need), e)
    cap = MAX_ELLIPSE_FRAC * extent_m / max(float(m.max()), 1e-9)
    if f_need <= cap:
        return f_need
    e = 10.0 ** np.floor(np.log10(cap)) if cap > 0 else 1.0
    return max(1.0, next((f * e for f in (5.0, 2.0, 1.0) if f * e <= cap), e))


def _draw_ellipses(ax, e_m, n_m, major, minor, az_deg, factor, color, label):
    for k, (x, y, a, b, z) in enumerate(zip(e_m, n_m, major, minor, az_deg)):
        if not np.all(np.isfinite([x, y, a, b, z])):
            continue
        # matplotlib's angle is counter-clockwise from +x (east); azimuth is clockwise from north
        ax.add_patch(
            Ellipse(
                (x, y),
                2 * a * factor,
                2 * b * factor,
                angle=90.0 - z,
                fill=False,
                color=color,
                lw=1.0,
                label=label if k == 0 else None,
                zorder=4,
            )
        )


def track_points(lla) -> np.ndarray:
    """Indices of the track epochs the plan draws: `layout.decimate` of latitude and of longitude
    together, so every bin's northern-, southern-, eastern- and western-most point is kept (the
    extent and the turns of the track) and the first and last epochs; at most ~2 x MAX_POINTS."""
    lla = np.asarray(lla, dtype=float)
    return np.union1d(np.union1d(L.decimate(lla[:, 0]), L.decimate(lla[:, 1])), [0, len(lla) - 1])


def plan_aspect(ctx) -> float:
    """North extent over east extent of what the plan will show (for sizing its box); 1 if unknown."""
    pts = []
    best = ctx.series.get(ctx.best) if ctx.best else None
    if best is not None and not best.is_static:
        p = best.lla[track_points(best.lla)]
        pts.append(p[np.isfinite(p).all(axis=1)])
    if ctx.targets is not None:
        pts.append(ctx.targets[["lat", "lon", "h"]].dropna().to_numpy(float))
        if best is not None and best.is_static:
            pts.append(best.lla[:1])
    if ctx.anchors is not None and ctx.session is not None and ctx.session.anchors is not None:
        pts.append(np.asarray(ctx.session.anchors.lla, dtype=float))
    p = np.vstack([x for x in pts if len(x)]) if any(len(x) for x in pts) else np.empty((0, 3))
    if len(p) < 2:
        return 1.0
    ned = lla_to_ned(p, p[0])
    span = np.ptp(ned[:, :2], axis=0)
    return float(np.clip((span[0] + 0.16 * span.max()) / max(span[1] + 0.16 * span.max(), 1e-9), 0.3, 3.0))


def plan_view(ax, ctx) -> str:
    """Draw the plan; returns a caption line (what is drawn, the ellipse enlargement)."""
    best = ctx.series.get(ctx.best) if ctx.best else None
    targets = ctx.targets
    static = best is None or best.is_static
    if best is not None and not static:
        origin = best.lla[np.isfinite(best.lla).all(axis=1)][0]
    elif targets is not None and np.isfinite(targets[["lat", "lon"]].to_numpy(float)).any():
        origin = (
            best.lla[np.isfinite(best.lla).all(axis=1)][0] if best is not None else targets[["lat", "lon", "h"]].dropna().to_numpy(float)[0]
        )
    else:
        ax.text(0.5, 0.5, "no position to draw", transform=ax.transAxes, ha="center")
        return ""
    pts = []
    caption = []
    if best is not None and not static:
        i = track_points(best.lla)
        ned = lla_to_ned(best.lla[i], origin)  # only the epochs drawn: every extreme of either axis
        ax.plot(ned[:, 1], ned[:, 0], color=L.COLORS[0], lw=1.2, label=f"track ({best.name})", zorder=3)
        if best.outage.any() or len(ctx.run.outage_windows):
            inside = best.outage.copy()
            for a, b in ctx.run.outage_windows:
                inside |= (best.t >= a) & (best.t < b)
            if inside.any():
                ax.plot(
                    np.where(inside[i], ned[:, 1], np.nan),
                    np.where(inside[i], ned[:, 0], np.nan),
                    color="#d62728",
                    lw=2.2,
                    label="in GPS outage / masked" if len(ctx.run.mask_windows) else "in GPS outage",
                    zorder=3,
                )
        ax.plot(ned[0, 1], ned[0, 0], "^", color="k", ms=7, label="start", zorder=5)
        ax.plot(ned[-1, 1], ned[-1, 0], "s", color="k", ms=6, mfc="white", label="end", zorder=5)
        pts.append(ned[:, :2])
        caption.append(f"track of the {best.name} solution")
    if ctx.anchors is not None and ctx.session is not None and ctx.session.anchors is not None:
        an = lla_to_ned(np.asarray(ctx.session.anchors.lla, dtype=float), origin)
        ax.plot(an[:, 1], an[:, 0], "s", color="#8c564b", ms=7, label="anchors", zorder=5)
        for (n, e, _), name in zip(an, ctx.session.anchors.ids):
            ax.annotate(str(name), (e, n), xytext=(4, 4), textcoords="offset points", fontsize=7.5, color="#8c564b")
        pts.append(an[:, :2])
    tgt_ned = None
    if targets is not None:
        ok = np.isfinite(targets[["lat", "lon", "h"]].to_numpy(float)).all(axis=1)
        tgt_ned = lla_to_ned(targets.loc[ok, ["lat", "lon", "h"]].to_numpy(float), origin)
        if static:
            for n, e, _ in tgt_ned:  # lines of sight from the observer at the origin
                ax.plot([0.0, e], [0.0, n], color="0.7", lw=0.7, zorder=1)
            ax.plot(0.0, 0.0, "^", color="k", ms=9, label="observer", zorder=5)
            pts.append(np.zeros((1, 2)))
        ax.plot(tgt_ned[:, 1], tgt_ned[:, 0], "o", color=L.COLORS[1], ms=4, label="targets", zorder=5)
        for (n, e, _), name in zip(tgt_ned, targets.loc[ok, "id"]):
            ax.annotate(str(name), (e, n), xytext=(5, 3), textcoords="offset points", fontsize=8, weight="bold", color=L.COLORS[1])
        pts.append(tgt_ned[:, :2])
    allp = np.vstack(pts)
    span = np.nanmax(allp, axis=0) - np.nanmin(allp, axis=0)
    extent = float(max(span.max(), 1.0))
    # ellipses: targets, else sampled epochs of a moving solution with position sigmas
    if tgt_ned is not None and len(tgt_ned):
        t_ok = targets[np.isfinite(targets[["lat", "lon", "h"]].to_numpy(float)).all(axis=1)]
        f = _enlargement(t_ok["ell95_major_m"].to_numpy(float), extent)
        _draw_ellipses(
            ax,
            tgt_ned[:, 1],
            tgt_ned[:, 0],
            t_ok["ell95_major_m"],
            t_ok["ell95_minor_m"],
            t_ok["ell95_azimuth_deg"],
            f,
            L.COLORS[1],
            "95 % ellipse" + (f" (x{f:g})" if f > 1 else ""),
        )
        caption.append("targets with their 95 % horizontal ellipses" + (f", drawn {f:g} times enlarged" if f > 1 else ""))
    elif best is not None and not static and best.has_position_sigma:
        k = np.unique(np.linspace(0, best.t.size - 1, N_TRACK_ELLIPSES).astype(int))
        cne = best.cov_ne_m2[k]
        cov = np.stack([np.column_stack([best.sigma_neu_m[k, 0] ** 2, cne]), np.column_stack([cne, best.sigma_neu_m[k, 1] ** 2])], axis=1)
        el = horizontal_ellipse(cov)
        f = _enlargement(el.semi_major_m, extent)
        ned = lla_to_ned(best.lla[k], origin)
        _draw_ellipses(
            ax,
            ned[:, 1],
            ned[:, 0],
            el.semi_major_m,
            el.semi_minor_m,
            el.azimuth_deg,
            f,
            "#08519c",
            "95 % ellipse" + (f" (x{f:g})" if f > 1 else ""),
        )
        caption.append(f"95 % ellipses at {k.size} epochs" + (f", drawn {f:g} times enlarged" if f > 1 else ""))
    lo, hi = np.nanmin(allp, axis=0), np.nanmax(allp, axis=0)
    pad = 0.08 * max(extent, 1.0)
    xs, ys = (lo[1] - pad, hi[1] + pad), (lo[0] - pad, hi[0] + pad)
    # widen the shorter side so that one metre is as long east as north in this box
    pos = ax.get_position()
    box = pos.width * ax.figure.get_figwidth() / (pos.height * ax.figure.get_figheight())
    w, h = xs[1] - xs[0], ys[1] - ys[0]
    if w / h < box:
        c = (xs[0] + xs[1]) / 2
        xs = (c - h * box / 2, c + h * box / 2)
    else:
        c = (ys[0] + ys[1]) / 2
        ys = (c - w / box / 2, c + w / box / 2)
    ax.set_xlim(*xs)
    ax.set_ylim(*ys)
    ax.set_aspect("equal", adjustable="box")
    unit, div = ("km", 1000.0) if extent > 5000 else ("m", 1.0)
    ax.xaxis.set_major_formatter(lambda v, _: f"{v / div:g}")
    ax.yaxis.set_major_formatter(lambda v, _: f"{v / div:g}")
    ax.set_xlabel(f"east, {unit}", fontsize=8)
    ax.set_ylabel(f"north, {unit}", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, lw=0.3, color="0.88")
    bar = L.scale_bar(ax, allp[:, ::-1])
    L.north_arrow(ax, allp[:, ::-1], taken=bar)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, borderaxespad=0.0)
    o = f"origin {origin[0]:.6f}, {origin[1]:.6f}"
    return "; ".join(caption) + f"; east/north about {o} (" + ("the observer" if static else "the start") + ")"
