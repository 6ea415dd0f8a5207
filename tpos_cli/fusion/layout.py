"""Layout of the error state of every INS error-state filter (paper 003 Sec. 4.2 order).

The first 15 states are the navigation errors at fixed offsets (module constants: numba reads
them as compile-time constants). States beyond them come in optional blocks (`Block`), placed
after index 15 in the order a `StateLayout` lists them; each block is a set of scalar states
with first-order dynamics (a Gauss-Markov time constant, or none for a random walk / random
constant), a driving PSD, and a prior covariance. Their nominal values ride in the filter's
`bias` vector after the six IMU biases (`bias[6 + offset - 15]`), fed back like the biases
(`bias -= x`), so that a smoother sees them as part of the state.

To add a state (issue 11: lever arm, IMU-GPS clock offset, odometer scale, mounting
misalignment): add a `Block` member, a builder like `gps_error_block`, and use the block's
offset (`layout.offset(Block.X)`, in kernels `layout_offsets[Block.X]`, -1 when absent) in the
measurement models that depend on it (`fusion.measurements`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

POS = 0  # position error, NED metres
VEL = 3  # velocity error, NED m/s
ATT = 6  # attitude error phi, rad: C_nb_est = (I - [phi x]) C_nb_true
BA = 9  # accelerometer bias error, m/s^2 (body)
BG = 12  # gyro bias error, rad/s (body)
N_NAV = 15


class Block(IntEnum):
    """Optional blocks of states after the 15 navigation errors."""

    GPS_ERROR = 0  # 3: time-correlated error of the GPS fixes, NED m (Gauss-Markov)
    RANGE_BIAS = 1  # 1: common range bias / NLOS state eps_d of paper 002 Eq. 17-18, m (random walk)
    FLOOR = 2  # 1: error of the floor height of the floor constraint, m (constant)
    CALIBRATION = 3  # A: residual bias of each anchor's calibrated range, m (constants; follows FLOOR)
    MOUNTING = 4  # 3: residual misalignment [pitch, yaw] (rad) of the IMU on the vehicle, distance (m) from
    # the IMU forward to the point where the non-holonomic constraint holds, negative behind (constants)
    ODOMETER = 5  # 1: scale-factor error of the odometer speed (random constant)
    CLOCK = 6  # 2: IMU-GPS clock offsets (s) of the fixes' positions and of their velocities: a value
    # stamped t holds at IMU time t + d (constants)
    LEVER = 7  # 2: correction (m) to the stated GPS lever arm along the vehicle's forward and right axes
    # (rows 0, 1 of the filter's C_vb: a level IMU's own x, y without vehicle axes) (constants)
    FLOAT = 8  # 3: offset of the GPS fixes of RTK float epochs, NED m (Gauss-Markov; `fusion.rtk_float`)


N_BLOCKS = len(Block)


@dataclass(frozen=True)
class ExtraBlock:
    """One block of extra states: `size` states, Gauss-Markov time constant `tau_s` (0: random
    walk, or a random constant when `q` is 0), driving PSDs `q` (size,), prior covariance P0."""

    block: Block
    size: int
    tau_s: float
    q: np.ndarray
    P0: np.ndarray


@dataclass(frozen=True)
class StateLayout:
    """The error state of one filter: 15 navigation errors plus `blocks`, in that order."""

    blocks: tuple[ExtraBlock, ...] = ()

    @property
    def n_states(self) -> int:
        return N_NAV + sum(b.size for b in self.blocks)

    @property
    def n_extra(self) -> int:
        return self.n_states - N_NAV

    def offset(self, block: Block) -> int:
        """Index of the block's first state, or -1 when the layout has no such block."""
        o = N_NAV
        for b in self.blocks:
            if b.block == block:
                return o
            o += b.size
        return -1

    def offsets(self) -> np.ndarray:
        """(N_BLOCKS,) int64: `offset` of every Block (-1 absent), for the kernels."""
        return np.array([self.offset(b) for b in Block], dtype=np.int64)

    def extra_tau_s(self) -> np.ndarray:
        return np.concatenate([np.full(b.size, float(b.tau_s)) for b in self.blocks]) if self.blocks else np.zeros(0)

    def extra_q(self) -> np.ndarray:
        return np.concatenate([np.asarray(b.q, dtype=float) * np.ones(b.size) for b in self.blocks]) if self.blocks else np.zeros(0)

    def extra_P0(self) -> np.ndarray:
        """Prior covariance of the extra states (n_extra, n_extra), block diagonal."""
        P = np.zeros((self.n_extra, self.n_extra))
        o = 0
        for b in self.blocks:
            P[o:o + b.size, o:o + b.size] = b.P0
            o += b.size
        return P


def gps_error_block(sigma_ned_m, tau_s: float) -> ExtraBlock:
    """Three first-order Gauss-Markov GPS position errors (NED) of stationary SDs `sigma_ned_m`:
    driving PSD 2 sigma^2 / tau, prior the stationary covariance (the error is there from the start)."""
    sd = np.asarray(sigma_ned_m, dtype=float) * np.ones(3)
    if not tau_s > 0:
        raise ValueError(f"`gps_gm_tau_s` must be > 0 with GPS error states, got {tau_s}")
    return ExtraBlock(Block.GPS_ERROR, 3, float(tau_s), 2.0 * sd**2 / max(float(tau_s), 1e-300), np.diag(sd**2))


def float_offset_block(sigma_h_m: float, sigma_v_m: float, tau_s: float) -> ExtraBlock:
    """The offset b_float (NED m) of an RTK receiver's float-epoch fixes, three first-order
    Gauss-Markov states of stationary SDs (sigma_h_m, sigma_h_m, sigma_v_m) and time constant tau_s:
    driving PSD 2 sigma^2 / tau, prior the stationary covariance. Only the position rows of float
    epochs see it (`fusion.rtk_float`); elsewhere it decays back to that prior, so every float stretch
    starts from the class's own uncertainty."""
    if not tau_s > 0:
        raise ValueError(f"`gps_float_tau_s` must be > 0 with float offset states, got {tau_s}")
    sd = np.array([sigma_h_m, sigma_h_m, sigma_v_m], dtype=float)
    return ExtraBlock(Block.FLOAT, 3, float(tau_s), 2.0 * sd**2 / float(tau_s), np.diag(sd**2))


def ranging_blocks(range_bias_sd_m: float, range_bias_q_m2ps: float, floor_sd_m: float, cal_cov_m2) -> tuple[ExtraBlock, ...]:
    """The extra states of the INS/range filter: eps_d (random walk), the floor-height error and
    the anchors' calibration biases (random constants, zero variance = not estimated)."""
    cal = np.atleast_2d(np.asarray(cal_cov_m2, dtype=float))
    return (ExtraBlock(Block.RANGE_BIAS, 1, 0.0, np.array([range_bias_q_m2ps]), np.array([[range_bias_sd_m**2]])),
            ExtraBlock(Block.FLOOR, 1, 0.0, np.zeros(1), np.array([[floor_sd_m**2]])),
            ExtraBlock(Block.CALIBRATION, cal.shape[0], 0.0, np.zeros(cal.shape[0]), cal))


def mounting_block(sigma_rad: float, sigma_axle_m: float) -> ExtraBlock:
    """Residual mounting misalignment [pitch, yaw] (rad, prior SD sigma_rad) and the distance (m,
    prior SD sigma_axle_m) from the IMU back to the point where the vehicle does not slip (rear
    axle), random constants: the NHC rows (`fusion.measurements.Kind.NHC`) observe the angles
    with the forward speed and the distance with the yaw rate; without them an error in the
    mounting would be enforced on the attitude as if it were exact."""
    return ExtraBlock(Block.MOUNTING, 3, 0.0, np.zeros(3), np.diag([float(sigma_rad) ** 2] * 2 + [float(sigma_axle_m) ** 2]))


def odometer_block(sigma_scale: float) -> ExtraBlock:
    """The odometer's scale-factor error k (speed read = (1 + k) x true speed), a random constant
    of prior SD sigma_scale (tyre wear and pressure: a few per cent)."""
    return ExtraBlock(Block.ODOMETER, 1, 0.0, np.zeros(1), np.array([[float(sigma_scale) ** 2]]))


def clock_block(sigma_s: float, rw_s_per_sqrt_s: float = 0.0) -> ExtraBlock:
    """The IMU-GPS clock offsets [d_pos, d_vel] (s, prior SD sigma_s each), random constants: a
    position stamped t was taken at IMU time t + d_pos, a velocity at t + d_vel (receivers derive
    them differently: Doppler or differenced positions, filtered or not), so the position rows see
    v d_pos and the velocity rows a d_vel (`fusion.measurements.measure`). Loggers stamp GPS
    records late or early by tens to hundreds of milliseconds; at 10 m/s, 0.1 s is a metre along
    the track, and in turns the forward and backward runs then pull the heading apart. A
    logger's clock also drifts against GPS time (tens of ppm, and buffering that changes), so the
    offsets are random walks of rw_s_per_sqrt_s (PSD rw^2 s^2/s) rather than exact constants."""
    return ExtraBlock(Block.CLOCK, 2, 0.0, np.full(2, float(rw_s_per_sqrt_s) ** 2), np.eye(2) * float(sigma_s) ** 2)


def lever_arm_block(sigma_m: float) -> ExtraBlock:
    """The correction dl = (forward, right) (m, prior SD sigma_m each) to the stated GPS lever arm
    in the vehicle's axes, random constants: the antenna sits at l_stated + C_vb^T (dl, 0) from the
    IMU, so the position rows see C_nb C_vb^T (dl, 0) and the velocity rows C_nb [w x] C_vb^T (dl, 0)
    (`fusion.measurements.measure`). Horizontal only: on a car the vertical component changes the
    antenna's position only through roll and pitch of a few degrees (under 10 % of it), so it goes
    into the height, which it does not bias, rather than into a state it would not observe. A
    lever arm the log does not state (or states wrong) shows in turns as a position error that
    rotates with the heading; unmodelled, the fixes pull the heading to explain it, and the
    forward and backward runs disagree after every turn."""
    return ExtraBlock(Block.LEVER, 2, 0.0, np.zeros(2), np.eye(2) * float(sigma_m) ** 2)


def backward_sign(n_states: int = N_NAV, layout: StateLayout | None = None) -> np.ndarray:
    """(n,) signs mapping a backward-run error state to forward-time errors: velocity, gyro bias
    and a clock offset (time-odd: reversed time runs the other way) flip; the other extra states
    keep their sign (they are stationary or constant)."""
    s = np.ones(n_states)
    s[VEL : VEL + 3] = -1.0
    s[BG : BG + 3] = -1.0
    if layout is not None and layout.offset(Block.CLOCK) >= 0:
        s[layout.offset(Block.CLOCK):layout.offset(Block.CLOCK) + 2] = -1.0
    return s
