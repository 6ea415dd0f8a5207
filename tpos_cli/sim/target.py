"""Scenario `target` (paper 000): a static observer aims a three-rangefinder MARG device at
targets on a flat vertical wall.

The device (IMU and LR1 origin) stands on a tripod at the observer position, zero roll, and is
held still for `static_s` (coarse alignment), then slews (septic smoothstep in yaw and pitch, peak
rate <= 30 deg/s) to the reference point and to each target in turn, holding LR1 on each for
`hold_s`; the holds are the `shots` windows. `motion="sine"` reproduces paper 000 section 6.1
instead: pitch = 54 deg sin(2 pi t/100 s) and yaw = wall azimuth + 54 deg sin(2 pi t/100 s).

Ranges are exact ray-plane intersections of three parallel beams along body forward from their
origins (contract: LR2 `baseline_12_m` to the LEFT of LR1, LR3 `baseline_13_m` BELOW LR1) with the
wall plane n.p = D in the observer's NED frame; no return (NaN) when a beam misses or exceeds
`max_range_m`. Magnetometer: a constant Earth field (total intensity, inclination, declination)
resolved in body axes, plus noise, plus an optional disturbance window (paper 000 section 6.2.2:
0.5 G = 50 uT with 1e-2 G = 1 uT noise, from a start time to the end).

Gyro scale and misalignment: every gyro measures omega_meas = (I + dM) omega + bias + noise with a
constant 3x3 dM per session (scale-factor errors on the diagonal, axis misalignment off it), each
element drawn N(0, sd^2) from its own random stream (the other draws of a seed are unchanged), sd per
grade (`GYRO_SCALE_PPM`): `mems` 1000 ppm (0.1 %: a consumer MEMS gyro after a one-time calibration;
data sheets give 0.4-1.5 % sensitivity tolerance and 0.5-2 % cross-axis sensitivity untrimmed),
`tactical` 100 ppm, `paper` and `perfect` 0 (paper 000 simulates a gyro with the stated bias and noise
only, and its goals are stated for that gyro). The attitude filters carry the `mems` figure as a
consider error for every log (`[target_fkf] gyro_scale_const_ppm`), since a log cannot state it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.geodetic import ned_to_lla
from tpos_cli.sim.kinematics import MotionSample, simulate_truth_imu
from tpos_cli.sim.profiles import SMOOTHSTEP_PEAK_RATE as PEAK
from tpos_cli.sim.profiles import ConstantProfile, RampProfile, SineProfile
from tpos_cli.sim.result import (
    SimImu,
    SimRanges,
    SimResult,
    SimShots,
    SimTargets,
    SimTruth,
)
from tpos_cli.sim.sensor_errors import corrupt_imu, imu_grade

DEFAULT_OBSERVER_LLA = (45.4946, -73.5622, 40.0)  # ETS Montreal (paper 000's experiments)
# Main field near Montreal (IGRF/WMM order of magnitude, 2015): total intensity, inclination, declination.
DEFAULT_FIELD = (53.5, 70.0, -14.6)  # uT, deg, deg (east positive)
#: Targets on the wall: (id, along-wall offset m (positive to the right facing the wall), height m
#: above the device, role).
DEFAULT_TARGETS = (
    ("REF", -3.0, 1.0, "reference"),
    ("T1", 4.0, 2.5, "truth"),
    ("T2", -6.0, 5.0, "truth"),
    ("T3", 1.0, 7.0, "truth"),
    ("T4", 7.5, 0.5, "truth"),
)
MAX_SLEW_RATE_RPS = np.radians(30.0)
#: SD (ppm) of each element of the gyro's constant scale/misalignment matrix dM per grade (module docstring).
GYRO_SCALE_PPM = {"paper": 0.0, "mems": 1000.0, "tactical": 100.0, "perfect": 0.0}


@dataclass(frozen=True)
class AimMotion:
    """Static device; attitude from yaw and pitch profiles, roll constant (default 0) or swaying."""

    yaw: RampProfile | SineProfile
    pitch: RampProfile | SineProfile
    roll: ConstantProfile | SineProfile = ConstantProfile(0.0)

    def __call__(self, t) -> MotionSample:
        y, y1, _ = self.yaw.eval(t)
        p, p1, _ = self.pitch.eval(t)
        r, r1, _ = self.roll.eval(t)
        z = np.zeros(np.shape(t) + (3,))
        return MotionSample(z, z.copy(), np.stack([r, p, y], axis=-1), np.stack([r1, p1, y1], axis=-1))


def wall_points_ned(wall_distance_m, wall_azimuth_rad, offsets_m, heights_m) -> np.ndarray:
    """NED (m, from the device) of wall points given along-wall offsets and heights."""
    n = np.array([np.cos(wall_azimuth_rad), np.sin(wall_azimuth_rad), 0.0])  # towards the wall
    right = np.array([-np.sin(wall_azimuth_rad), np.cos(wall_azimuth_rad), 0.0])  # along it, to the right
    off = np.asarray(offsets_m, dtype=float)[:, None]
    hgt = np.asarray(heights_m, dtype=float)[:, None]
    return wall_distance_m * n + off * right - hgt * np.array([0.0, 0.0, 1.0])


def beam_ranges(C_nb, wall_distance_m, wall_azimuth_rad, baseline_12_m, baseline_13_m, max_range_m=np.inf):
    """Exact (K, 3) ranges d1, d2, d3 from the device at the NED origin to the wall n.p = D.

    d_i = (D - n.o_i) / (n.u) with u = C_nb e_x the common beam direction and o_i the beam origins
    (LR1 at the origin, LR2 at -baseline_12 along body right, LR3 at +baseline_13 along body down).
    """
    n = np.array([np.cos(wall_azimuth_rad), np.sin(wall_azimuth_rad), 0.0])
    u = C_nb[..., :, 0]
    origins_b = np.array([[0.0, 0.0, 0.0], [0.0, -baseline_12_m, 0.0], [0.0, 0.0, baseline_13_m]])
    o = np.einsum("kij,lj->kli", C_nb, origins_b)  # (K, 3 beams, 3)
    nu = u @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        d = (wall_distance_m - o @ n) / nu[:, None]
    d[(nu[:, None] <= 0.0) | ~(d > 0.0) | (d > max_range_m)] = np.nan
    return d


def _aim_schedule(points_ned, ids, duration_s, static_s, hold_s, yaw0, pitch0):
    yaw_r, pitch_r, shots = [], [], []
    t, y, p = static_s, yaw0, pitch0
    k = 0
    while True:
        q = points_ned[k % len(ids)]
        ny = np.arctan2(q[1], q[0])
        npitch = np.arctan2(-q[2], np.hypot(q[0], q[1]))
        dy = (ny - y + np.pi) % (2 * np.pi) - np.pi
        dp = npitch - p
        T = max(2.0, PEAK * max(abs(dy), abs(dp)) / MAX_SLEW_RATE_RPS)
        if t + T + hold_s > duration_s:
            break
        yaw_r.append((t, T, dy))
        pitch_r.append((t, T, dp))
        shots.append((ids[k % len(ids)], t + T, t + T + hold_s))
        t, y, p = t + T + hold_s, y + dy, npitch
        k += 1
    return RampProfile.from_ramps(yaw0, yaw_r), RampProfile.from_ramps(pitch0, pitch_r), shots


def simulate_target(
    duration_s: float = 90.0,
    *,
    seed: int = 0,
    grade: str = "paper",
    noise_free: bool = False,
    rate_hz: float = 100.0,
    motion: str = "shots",
    static_s: float = 10.0,
    hold_s: float = 8.0,
    observer_lla=DEFAULT_OBSERVER_LLA,
    wall_distance_m: float = 12.0,
    wall_azimuth_deg: float = 30.0,
    targets=DEFAULT_TARGETS,
    baseline_12_m: float = 0.20,
    baseline_13_m: float = 0.20,
    range_sigma_m: float = 0.0015,
    range_rate_hz: float = 10.0,
    max_range_m: float = 80.0,
    field_ut_inc_dec=DEFAULT_FIELD,
    mag_disturbance_ut: float = 0.0,
    mag_disturbance_start_s: float = 4.0,
    mag_disturbance_end_s: float | None = None,
    mag_disturbance_noise_ut: float = 1.0,
    mag_disturbance_dir_b=(0.0, 1.0, 0.0),
    roll_deg: float = 0.0,
    roll_sway_deg: float = 0.0,
    roll_sway_period_s: float = 7.0,
    gyro_scale_ppm: float | None = None,
    start_utc: str = "2015-06-11T14:02:00Z",
    t0_s: float = 0.0,
    name: str = "target",
) -> SimResult:
    """Simulate the `target` scenario; see the module docstring.

    `mag_disturbance_ut` > 0 adds a field of that magnitude along `mag_disturbance_dir_b` (body FRD;
    default body right) plus white noise `mag_disturbance_noise_ut` in [start, end) (end default:
    the end of the session). `noise_free` gives error-free IMU, magnetometer and ranges.
    `roll_deg` holds the device at that roll (a hand-held device is never level) and
    `roll_sway_deg` adds a sinusoidal roll sway of that amplitude and period `roll_sway_period_s`
    (roll turns about the beam, so LR1 still hits the same points). `gyro_scale_ppm` the SD of each
    element of the gyro's constant scale/misalignment dM (None: the grade's `GYRO_SCALE_PPM`; 0: none).
    """
    if duration_s <= 0 or rate_hz <= 0 or wall_distance_m <= 0:
        raise InvalidInputError("duration, rate and wall distance must be > 0")
    if motion not in ("shots", "sine"):
        raise InvalidInputError(f"motion: {motion!r} is not one of shots, sine")
    stride = rate_hz / range_rate_hz
    if abs(stride - round(stride)) > 1e-9 or round(stride) < 1:
        raise InvalidInputError(f"range rate: {range_rate_hz} Hz must divide the IMU rate {rate_hz} Hz")
    # spawn(4)'s first three children are spawn(3)'s: the scale draw leaves every other draw of a seed as it was
    imu_rng, mag_rng, lr_rng, scale_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4))
    az = np.radians(wall_azimuth_deg)
    ids = tuple(str(t[0]) for t in targets)
    pts = wall_points_ned(wall_distance_m, az, [t[1] for t in targets], [t[2] for t in targets])
    if motion == "shots":
        ref = [i for i, t in enumerate(targets) if t[3] == "reference"]
        order = ref + [i for i in range(len(ids)) if i not in ref]
        yaw_p, pitch_p, shots = _aim_schedule(pts[order], tuple(ids[i] for i in order), duration_s, static_s, hold_s, az, 0.0)
    else:
        a = np.radians(54.0)
        yaw_p, pitch_p, shots = SineProfile(a, 100.0, offset=az), SineProfile(a, 100.0), []
    roll_p = (SineProfile(np.radians(roll_sway_deg), roll_sway_period_s, offset=np.radians(roll_deg))
              if roll_sway_deg != 0.0 else ConstantProfile(np.radians(roll_deg)))
    mot = AimMotion(yaw_p, pitch_p, roll_p)

    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    lla0 = np.asarray(observer_lla, dtype=float)
    ti = simulate_truth_imu(mot, t, lla0)
    g = imu_grade("perfect" if noise_free else grade, "target")
    sd_scale = (GYRO_SCALE_PPM[g.name] if gyro_scale_ppm is None else float(gyro_scale_ppm)) * 1e-6
    if sd_scale < 0.0:
        raise InvalidInputError(f"gyro_scale_ppm: {gyro_scale_ppm} must be >= 0")
    dM = scale_rng.standard_normal((3, 3)) * sd_scale if (sd_scale > 0.0 and not noise_free) else np.zeros((3, 3))
    gyro, acc, err = corrupt_imu(ti.gyro_b_rps @ (np.eye(3) + dM).T, ti.acc_b_mps2, g, rate_hz, imu_rng)
    truth = SimTruth(ti.t_s, ti.lla, ti.vel_ned_mps, ti.rpy_rad)
    C_nb = truth.C_nb

    F, inc, dec = field_ut_inc_dec
    inc, dec = np.radians(inc), np.radians(dec)
    m_n = F * np.array([np.cos(inc) * np.cos(dec), np.cos(inc) * np.sin(dec), np.sin(inc)])
    mag_true = np.einsum("kji,j->ki", C_nb, m_n)  # instantaneous field at t_k, body FRD
    mag = mag_true + mag_rng.standard_normal((n, 3)) * g.mag_noise_ut
    if mag_disturbance_ut > 0.0 and not noise_free:
        end = duration_s + 1.0 if mag_disturbance_end_s is None else mag_disturbance_end_s
        win = (t >= mag_disturbance_start_s) & (t < end)
        d = np.asarray(mag_disturbance_dir_b, dtype=float)
        d = d / np.linalg.norm(d)
        mag[win] += mag_disturbance_ut * d + mag_rng.standard_normal((int(win.sum()), 3)) * mag_disturbance_noise_ut
    imu = SimImu(t, gyro, acc, mag, ti.gyro_b_rps, ti.acc_b_mps2, mag_true, err, g, "RFU", float(rate_hz))

    ri = np.arange(0, n, int(round(stride)))
    d_true = beam_ranges(C_nb[ri], wall_distance_m, az, baseline_12_m, baseline_13_m, max_range_m)
    sig = 0.0 if noise_free else range_sigma_m
    ranges = SimRanges(t[ri].copy(), d_true + lr_rng.standard_normal(d_true.shape) * sig, d_true, baseline_12_m, baseline_13_m, float(sig if sig > 0 else range_sigma_m))

    targets_out = SimTargets(ids, ned_to_lla(pts, lla0), tuple(str(t[3]) for t in targets))
    shots_out = SimShots(tuple(s[0] for s in shots), np.array([s[1] for s in shots]), np.array([s[2] for s in shots]))
    params = {
        "scenario": "target",
        "duration_s": duration_s,
        "seed": seed,
        "grade": g.name,
        "motion": motion,
        "wall_distance_m": wall_distance_m,
        "wall_azimuth_deg": wall_azimuth_deg,
        "field_ut_inc_dec": list(field_ut_inc_dec),
        "mag_disturbance_ut": mag_disturbance_ut,
        "roll_deg": roll_deg,
        "roll_sway_deg": roll_sway_deg,
        "gyro_scale_ppm": sd_scale * 1e6,
        "gyro_scale_misalignment": dM.tolist(),  # omega_meas = (I + dM) omega + bias + noise
        "mag_disturbance_window_s": [mag_disturbance_start_s, mag_disturbance_end_s] if mag_disturbance_ut > 0 else None,
    }
    return SimResult(
        kind="target",
        name=name,
        t0_s=float(t0_s),
        truth=truth,
        imu=imu,
        ranges=ranges,
        targets=targets_out,
        shots=shots_out if shots else None,
        toml={
            "start_utc": start_utc,
            "magnetic": {"declination_deg": float(field_ut_inc_dec[2])},
            "observer": {"lat": float(lla0[0]), "lon": float(lla0[1]), "h": float(lla0[2])},
        },
        params=params,
    )
