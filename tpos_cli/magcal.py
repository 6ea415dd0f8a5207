"""Magnetometer hard/soft-iron calibration by ellipsoid fitting.

Model (in the LOGGED sensor axes, as `session.py` applies it): m_raw = A h + b + noise with |h| = F
(the local field magnitude), so the calibration is m_cal = S (m_raw - b), S = A⁻¹ chosen symmetric.
Fit: the algebraic least-squares quadric m^T M m + 2 p^T m + c = 0 (Li & Griffiths 2004, Eq. 7-11,
without their ellipsoid-specific constraint, which rotation sequences rarely need);
b = -M⁻¹ p; S = (M / (b^T M b - c))^{1/2} F (symmetric square root), so |S (m - b)| = F.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import ProcessingError


def apply_mag_calibration(mag_ut, hard_iron_ut, soft_iron):
    """m_cal = S (m_raw - b) per row: `mag_ut` (N, 3) µT, `hard_iron_ut` b (3,), `soft_iron` S (3, 3)."""
    m = np.asarray(mag_ut, float)
    return (m - np.asarray(hard_iron_ut, float)) @ np.asarray(soft_iron, float).T


@dataclass(frozen=True)
class MagCalibration:
    hard_iron_ut: np.ndarray  # (3,)
    soft_iron: np.ndarray  # (3, 3) symmetric
    field_ut: float  # F the calibrated magnitude is scaled to
    residual_sd_ut: float  # SD of |m_cal| - F over the fitted samples
    raw_norm_sd_ut: float  # SD of |m_raw| (for comparison)
    coverage: float  # smallest / largest eigenvalue of the spread of calibrated directions (0 = planar, 1 = sphere)

    def toml_keys(self) -> dict:
        return {"hard_iron_ut": [round(float(x), 4) for x in self.hard_iron_ut],
                "soft_iron": [[round(float(x), 6) for x in row] for row in self.soft_iron]}


def fit_ellipsoid(mag_ut, field_ut: float | None = None) -> MagCalibration:
    """Hard/soft iron from samples (N, 3) µT spread over many orientations.

    `field_ut`: the local field magnitude (IGRF); default the mean radius of the fitted ellipsoid.
    Raises ProcessingError when the samples do not determine an ellipsoid (too few orientations).
    """
    m = np.asarray(mag_ut, float)
    m = m[np.isfinite(m).all(axis=1)]
    if m.shape[0] < 50:
        raise ProcessingError(f"calibrate-mag: {m.shape[0]} magnetometer samples; at least 50 over many orientations are needed")
    scale = np.abs(m).max()
    x, y, z = (m / scale).T
    # quadric a x² + b y² + c z² + 2f yz + 2g xz + 2h xy + 2p x + 2q y + 2r z = 1
    D = np.column_stack([x * x, y * y, z * z, 2 * y * z, 2 * x * z, 2 * x * y, 2 * x, 2 * y, 2 * z])
    coef, *_ = np.linalg.lstsq(D, np.ones_like(x), rcond=None)
    a, b_, c, f, g, h, p, q, r = coef
    M = np.array([[a, h, g], [h, b_, f], [g, f, c]])
    w, V = np.linalg.eigh(M)
    if not (w > 0).all():
        raise ProcessingError("calibrate-mag: the samples do not outline an ellipsoid (rotate the device through many orientations)")
    center = -np.linalg.solve(M, np.array([p, q, r]))
    k = 1.0 + center @ M @ center  # (m-b)^T M (m-b) = k
    lo, hi = m.min(axis=0) / scale, m.max(axis=0) / scale
    if not (k > 0 and np.all((center >= lo) & (center <= hi))):
        # samples that turn through enough orientations surround the ellipsoid's centre: a centre
        # outside their range on an axis is a quadric fitted to an arc or a line (a degenerate fit)
        raise ProcessingError("calibrate-mag: the samples do not surround the fitted centre (hard iron): they cover too "
                              "few orientations to outline an ellipsoid (rotate the device through many orientations)")
    S_unit = V @ np.diag(np.sqrt(w / k)) @ V.T  # |S_unit (m - b)| = 1 (scaled units)
    b_ut = center * scale
    S_unit = S_unit / scale
    radius = float(np.mean(np.linalg.norm((m - b_ut) @ S_unit.T, axis=1)))
    F = float(field_ut) if field_ut is not None else float(np.cbrt(1.0 / np.prod(np.linalg.eigvalsh(S_unit))))
    S = S_unit * F / radius
    cal = apply_mag_calibration(m, b_ut, S)
    nrm = np.linalg.norm(cal, axis=1)
    u = cal / nrm[:, None]
    ev = np.linalg.eigvalsh(u.T @ u / u.shape[0])
    return MagCalibration(b_ut, S, F, float(np.std(nrm - F)), float(np.std(np.linalg.norm(m, axis=1))), float(ev[0] / ev[-1]))


def field_profile(t_s, mag_ut, parts: int = 3) -> str:
    """The field magnitude |m| (5-95 % range, µT) over `parts` equal stretches of the samples (t_s on
    the logger clock): one field, whatever the device's attitude and its own iron, keeps the same
    range in each; a magnet attached for part of a log does not."""
    t = np.asarray(t_s, float)
    nrm = np.linalg.norm(np.asarray(mag_ut, float), axis=1)
    ok = np.isfinite(nrm) & np.isfinite(t)
    t, nrm = t[ok], nrm[ok]
    if t.size < parts:
        return "too few samples"
    edges = np.linspace(t[0], t[-1], parts + 1)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (t >= a) & (t <= b)
        lo, hi = np.percentile(nrm[sel], [5, 95])
        out.append(f"{a:.0f}-{b:.0f} s {lo:.0f}-{hi:.0f} µT")
    return ", ".join(out)


def calibrate_session(session_dir, window=None):
    """(MagCalibration, note) from a session's magnetometer, in its logged axes, undoing any calibration it has."""
    from tpos_cli.errors import InvalidInputError
    from tpos_cli.frames.rotation import axes_to_dcm
    from tpos_cli.session import load_session

    s = load_session(session_dir)
    if s.imu.mag_b_ut is None:
        raise InvalidInputError(f"{session_dir}: the session has no magnetometer columns")
    t = s.imu.t_s + s.t0_s
    sel = np.ones(t.size, bool) if window is None else (t >= window[0]) & (t <= window[1])
    if not sel.any():  # a window off the log is a usage mistake, not a failed fit
        raise InvalidInputError(f"--window {window[0]:g}:{window[1]:g}: no magnetometer samples in that window "
                                f"(log spans {t[0]:.2f}-{t[-1]:.2f})")
    m_s = s.imu.mag_b_ut[sel] @ axes_to_dcm(s.meta.axes)  # FRD -> logged axes (C_bs^T per row)
    if s.meta.hard_iron_ut is not None or s.meta.soft_iron is not None:  # back to raw: m = S⁻¹ m_cal + b
        hi = s.meta.hard_iron_ut if s.meta.hard_iron_ut is not None else np.zeros(3)
        si = s.meta.soft_iron if s.meta.soft_iron is not None else np.eye(3)
        m_s = np.linalg.solve(si, m_s.T).T + hi
    field, src = None, "the fitted mean radius"
    pos = s.meta.observer_lla
    if s.gps is not None and s.gps.valid.any():
        pos = s.gps.lla[s.gps.valid][0]
    if pos is not None:
        from datetime import datetime

        from tpos_cli.magnetic import field_ned_ut

        field = float(np.linalg.norm(field_ned_ut(pos, s.meta.start_utc or datetime(2020, 1, 1))))
        src = "the IGRF field at the session position"
    try:
        cal = fit_ellipsoid(m_s, field)
    except ProcessingError as exc:
        raise ProcessingError(
            f"{exc}; the field's magnitude along the {'window' if window is not None else 'log'} (5-95 %): "
            f"{field_profile(t[sel], m_s)}: if it changes from one stretch to the next, the samples hold more than one "
            "field (a magnet attached for part of the log?): calibrate one stretch where the device turns in one "
            "field, with --window T0:T1") from None
    note = (f"{int(sel.sum())} samples; |m| SD {cal.raw_norm_sd_ut:.2f} µT raw -> {cal.residual_sd_ut:.2f} µT calibrated; "
            f"scaled to {cal.field_ut:.1f} µT ({src}); orientation coverage {cal.coverage:.2f} (1 = all directions)")
    if cal.coverage < 0.1:
        note += "; WARNING: the rotations cover too few directions for a trustworthy soft-iron matrix"
    return cal, note


def write_calibrated_copy(session_dir, out_dir, cal: MagCalibration, *, force: bool = False) -> None:
    """Copy the session to `out_dir` with `[magnetic] hard_iron_ut`, `soft_iron` set (input untouched).
    The new session.toml is built (and checked) before anything is copied, keeping the file as
    written (quoted keys, datetimes, comments): a session it cannot rewrite leaves no output."""
    import shutil
    from pathlib import Path

    from tpos_cli.errors import InvalidInputError
    from tpos_cli.importers.session_out import session_toml_text
    from tpos_cli.io.run_dir import check_session_out

    src, dst = Path(session_dir).resolve(), Path(out_dir).resolve()
    if src == dst:
        raise InvalidInputError(f"{out_dir}: -o must name a new directory, not the input session")
    # absent or empty; with `force` an existing session only, holding neither the input session nor the
    # current directory (the guard of `tpos calibrate-mag --force`, for library callers too)
    check_session_out(Path(out_dir), force=force, src=src)
    text = session_toml_text(src / "session.toml", {"magnetic": cal.toml_keys()}, dst.name)
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    (dst / "session.toml").write_text(text, encoding="utf-8")
