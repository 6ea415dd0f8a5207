"""Navigation solutions and their contract trajectory rows (`trajectory.parquet`, docs/log-format.md).

`Solution` is what every filter run and smoother yields at a set of IMU samples; `trajectory_table`
turns any solution (also an attitude-only one) into contract rows: `t, lat, lon, h, vn, ve, vd,
roll, pitch, yaw, solution`, the sigma columns it knows, then a chain's own columns. Attitude
sigmas come twice: `sigma_roll/pitch/yaw` are Euler-angle SDs (`frames.rotation.euler_sigmas_deg`),
singular at pitch +-90 deg (204 deg of yaw SD near it on a hand-held log whose attitude is good to
0.5 deg); `sigma_tilt_n`, `sigma_tilt_e`, `sigma_heading` are the SDs of the NED attitude error (the
rotation about north, east and down), and `att95_deg` bounds its total angle (`attitude_error_sigmas`),
defined at any attitude. `trajectory_columns`/`solution_columns` give the same rows as `io.columns.Columns`
(the drive chain: no pandas), `trajectory_table`/`solution_table` as a DataFrame.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tpos_cli.frames.rotation import dcm_to_euler, euler_sigmas_deg
from tpos_cli.io.columns import Columns

if TYPE_CHECKING:
    import pandas as pd


@dataclass(frozen=True)
class Solution:
    """A navigation solution at sample indices `idx` (K,): nav (K,6) [lat_rad, lon_rad, h_m, vn,
    ve, vd], C_nb (K,3,3), P9 (K,9,9) covariance of [pos NED m, vel NED m/s, phi rad]; bias
    (K, 6 + n_extra) or None: the IMU biases and the nominal of the extra states (`fusion.layout`)."""

    name: str
    idx: np.ndarray
    nav: np.ndarray
    C_nb: np.ndarray
    P9: np.ndarray
    bias: np.ndarray | None = None

    def rows(self, keep) -> Solution:
        """The solution at the rows where `keep` is True."""
        return Solution(self.name, self.idx[keep], self.nav[keep], self.C_nb[keep], self.P9[keep],
                        None if self.bias is None else self.bias[keep])

    def renamed(self, name: str) -> Solution:
        return Solution(name, self.idx, self.nav, self.C_nb, self.P9, self.bias)


def _sd(P: np.ndarray) -> np.ndarray:
    return np.sqrt(np.clip(np.diagonal(P, axis1=1, axis2=2), 0.0, None))


# chi2_3(0.95) (scipy.stats.chi2.ppf(0.95, 3)): the 95 % quantile of phi^T P^-1 phi for a Gaussian 3-vector
CHI2_3DOF_95 = 7.814727903251178


def attitude_error_sigmas(P_att_rad2) -> tuple[np.ndarray, np.ndarray]:
    """SDs (K, 3) in deg of the NED attitude error phi (rotation about north, east, down: the last is the
    heading's) and the 95 % bound (K,) in deg of its total angle |phi|: sqrt(CHI2_3DOF_95 lambda_max(P)).
    The bound holds with at least 95 %: phi^T phi <= lambda_max phi^T P^-1 phi, and
    P(phi^T P^-1 phi <= CHI2_3DOF_95) = 0.95; exactly 95 % when P is isotropic, more when one axis dominates
    (it is then that axis's 2.8-sigma). NaN where P is not finite."""
    P = np.asarray(P_att_rad2, dtype=float).reshape(-1, 3, 3)
    sd = np.degrees(_sd(P))
    ok = np.isfinite(P).all(axis=(1, 2))
    lam = np.full(P.shape[0], np.nan)
    if ok.any():
        lam[ok] = np.linalg.eigvalsh(0.5 * (P[ok] + np.swapaxes(P[ok], 1, 2)))[:, -1]
    return sd, np.degrees(np.sqrt(CHI2_3DOF_95 * np.clip(lam, 0.0, None)))


def trajectory_table(name: str, t, lla_deg, vel_ned_mps, C_nb, **kw) -> pd.DataFrame:
    """`trajectory_columns` as a DataFrame (the solution's name as a scalar: pandas repeats it)."""
    import pandas as pd

    return pd.DataFrame(_trajectory_cols(name, t, lla_deg, vel_ned_mps, C_nb, **kw))


def trajectory_columns(name: str, t, lla_deg, vel_ned_mps, C_nb, **kw) -> Columns:
    """Contract rows of one solution (`_trajectory_cols`) as `Columns`, 'solution' an object array."""
    cols = _trajectory_cols(name, t, lla_deg, vel_ned_mps, C_nb, **kw)
    k = cols["t"].size
    solution = np.empty(k, dtype=object)
    solution.fill(name)  # the one str object in every row (np.full converts it to a new str per row: 2.8 ms per hour of 10 Hz rows)
    cols["solution"] = solution
    return Columns(cols, k)


def _trajectory_cols(name: str, t, lla_deg, vel_ned_mps, C_nb, *, P_pos_ned_m2=None, P_vel_ned_m2ps2=None,
                     P_att_rad2=None, vertical_sigma: str = "sigma_d",
                     extra: Mapping[str, object] | None = None) -> dict:
    """Contract rows of one solution, column by column.

    t (K,) logger-clock s; lla_deg (K, 3) or (3,) (a static observer); vel_ned_mps (K, 3) or None
    (zeros); C_nb (K, 3, 3); optional covariances (K, 3, 3) of the NED position (m^2), velocity
    ((m/s)^2) and attitude error phi (rad^2) give `sigma_n, sigma_e, <vertical_sigma>`,
    `sigma_vn, sigma_ve, sigma_vd`, `sigma_roll, sigma_pitch, sigma_yaw` and `sigma_tilt_n,
    sigma_tilt_e, sigma_heading, att95_deg` (deg, `attitude_error_sigmas`); `extra` columns follow.
    """
    t = np.asarray(t, dtype=float)
    k = t.size
    lla = np.broadcast_to(np.asarray(lla_deg, dtype=float), (k, 3))
    vel = np.zeros((k, 3)) if vel_ned_mps is None else np.asarray(vel_ned_mps, dtype=float)
    r, p, y = dcm_to_euler(C_nb)
    cols: dict = {"t": t, "lat": lla[:, 0].copy(), "lon": lla[:, 1].copy(), "h": lla[:, 2].copy(),
                  "vn": vel[:, 0], "ve": vel[:, 1], "vd": vel[:, 2],
                  "roll": np.degrees(r), "pitch": np.degrees(p), "yaw": np.degrees(y),
                  "solution": name if k else np.full(k, name, dtype=object)}  # a scalar: pandas repeats it
    if P_pos_ned_m2 is not None:
        sd = _sd(P_pos_ned_m2)
        cols.update({"sigma_n": sd[:, 0], "sigma_e": sd[:, 1], vertical_sigma: sd[:, 2]})
    if P_vel_ned_m2ps2 is not None:
        sd = _sd(P_vel_ned_m2ps2)
        cols.update({"sigma_vn": sd[:, 0], "sigma_ve": sd[:, 1], "sigma_vd": sd[:, 2]})
    if P_att_rad2 is not None:
        se = euler_sigmas_deg(C_nb, P_att_rad2)
        cols.update({"sigma_roll": se[:, 0], "sigma_pitch": se[:, 1], "sigma_yaw": se[:, 2]})
        sd, att95 = attitude_error_sigmas(P_att_rad2)
        cols.update({"sigma_tilt_n": sd[:, 0], "sigma_tilt_e": sd[:, 1], "sigma_heading": sd[:, 2], "att95_deg": att95})
    cols.update(extra or {})
    return cols


def solution_table(sol: Solution, t_s, t0_s: float, *, vertical_sigma: str = "sigma_d",
                   extra: Mapping[str, object] | None = None, P_att_rad2=None) -> pd.DataFrame:
    """`trajectory_table` of a navigation `Solution`; t_s the run's sample times (session s), t0_s
    the session epoch on the logger clock; P_att_rad2 (K, 3, 3): the attitude-error covariance to
    use instead of sol.P9[:, 6:9, 6:9] (an attitude moved to other axes, without a copy of P9)."""
    args, cov = _solution_args(sol, t_s, t0_s, P_att_rad2)
    return trajectory_table(*args, **cov, vertical_sigma=vertical_sigma, extra=extra)


def solution_columns(sol: Solution, t_s, t0_s: float, *, vertical_sigma: str = "sigma_d",
                     extra: Mapping[str, object] | None = None, P_att_rad2=None) -> Columns:
    """`solution_table`'s rows as `Columns` (`trajectory_columns`)."""
    args, cov = _solution_args(sol, t_s, t0_s, P_att_rad2)
    return trajectory_columns(*args, **cov, vertical_sigma=vertical_sigma, extra=extra)


def _solution_args(sol: Solution, t_s, t0_s: float, P_att_rad2) -> tuple[tuple, dict]:
    """(name, t, lla_deg, vel, C_nb) and the covariances of `trajectory_table` for a `Solution`."""
    lla = np.column_stack([np.degrees(sol.nav[:, 0]), np.degrees(sol.nav[:, 1]), sol.nav[:, 2]])
    return ((sol.name, np.asarray(t_s)[sol.idx] + t0_s, lla, sol.nav[:, 3:6], sol.C_nb),
            {"P_pos_ned_m2": sol.P9[:, 0:3, 0:3], "P_vel_ned_m2ps2": sol.P9[:, 3:6, 3:6],
             "P_att_rad2": sol.P9[:, 6:9, 6:9] if P_att_rad2 is None else P_att_rad2})
