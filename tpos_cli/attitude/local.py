"""Local attitude filters of paper 000 (Sect. 5.1): gyro-only, LF1 (acc/mag) and LF2 (three LRs).

`model = "full"` (default) is an error-state DCM filter valid at any roll; `model = "paper8"` is
the paper's 8-state simplified DCM filter (Eq. 16, 21-22), which assumes zero roll. Both return an
`AttitudeSolution` with `C_nb` (FRD->NED) and the NED attitude-error covariance `P_att`
(C_true = exp(phi) C_hat), so the master filter and the targeting code see one interface.
The upper-bounding of Eq. 23 (P0/beta, Q/beta) is applied by the caller through `beta`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tpos_cli.attitude import _kernels as K
from tpos_cli.attitude import motion
from tpos_cli.attitude.magfield import reference_field_ned
from tpos_cli.frames import earth
from tpos_cli.frames.rotation import axes_to_dcm, dcm_to_euler, euler_sigmas_deg

# C_bs for the paper's RFU body axes, and the fixed ENU->NED swap: the one place where the
# paper's frames meet the package's (docs/architecture.md).
C_FRD_RFU = axes_to_dcm("RFU")
C_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class FilterNoise:
    """Sensor noise in SI units: per-sample white noise SDs, the initial bias SDs and their random walks."""

    gyro_noise_rps: float
    gyro_bias_rps: float
    gyro_bias_rw_rps_rts: float
    acc_noise_mps2: float
    mag_noise_ut: float
    range_sigma_m: float
    gyro_scale_sd: float = 3e-4  # relative SD of a sample's rotation angle (scale factor, coning)
    # > 0: the gyro's constant scale/misalignment, omega_meas = (I + dM) omega + b with dM ~ N(0, sd^2 I9) (a
    # data-sheet figure), is carried as a sensitivity the filter never corrects (`_kernels.Init.S0`,
    # `AttitudeSolution.S_gm`): a heading carried by the gyro through many turns drifts by dM times the turned angle
    gyro_scale_const_sd: float = 0.0
    acc_bias_mps2: float = 0.0  # SD of the accelerometer bias (prior of its states; 0: no such error)
    acc_bias_rw_mps2_rts: float = 0.0  # its random walk


@dataclass(frozen=True)
class FilterSetup:
    """Everything a local filter needs besides the samples.

    lat_rad, h_m: observer position (Earth rate and gravity). C0 (3,3), bias0_rps (3,),
    P0 (6,6) initial state (attitude error NED rad^2, gyro bias (rad/s)^2; the accelerometer-bias
    prior is then `noise.acc_bias_mps2` about `acc_bias0_mps2`) or (9,9) with the accelerometer bias
    (m/s^2)^2 and its correlation with the levelling error. beta: Eq. 23-24 information share.
    mag_ref = (norm uT, dip rad) of the Earth field (with `declination_rad` the reference vector of
    the magnetic update); wall_n_ned (3,) unit normal of the wall the beams hit; baselines in m
    (contract `[rangefinders]`).
    """

    lat_rad: float
    h_m: float
    C0: np.ndarray
    bias0_rps: np.ndarray
    P0: np.ndarray
    noise: FilterNoise
    declination_rad: float = 0.0
    mag_ref: tuple[float, float] = (0.0, 0.0)
    mag_norm_tol_ut: float = 0.0  # <= 0: no field-magnitude/dip test inside LF1
    mag_dip_tol_rad: float = np.radians(5.0)
    mag_consider: bool = True  # the magnetometer corrects heading and gyro bias only (`_kernels.Gates`)
    mag_nis_tau_s: float = 0.0  # > 0: reject the field while its mean NIS over ~tau exceeds ratio (per dof)
    mag_nis_ratio: float = 3.0
    acc_static_tol_mps2: float = 0.5
    gyro_static_tol_rps: float = np.radians(90.0)
    wall_n_ned: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    baseline_12_m: float = 0.2
    baseline_13_m: float = 0.2
    range_gate_chi2: float = 0.0
    beta: float = 1.0
    # bounded motion of a hand-held device (kernel USE_MOTION): SDs of its velocity and of its
    # displacement from the mean position, and how often they are applied (~ their correlation time)
    motion_sd_mps: float = 0.5
    motion_sd_m: float = 0.3
    motion_interval_s: float = 1.0
    zupt_sd_mps: float = 0.02  # velocity SD of a device in a detected still period
    # > 0: the displacement is a damped oscillator (natural frequency, damping ratio, stationary SD
    # motion_sd_m) checked against the integrated specific force every motion_step_s (kernel `Hand`)
    motion_freq_hz: float = 0.0
    motion_damping: float = 0.7071
    motion_step_s: float = 0.05
    gyro_err_sd: float = 0.0  # > 0: scale-factor/misalignment states (I + M), prior SD of each element
    gyro_err_rw_rts: float = 0.0  # their random walk, per sqrt(s)
    gyro_M0: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    acc_bias0_mps2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acc_scale_sd: float = 0.0  # > 0: accelerometer scale-factor states (prior SD, relative)
    gravity_mps2: float | None = None  # measured |f| at rest (absorbs the accelerometer scale); None: normal gravity
    # the alignment's attitude error per accelerometer bias, phi0 = lev_map b_a (rad per m/s^2), and the
    # wall normal's azimuth error per bias (LF2): the filter carries both as a bias sensitivity
    # (`_kernels.Init.S0`, `AttitudeSolution.S_ba`)
    lev_map: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    wall_sens: np.ndarray = field(default_factory=lambda: np.zeros(3))
    # > 0: the prior's heading is the start alignment's, whose error (variance align_heading_var_rad2 =
    # P0[2,2]) other filters share (LF2's wall normal): the run carries its sensitivity to it
    # (`AttitudeSolution.s_al`) and its covariance holds that error once, not divided by beta
    align_heading_var_rad2: float = 0.0


@dataclass(frozen=True)
class AttitudeSolution:
    """One attitude solution over the IMU samples.

    C_nb (N,3,3) FRD->NED; P_att (N,3,3) rad^2 NED error covariance; bias_rps (N,3) or None;
    acc_bias_mps2 (N,3) or None; var_bias (N,6) variances of [gyro bias, acc bias] or None;
    nis: {"acc"|"mag"|"range"|"obs": (N,) NaN where no update}; mag_ok (N,) bool or None.
    nis_backward: a smoothed solution's backward run's NIS, the same keys (`nis` holds the forward run's).
    """

    name: str
    t_s: np.ndarray
    C_nb: np.ndarray
    P_att: np.ndarray
    bias_rps: np.ndarray | None = None
    nis: dict = field(default_factory=dict)
    mag_ok: np.ndarray | None = None
    gyro_M: np.ndarray | None = None  # (N,3,3) estimated gyro scale/misalignment (setup.gyro_err_sd > 0)
    mag_gated: bool = False  # True: LF1 already dropped the samples with mag_ok False
    x8: np.ndarray | None = None  # paper8 model only: the 8 DCM states (N,8) and covariance
    P8: np.ndarray | None = None
    acc_bias_mps2: np.ndarray | None = None
    var_bias: np.ndarray | None = None
    fb_scale: tuple[float, float] | None = None  # smoothed only: (tilt, heading) forward/backward consistency (smoother)
    # smoothed only: (N,) bool, True where at least one run used the field sample (False in both: the heading
    # there rests on the gyro and the alignments alone)
    mag_any: np.ndarray | None = None
    # the attitude error's sensitivity to the accelerometer bias, e = a + S_ba b_a (N,3,3), and the part
    # Q_ba (N,3,3) rad^2 of P_att that the filter's own bias prior explains (`honest_covariance`)
    S_ba: np.ndarray | None = None
    Q_ba: np.ndarray | None = None
    # the error's sensitivity (N,3) to the start alignment's heading error h ~ N(0, var_al) rad^2, an error
    # other solutions share: e = a + s_al h (+ S_ba b_a), a independent of h; P_att holds var_al s s^T
    # (`master.fuse` fuses with the cross-covariance var_al s_i s_j^T)
    s_al: np.ndarray | None = None
    var_al: float = 0.0
    # the error's sensitivity (N,3,9) to the gyro's constant scale/misalignment dM ~ N(0, var_gm I9), which every
    # solution from the same gyro shares: e = a + S_gm vec(dM) (+ ...), P_att holds var_gm S_gm S_gm^T
    # (`FilterNoise.gyro_scale_const_sd`; `master.fuse` adds it to the fused covariance for the fused weights)
    S_gm: np.ndarray | None = None
    var_gm: float = 0.0
    nis_backward: dict | None = None

    def euler_deg(self):
        """(N,3) roll, pitch, yaw in degrees, yaw in [0, 360)."""
        r, p, y = dcm_to_euler(self.C_nb)
        out = np.degrees(np.stack([r, p, y], axis=-1))
        out[:, 2] %= 360.0
        return out

    def euler_sigma_deg(self):
        """(N,3) SD of roll, pitch, yaw (deg) from P_att (phi = M d(roll, pitch, yaw))."""
        return euler_sigmas_deg(self.C_nb, self.P_att)


def honest_covariance(sol: AttitudeSolution, acc_bias_var: float) -> np.ndarray:
    """(N,3,3) rad^2 covariance of the attitude error with the accelerometer bias b_a ~ N(0, acc_bias_var I)
    acting through the levelling and the filters as it does: e = a + S_ba b_a, a independent of b_a, so
    Cov(e) = (P_att - Q_ba) + S_ba S_ba^T acc_bias_var (a filter whose prior takes the alignment's tilt
    as independent of b_a holds Q_ba = B B^T acc_bias_var of it in P_att; `_kernels.Init.S0`).
    P_att where the solution has no sensitivity."""
    if sol.S_ba is None:
        return sol.P_att
    S = sol.S_ba
    return sol.P_att - sol.Q_ba + acc_bias_var * (S @ np.swapaxes(S, 1, 2))


def add_heading_variance(sol: AttitudeSolution, var_rad2: float, bias_var_rad2: float = 0.0,
                         align_var_rad2: float = 0.0) -> AttitudeSolution:
    """`sol` with a constant heading-error variance added about NED down (e.g. LF2's wall azimuth), of
    which `bias_var_rad2` is the accelerometer bias's share that the solution's sensitivity `S_ba`
    already carries (so it joins `Q_ba` too, and `honest_covariance` counts it once) and `align_var_rad2`
    the start alignment's heading error (variance `var_al`) in it: a wall normal turned by the alignment's
    heading gives the solution that heading error again (`s_al` gains e_D, with its cross-covariance)."""
    if var_rad2 <= 0.0:
        return sol
    P = sol.P_att.copy()
    P[:, 2, 2] += var_rad2
    Q = sol.Q_ba
    if Q is not None and bias_var_rad2 > 0.0:
        Q = Q.copy()
        Q[:, 2, 2] += bias_var_rad2
    s_al = sol.s_al
    if s_al is not None and align_var_rad2 > 0.0:
        # the shared part becomes var (s + u)(s + u)^T, u = e_D: var u u^T is in var_rad2, the cross terms are added
        X = align_var_rad2 * s_al
        P[:, :, 2] += X
        P[:, 2, :] += X
        s_al = s_al + np.array([0.0, 0.0, 1.0])
    return replace(sol, P_att=P, Q_ba=Q, s_al=s_al)


def range_differences(t_imu_s, t_rng_s, range_m):
    """(N,2) d1-d2, d1-d3 attached to the first IMU sample at or after each range sample.

    NaN where no return (any of the three beams missing) or no range sample in the interval.
    """
    out = np.full((t_imu_s.size, 2), np.nan)
    if t_rng_s is None or len(t_rng_s) == 0:
        return out
    r = np.asarray(range_m, dtype=float)
    idx = np.searchsorted(t_imu_s, t_rng_s, side="left")
    keep = idx < t_imu_s.size
    d = np.stack([r[:, 0] - r[:, 1], r[:, 0] - r[:, 2]], axis=-1)
    out[idx[keep]] = d[keep]
    return out


def gravity_variance(gyro_b_rps, acc_b_mps2, still, g_mps2, r_acc, acc_tol_mps2, gyro_tol_rps):
    """(N,) variance (m/s^2)^2 of the direct gravity update (Eq. 5) at each sample; NaN where none.

    Gravity is measured only in detected still periods where | |f| - g | and |omega| are below
    their tolerances (used when the hand-motion model is off: with it, still periods are
    zero-velocity updates of the integrated specific force instead).
    """
    fn = np.linalg.norm(acc_b_mps2, axis=1)
    w = np.linalg.norm(gyro_b_rps, axis=1)
    quiet = still & (np.abs(fn - g_mps2) < acc_tol_mps2) & (w < gyro_tol_rps)
    return np.where(quiet, r_acc, np.nan)


def _nav_vectors(setup: FilterSetup):
    w_ie = earth.earth_rate_ned_rps(setup.lat_rad)
    g_n = earth.gravity_ned_mps2(setup.lat_rad, setup.h_m)
    return np.ascontiguousarray(w_ie, dtype=float), np.ascontiguousarray(g_n, dtype=float)


def _reverse(t, gyro, acc, mag, rd, st):
    """Time-reversed samples: the rate of row k covers (t_{k-1}, t_k], so it moves one row (negated);
    the specific force is an interval mean too (not negated)."""
    g = np.zeros_like(gyro)
    g[1:] = -gyro[::-1][:-1]
    a = np.empty_like(acc)
    a[1:] = acc[::-1][:-1]
    a[0] = acc[-1]
    # copies, not reversed views: a view is another memory layout, for which numba would compile the
    # whole kernel a second time (and `@` on it warns)
    return -t[::-1], g, a, np.ascontiguousarray(mag[::-1]), np.ascontiguousarray(rd[::-1]), np.ascontiguousarray(st[::-1])


def _hand(setup: FilterSetup, dt_mean: float, share: float) -> K.Hand:
    """The kernel's hand model from the setup; `share` the information share (Eq. 23)."""
    step = max(1, int(round(setup.motion_step_s / dt_mean)))
    epoch = max(1, int(round(setup.motion_interval_s / dt_mean)))
    zupt = setup.zupt_sd_mps / np.sqrt(share)
    if setup.motion_freq_hz > 0.0:
        vp1, _ = motion.displacement_var(setup.motion_freq_hz, setup.motion_damping, 1.0)
        q = setup.motion_sd_m**2 / vp1  # stationary displacement SD -> driving-noise PSD
        return K.Hand(2.0 * np.pi * setup.motion_freq_hz, setup.motion_damping, q / share, step, epoch,
                      setup.motion_sd_mps / np.sqrt(share), setup.motion_sd_m / np.sqrt(share), zupt)
    return K.Hand(0.0, 0.0, 0.0, step, epoch, setup.motion_sd_mps / np.sqrt(share), setup.motion_sd_m / np.sqrt(share), zupt)


def initial_covariance(setup: FilterSetup, use: int) -> np.ndarray:
    """(n,n) P0 of the kernel's state (`_kernels.state_offsets`), before the Eq. 23 division by beta."""
    n, i_m, i_v, i_s = K.state_offsets(use, setup.gyro_err_sd > 0.0, setup.acc_scale_sd > 0.0)
    P0 = np.zeros((n, n))
    P0[K.I_BA:K.I_BA + 3, K.I_BA:K.I_BA + 3] = np.eye(3) * setup.noise.acc_bias_mps2**2
    given = np.asarray(setup.P0, dtype=float)
    P0[0:given.shape[0], 0:given.shape[0]] = given  # (6,6) [phi, gyro bias] or (9,9) with the acc bias
    if i_m:
        P0[i_m:i_m + 9, i_m:i_m + 9] = np.eye(9) * setup.gyro_err_sd**2
    if i_s:
        P0[i_s:i_s + 3, i_s:i_s + 3] = np.eye(3) * setup.acc_scale_sd**2
    if i_v:
        if setup.motion_freq_hz > 0.0:
            vp1, vv1 = motion.displacement_var(setup.motion_freq_hz, setup.motion_damping, 1.0)
            var_v, var_p = vv1 * setup.motion_sd_m**2 / vp1, setup.motion_sd_m**2
        else:
            var_v, var_p = setup.motion_sd_mps**2, setup.motion_sd_m**2
        P0[i_v:i_v + 3, i_v:i_v + 3] = np.eye(3) * var_v
        P0[i_v + 3:i_v + 6, i_v + 3:i_v + 6] = np.eye(3) * var_p
    return P0


def run_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, setup: FilterSetup, use: int,
             backward: bool = False, still=None) -> AttitudeSolution:
    """Run the full-attitude error-state local filter (`_kernels.marg_filter`), forward or backward.

    t_s (N,) s increasing; gyro_b_rps, acc_b_mps2 (N,3) FRD; mag_b_ut (N,3) uT or None (NaN rows:
    not used); rdiff_m (N,2) or None (`range_differences`); `use` a combination of `_kernels.USE_*`
    (0: gyro only). Backward: the same kernel on time-reversed samples with negated rates; `setup.C0`,
    `bias0_rps` are then the state at the LAST sample. `still` (N,) bool marks detected still periods
    (default: all). Raises ValueError on inconsistent shapes or a magnetic update without reference.
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    n = t.size
    gyro = np.ascontiguousarray(gyro_b_rps, dtype=float)
    acc = np.ascontiguousarray(acc_b_mps2, dtype=float)
    mag = np.full((n, 3), np.nan) if mag_b_ut is None else np.ascontiguousarray(mag_b_ut, dtype=float)
    rd = np.full((n, 2), np.nan) if rdiff_m is None else np.ascontiguousarray(rdiff_m, dtype=float)
    st = np.ones(n, dtype=np.bool_) if still is None else np.ascontiguousarray(still, dtype=np.bool_)
    for a, shape, what in ((gyro, (n, 3), "gyro"), (acc, (n, 3), "acc"), (mag, (n, 3), "mag"), (rd, (n, 2), "rdiff"),
                           (st, (n,), "still"), (np.asarray(setup.C0), (3, 3), "C0")):
        if a.shape != shape:
            raise ValueError(f"run_full: {what} has shape {a.shape}, expected {shape}")
    if np.shape(setup.P0) not in ((6, 6), (9, 9)):
        raise ValueError(f"run_full: P0 has shape {np.shape(setup.P0)}, expected (6, 6) or (9, 9)")
    if n > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("run_full: t_s must increase")
    if (use & K.USE_MAG) and setup.mag_ref[0] <= 0.0:
        raise ValueError("run_full: the magnetic update needs setup.mag_ref (norm, dip) of the Earth field")
    noise = setup.noise
    w_ie, g_n = _nav_vectors(setup)
    if setup.gravity_mps2 is not None:
        g_n = np.array([0.0, 0.0, float(setup.gravity_mps2)])
    bias0 = np.asarray(setup.bias0_rps, dtype=float)
    if backward:
        t, gyro, acc, mag, rd, st = _reverse(t, gyro, acc, mag, rd, st)
        w_ie = -w_ie
        bias0 = -bias0
    beta = setup.beta
    o2 = np.array([0.0, -setup.baseline_12_m, 0.0])  # LR2 left of LR1 (FRD y is right)
    o3 = np.array([0.0, 0.0, setup.baseline_13_m])  # LR3 below LR1 (FRD z is down)
    r_rng = noise.range_sigma_m**2 * np.array([[2.0, 1.0], [1.0, 2.0]])  # d1 shared by both
    r_acc = noise.acc_noise_mps2**2
    share = 1.0
    if (use & K.USE_RANGE) and (use & K.USE_ACC):
        # LF2 levels with the accelerometer too (roll is unobservable from the beams alone), with
        # its information share only (R / beta), so that the accelerometer LF1 also uses is not
        # counted twice in full by the master fusion
        r_acc = r_acc / beta
        share = beta
    motion_on = bool(use & K.USE_MOTION)
    grav = np.full(n, np.nan) if motion_on else gravity_variance(
        gyro - bias0, acc, st, float(np.linalg.norm(g_n)), r_acc, setup.acc_static_tol_mps2, setup.gyro_static_tol_rps)
    dt_mean = float(np.median(np.abs(np.diff(t)))) if n > 1 else 0.01
    m_ref = reference_field_ned(setup.mag_ref[0], setup.mag_ref[1], setup.declination_rad)
    samples = K.Samples(t, gyro, acc, mag, rd, st, np.ascontiguousarray(grav))
    frame = K.Frame(w_ie, g_n, m_ref, np.ascontiguousarray(setup.wall_n_ned, dtype=float), o2, o3,
                    np.ascontiguousarray(setup.wall_sens, dtype=float))
    kn = K.Noise((noise.gyro_noise_rps * dt_mean) ** 2 / beta, noise.gyro_scale_sd**2 / beta,
                 noise.gyro_bias_rw_rps_rts**2 / beta, noise.acc_bias_rw_mps2_rts**2 / beta,
                 setup.gyro_err_rw_rts**2 / beta, (noise.acc_noise_mps2 * dt_mean) ** 2,
                 noise.mag_noise_ut**2, r_rng, noise.acc_bias_mps2**2, noise.acc_bias_mps2**2 / beta,
                 noise.gyro_scale_const_sd**2)
    gates = K.Gates(int(use), bool(setup.gyro_err_sd > 0.0), bool(setup.acc_scale_sd > 0.0), bool(setup.mag_consider),
                    float(setup.mag_norm_tol_ut),
                    float(setup.mag_dip_tol_rad), float(setup.mag_nis_tau_s), float(setup.mag_nis_ratio),
                    float(setup.range_gate_chi2))
    acc_b0 = np.asarray(setup.acc_bias0_mps2, dtype=float)
    P0 = initial_covariance(setup, use) / beta
    consider_gm = setup.noise.gyro_scale_const_sd > 0.0
    S0 = np.zeros((P0.shape[0], K.S_GYRO + 9 if consider_gm else 7))
    S0[0:3, 0:3] = setup.lev_map
    S0[K.I_BA:K.I_BA + 3, 0:3] = np.eye(3)
    S0[K.I_BA:K.I_BA + 3, 3:6] = np.eye(3)
    S0[2, 6] = 1.0  # the start alignment's heading error (used with align_heading_var_rad2 > 0)
    init = K.Init(np.ascontiguousarray(setup.C0, dtype=float), np.ascontiguousarray(bias0),
                  np.ascontiguousarray(acc_b0), np.ascontiguousarray(setup.gyro_M0, dtype=float), P0, S0)
    with_m = setup.gyro_err_sd > 0
    out = K.Outputs(np.empty((n, 3, 3)), np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 6)),
                    np.empty(n), np.empty(n), np.empty(n), np.empty(n, dtype=np.bool_), np.zeros((n if with_m else 1, 3, 3)),
                    np.empty((n, 3, S0.shape[1])))
    K.marg_filter(samples, frame, kn, _hand(setup, dt_mean, share), gates, init, out)
    o = {f: getattr(out, f) for f in out._fields}
    del out
    if backward:
        o = {k: v[::-1] if v.shape[0] == n else v for k, v in o.items()}
        o["bias"] = -o["bias"]
    # the sensitivities (N,3,S) are split into the solution's fields and freed before the covariance's
    # temporaries (memory)
    S_att = o.pop("S_att")
    B = S_att[:, :, 3:6]
    Q_ba = noise.acc_bias_mps2**2 / beta * (B @ np.swapaxes(B, 1, 2))
    S_ba = np.ascontiguousarray(S_att[:, :, 0:3])
    s_al = np.ascontiguousarray(S_att[:, :, 6]) if setup.align_heading_var_rad2 > 0.0 else None
    S_gm = np.ascontiguousarray(S_att[:, :, K.S_GYRO:K.S_GYRO + 9]) if consider_gm else None
    del S_att, B
    P_att, var_al = np.ascontiguousarray(o["P_att"]), 0.0
    if s_al is not None:
        # the prior's share of the alignment's heading error, P0[2,2] / beta s s^T (Eq. 23's bound), is that
        # error's own variance once: the cross-covariance with the filters that share it is `master.fuse`'s
        var_al = float(setup.align_heading_var_rad2)
        P_att = P_att + (var_al - P0[2, 2]) * (s_al[:, :, None] * s_al[:, None, :])
    var_gm = 0.0
    if S_gm is not None:
        # the kernel's P_att holds none of dM (no state): its share is added once, exactly
        var_gm = float(setup.noise.gyro_scale_const_sd) ** 2
        P_att = P_att + var_gm * (S_gm @ np.swapaxes(S_gm, 1, 2))
    return AttitudeSolution(
        S_ba=S_ba, Q_ba=Q_ba,
        name=name, t_s=np.asarray(t_s, dtype=float), C_nb=np.ascontiguousarray(o["C"]), P_att=P_att, s_al=s_al,
        var_al=var_al, S_gm=S_gm, var_gm=var_gm, bias_rps=o["bias"], acc_bias_mps2=o["acc_bias"], var_bias=o["var_bias"],
        nis={"acc": o["nis_acc"], "mag": o["nis_mag"], "range": o["nis_rng"]},
        mag_ok=o["mag_ok"] if (use & K.USE_MAG) else None, gyro_M=o["M"] if with_m else None,
        mag_gated=bool((use & K.USE_MAG) and (setup.mag_norm_tol_ut > 0.0 or setup.mag_nis_tau_s > 0.0)),
    )


# ---------------------------------------------------------------- paper's 8-state model


def paper_dcm_from_frd(C_nb):
    """Paper's C_b^n (RFU body -> ENU nav, Eq. 16) from the package's C_nb (FRD -> NED)."""
    return C_NED_ENU.T @ C_nb @ C_FRD_RFU


def frd_from_paper_dcm(C_p):
    """Package C_nb (FRD -> NED) from the paper's C_b^n (RFU -> ENU), projected onto SO(3)."""
    U, _, Vt = np.linalg.svd(C_p)
    D = np.ones(C_p.shape[:-1])
    D[..., 2] = np.sign(np.linalg.det(U @ Vt))
    R = (U * D[..., None, :]) @ Vt
    return C_NED_ENU @ R @ C_FRD_RFU.T


def run_paper8(name, t_s, gyro_b_rps, pitch_yaw_obs_rad, obs_var_rad2, setup: FilterSetup,
               q_elem: float | None = None, r_floor: float = 1e-8, gate: float = 0.0) -> AttitudeSolution:
    """Paper 000 8-state DCM filter (Eq. 16, 21-26) from per-sample (pitch, yaw) observations.

    pitch_yaw_obs_rad (N,2): Eq. 9 (LF1) or Eq. 15 (LF2) angles, NaN where no observation;
    obs_var_rad2 (N,2). Returns P_att mapped to the NED attitude-error form (pitch/yaw only;
    roll is not a state of this model and gets the variance of its initial value).
    """
    n = t_s.size
    noise = setup.noise
    w_ie, _ = _nav_vectors(setup)
    w_ie_enu = C_NED_ENU.T @ w_ie
    gyro_rfu = np.asarray(gyro_b_rps, dtype=float) @ C_FRD_RFU  # v_rfu = C_bs^T v_frd
    Cp0 = paper_dcm_from_frd(np.asarray(setup.C0, dtype=float))
    x0 = np.array([Cp0[0, 0], Cp0[0, 1], Cp0[0, 2], Cp0[1, 0], Cp0[1, 1], Cp0[1, 2], Cp0[2, 1], Cp0[2, 2]])
    dt_mean = float(np.median(np.diff(t_s))) if n > 1 else 0.01
    if q_elem is None:
        # element noise of a rotation error of the per-sample gyro noise plus the bias growth
        q_elem = (noise.gyro_noise_rps * dt_mean) ** 2 + (noise.gyro_bias_rps * dt_mean) ** 2
    var_att0 = float(np.max(np.diag(setup.P0)[0:3]))
    P0 = np.eye(8) * var_att0 / setup.beta
    out_x = np.empty((n, 8))
    out_P = np.empty((n, 8, 8))
    nis = np.empty(n)
    K.run_paper8(np.ascontiguousarray(t_s, dtype=float), np.ascontiguousarray(gyro_rfu),
                 np.ascontiguousarray(pitch_yaw_obs_rad, dtype=float),
                 np.ascontiguousarray(obs_var_rad2, dtype=float), x0, P0, w_ie_enu,
                 q_elem / setup.beta, r_floor, gate, out_x, out_P, nis)
    return paper8_solution(name, t_s, out_x, out_P, nis)


def paper8_solution(name, t_s, x8, P8, nis=None) -> AttitudeSolution:
    """Wrap 8-state estimates (N,8), (N,8,8) as an AttitudeSolution (C projected onto SO(3))."""
    n = x8.shape[0]
    Cp = np.zeros((n, 3, 3))
    Cp[:, 0, :] = x8[:, 0:3]
    Cp[:, 1, :] = x8[:, 3:6]
    Cp[:, 2, 1] = x8[:, 6]
    Cp[:, 2, 2] = x8[:, 7]
    Cp[:, 2, 0] = 0.0
    C_nb = frd_from_paper_dcm(Cp)
    # pitch/yaw variances from the second column (C12, C22, C32) = (s_psi c_th, c_psi c_th, s_th)
    th = np.arcsin(np.clip(x8[:, 6], -1, 1))
    var_th = P8[:, 6, 6] / np.maximum(np.cos(th) ** 2, 1e-6)
    var_psi = (P8[:, 1, 1] + P8[:, 4, 4]) / np.maximum(2.0 * np.cos(th) ** 2, 1e-6)
    _, _, yaw = dcm_to_euler(C_nb)
    P_att = np.zeros((n, 3, 3))
    # phi = d_pitch (-sin yaw, cos yaw, 0) + d_yaw e_D (+ roll along the beam, taken as pitch-like)
    e = np.stack([-np.sin(yaw), np.cos(yaw), np.zeros(n)], axis=-1)
    P_att += var_th[:, None, None] * (e[:, :, None] * e[:, None, :])
    P_att[:, 2, 2] += var_psi
    bx = C_nb[:, :, 0]
    P_att += var_th[:, None, None] * (bx[:, :, None] * bx[:, None, :])
    return AttitudeSolution(name=name, t_s=np.asarray(t_s, dtype=float), C_nb=C_nb, P_att=P_att,
                            nis={"obs": nis if nis is not None else np.full(n, np.nan)},
                            x8=x8, P8=P8)
