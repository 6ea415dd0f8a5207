"""IMU and magnetometer error models per sensor grade.

Per axis, gyro and accelerometer errors are a constant bias of the stated magnitude with a random
sign (papers 000 and 002 state constant biases this way), an optional first-order Gauss-Markov
in-run bias (Groves Eq. 4.2-4.3; paper 003 models its biases so), and white noise of the stated SD
per sample. Grades:

- `perfect`: no errors.
- `mems`: a consumer MEMS IMU (gyro 0.008 deg/s per sample at 100 Hz, 20 deg/h constant plus
  10 deg/h Gauss-Markov bias with 300 s correlation; accelerometer 1.5 mg noise, 10 mg constant
  plus 2 mg Gauss-Markov bias).
- `tactical`: a tactical-grade IMU (gyro 0.004 deg/s per sample, 1 deg/h constant plus 0.5 deg/h
  Gauss-Markov bias; accelerometer 0.5 mg noise, 1 mg constant plus 0.2 mg Gauss-Markov bias):
  every figure between `mems` and a navigation-grade unit.
- `paper`: the scenario paper's figures (`PAPER_GRADES`); figures a paper does not state fall back
  to `mems` and are listed in `assumed`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import lfilter

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.earth import G0_MPS2

DEG = np.pi / 180.0


@dataclass(frozen=True)
class ImuGrade:
    """Error figures of an IMU (and magnetometer), in the contract's units."""

    name: str
    gyro_noise_dps: float = 0.0  # white noise SD per sample, deg/s
    gyro_bias_dph: float = 0.0  # constant bias magnitude per axis, deg/h
    gyro_bias_gm_dph: float = 0.0  # Gauss-Markov in-run bias SD, deg/h
    gyro_bias_tau_s: float = 300.0
    acc_noise_mg: float = 0.0
    acc_bias_mg: float = 0.0
    acc_bias_gm_mg: float = 0.0
    acc_bias_tau_s: float = 300.0
    mag_noise_ut: float = 0.0
    assumed: tuple[str, ...] = field(default=())  # figures not stated by the source

    def toml_figures(self, with_mag: bool) -> dict:
        """The contract's `[imu]` noise keys for this grade."""
        out = {
            "gyro_noise_dps": self.gyro_noise_dps,
            "gyro_bias_dph": self.gyro_bias_dph,
            "acc_noise_mg": self.acc_noise_mg,
            "acc_bias_mg": self.acc_bias_mg,
        }
        if with_mag:
            out["mag_noise_ut"] = self.mag_noise_ut
        return out


PERFECT = ImuGrade("perfect")
MEMS = ImuGrade(
    "mems",
    gyro_noise_dps=0.008,
    gyro_bias_dph=20.0,
    gyro_bias_gm_dph=10.0,
    acc_noise_mg=1.5,
    acc_bias_mg=10.0,
    acc_bias_gm_mg=2.0,
    mag_noise_ut=0.5,
)

TACTICAL = ImuGrade(
    "tactical",
    gyro_noise_dps=0.004,
    gyro_bias_dph=1.0,
    gyro_bias_gm_dph=0.5,
    acc_noise_mg=0.5,
    acc_bias_mg=1.0,
    acc_bias_gm_mg=0.2,
    mag_noise_ut=0.5,
)

PAPER_GRADES = {
    # Paper 000, section 6.1: gyro constant bias 5 deg/h and white noise 0.5 deg/h SD;
    # accelerometer constant bias 1e-4 g and white noise 1e-3 g SD. Magnetometer noise not stated.
    "target": ImuGrade(
        "paper",
        gyro_noise_dps=0.5 / 3600.0,
        gyro_bias_dph=5.0,
        acc_noise_mg=1.0,
        acc_bias_mg=0.1,
        mag_noise_ut=0.5,
        assumed=("mag_noise_ut",),
    ),
    # Paper 003 states no sensor figures (a low-cost 9-DoF MEMS IMU): the mems grade.
    "drive": replace(MEMS, name="paper", assumed=("all: paper 003 gives no sensor figures",)),
    # Paper 002, section 5.1: in-run bias stability < 3 deg/h; acceleration resolution 1/2000 g.
    "ranging": ImuGrade(
        "paper",
        gyro_noise_dps=0.005,
        gyro_bias_dph=3.0,
        acc_noise_mg=0.5,
        acc_bias_mg=2.0,
        assumed=("gyro_noise_dps", "acc_bias_mg"),
    ),
}

GRADES = ("paper", "mems", "tactical", "perfect")


def imu_grade(name: str, scenario: str) -> ImuGrade:
    """The ImuGrade called `name` (paper | mems | tactical | perfect) for `scenario`."""
    if name == "perfect":
        return PERFECT
    if name == "mems":
        return MEMS
    if name == "tactical":
        return TACTICAL
    if name == "paper":
        return PAPER_GRADES[scenario]
    raise InvalidInputError(f"grade: {name!r} is not one of {', '.join(GRADES)}")


@dataclass(frozen=True)
class ImuErrors:
    """Error series added to the ideal IMU (body FRD), so tests can compare estimates to them."""

    gyro_bias_rps: np.ndarray  # (N, 3) total bias (constant + Gauss-Markov)
    acc_bias_mps2: np.ndarray  # (N, 3)
    gyro_noise_rps: np.ndarray  # (N, 3) white part
    acc_noise_mps2: np.ndarray  # (N, 3)


def gauss_markov(n: int, sd: float, tau_s: float, dt_s: float, rng) -> np.ndarray:
    """(n, 3) stationary first-order Gauss-Markov sequence: b_k = phi b_{k-1} + sqrt(1-phi^2) sd w_k."""
    if sd <= 0.0:
        return np.zeros((n, 3))
    phi = np.exp(-dt_s / tau_s)
    w = rng.standard_normal((n, 3)) * sd * np.sqrt(1.0 - phi * phi)
    w[0] = rng.standard_normal(3) * sd  # stationary start
    return lfilter([1.0], [1.0, -phi], w, axis=0)


def imu_errors(grade: ImuGrade, n: int, rate_hz: float, rng) -> ImuErrors:
    """Draw the bias and noise series of `grade` for n samples at `rate_hz`."""
    dt = 1.0 / rate_hz
    sign = lambda: rng.choice([-1.0, 1.0], size=3)  # noqa: E731
    g_bias = sign() * grade.gyro_bias_dph * DEG / 3600.0 + gauss_markov(
        n, grade.gyro_bias_gm_dph * DEG / 3600.0, grade.gyro_bias_tau_s, dt, rng
    )
    a_bias = sign() * grade.acc_bias_mg * 1e-3 * G0_MPS2 + gauss_markov(
        n, grade.acc_bias_gm_mg * 1e-3 * G0_MPS2, grade.acc_bias_tau_s, dt, rng
    )
    g_noise = rng.standard_normal((n, 3)) * grade.gyro_noise_dps * DEG
    a_noise = rng.standard_normal((n, 3)) * grade.acc_noise_mg * 1e-3 * G0_MPS2
    return ImuErrors(np.broadcast_to(g_bias, (n, 3)).copy(), np.broadcast_to(a_bias, (n, 3)).copy(), g_noise, a_noise)


def corrupt_imu(gyro_true_b_rps, acc_true_b_mps2, grade: ImuGrade, rate_hz: float, rng):
    """(gyro, acc, ImuErrors): ideal samples plus the bias and noise series of `grade`."""
    err = imu_errors(grade, gyro_true_b_rps.shape[0], rate_hz, rng)
    gyro = gyro_true_b_rps + err.gyro_bias_rps + err.gyro_noise_rps
    acc = acc_true_b_mps2 + err.acc_bias_mps2 + err.acc_noise_mps2
    return gyro, acc, err
