"""One position per target from its repeat shots: inverse-covariance weighting, 95 % ellipse.

A run writes one `targets.parquet` row per shot and solution, with the shot's north-east-up SDs
(`sigma_n`, `sigma_e`, `sigma_u`, m) and, where the chain provides them, the cross covariances
(`cov_ne_m2`, `cov_nu_m2`, `cov_eu_m2`, m^2, north-east-up). The shots of one target combine by
inverse-covariance weighting (generalised least squares of one point seen n times):

    W_i = P_i^-1,   P_ind = (sum W_i)^-1,   x = P_ind sum W_i x_i,   A_i = P_ind W_i (sum A_i = I)

P_ind is the covariance of x only if the shots' errors are independent. Shots of one session share
the attitude filter's slowly varying errors (heading bias, the reference calibration), and a
shared error does not average out: with fully correlated errors e_i = L_i z (L_i L_i^T = P_i) the
covariance of x is P_cor = M M^T, M = sum A_i L_i (P_i itself for equal shots). The shots' scatter
about x tells how much of their error is independent: f = chi2 / dof with chi2 = sum
(x_i - x)^T W_i (x_i - x) and dof = 3 (n - 1) (variance-component estimation). The combined
covariance is

    P = f P_ind                      for f >= 1 (the shots disagree more than their sigmas allow:
                                     the a-posteriori variance factor of a least-squares adjustment)
    P = (1 - f) P_cor + f P_ind      for f < 1 (the share f of each shot's variance that shows as
                                     scatter averages out, the rest is common to the shots)

so a combination never claims more than the shots show: agreeing shots keep a single shot's sigma.

The 95 % horizontal ellipse of a 2x2 north-east covariance C has semi-axes sqrt(chi2_2(0.95) l_k)
for the eigenvalues l_k of C (chi2_2(p) = -2 ln(1 - p), exactly), and its orientation is the azimuth of the major axis, degrees
clockwise from true north in [0, 180).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.frames.geodetic import enu_to_lla, lla_to_enu
from tpos_cli.report.format import utc_strings
from tpos_cli.report.projection import UtmZone, to_utm, zone_for

if TYPE_CHECKING:
    import pandas as pd

SIGMA_COLS = ("sigma_n", "sigma_e", "sigma_u")
CROSS_COLS = {"cov_ne_m2": (0, 1), "cov_nu_m2": (0, 2), "cov_eu_m2": (1, 2)}
ELLIPSE_PROB = 0.95


@dataclass(frozen=True)
class HorizontalEllipse:
    """Confidence ellipses of (N, 2, 2) north-east covariances: semi-axes, m; azimuth of the major
    axis, deg clockwise from north in [0, 180)."""

    semi_major_m: np.ndarray
    semi_minor_m: np.ndarray
    azimuth_deg: np.ndarray


def covariance_neu(df: pd.DataFrame) -> np.ndarray:
    """(N, 3, 3) north-east-up covariances, m^2, from the SD columns and any cross-covariance columns.

    Missing SD columns give NaN (no covariance known); missing cross columns count as zero.
    """
    n = len(df)
    sd = np.column_stack([df[c].to_numpy(float) if c in df.columns else np.full(n, np.nan) for c in SIGMA_COLS])
    cov = np.zeros((n, 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = sd**2
    for col, (i, j) in CROSS_COLS.items():
        if col in df.columns:
            c = np.nan_to_num(df[col].to_numpy(float))
            cov[:, i, j] = cov[:, j, i] = c
    return cov


def horizontal_ellipse(cov_ne_m2, prob: float = ELLIPSE_PROB) -> HorizontalEllipse:
    """The `prob` confidence ellipse of each (2, 2) north-east covariance (NaN where not finite)."""
    c = np.asarray(cov_ne_m2, dtype=float).reshape(-1, 2, 2)
    ok = np.all(np.isfinite(c), axis=(1, 2))
    k2 = -2.0 * np.log1p(-prob)  # squared Mahalanobis radius: chi-square with 2 dof is exponential, mean 2
    major = np.full(len(c), np.nan)
    minor = np.full(len(c), np.nan)
    az = np.full(len(c), np.nan)
    if ok.any():
        lam, vec = np.linalg.eigh(c[ok])  # ascending eigenvalues; columns are eigenvectors (n, e)
        lam = np.clip(lam, 0.0, None)
        major[ok] = np.sqrt(k2 * lam[:, 1])
        minor[ok] = np.sqrt(k2 * lam[:, 0])
        v = vec[:, :, 1]
        az[ok] = np.mod(np.degrees(np.arctan2(v[:, 1], v[:, 0])), 180.0)
    return HorizontalEllipse(major, minor, az)


def _combine_one(x_enu: np.ndarray, cov_neu: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Combined NEU offset (3,), its covariance (3, 3) and f = chi2 / dof (NaN for one shot); see
    the module docstring."""
    x = x_enu[:, [1, 0, 2]]  # east-north-up -> north-east-up, the covariance's order
    n = len(x)
    W = np.linalg.inv(cov_neu)
    P_ind = np.linalg.inv(W.sum(axis=0))
    xc = P_ind @ np.einsum("nij,nj->i", W, x)
    if n == 1:
        return xc, P_ind, float("nan")
    r = x - xc
    f = float(np.einsum("ni,nij,nj->", r, W, r)) / (3.0 * (n - 1))
    if f >= 1.0:
        return xc, f * P_ind, f
    M = np.einsum("ij,njk,nkl->il", P_ind, W, np.linalg.cholesky(cov_neu))  # sum A_i L_i
    return xc, (1.0 - f) * (M @ M.T) + f * P_ind, f


def combine_shots(shots: pd.DataFrame) -> pd.DataFrame:
    """One row per target id from the shots of ONE solution (targets.parquet rows).

    Returns columns: id, lat, lon, h, sigma_n, sigma_e, sigma_u, cov_ne_m2, cov_nu_m2, cov_eu_m2,
    ell95_major_m, ell95_minor_m, ell95_azimuth_deg, n_shots, shot_chi2_dof (chi2 / dof of the
    shots about the combined point; NaN for one shot), t_first, t_last (start of the first and end of
    the last shot, logger clock). Ids keep their first-appearance order. Shots without a position
    are left out (a target whose shots all failed gets NaN coordinates and n_shots = 0). Shots
    without covariance are averaged with equal weights and give NaN sigmas.
    """
    df = shots.reset_index(drop=True)
    lla = df[["lat", "lon", "h"]].to_numpy(float)
    cov = covariance_neu(df)
    t0 = df["t_start"].to_numpy(float) if "t_start" in df.columns else np.full(len(df), np.nan)
    t1 = df["t_end"].to_numpy(float) if "t_end" in df.columns else t0
    ids = df["id"].astype(str).to_numpy()
    rows = []
    for tid in dict.fromkeys(ids):
        m = np.flatnonzero((ids == tid) & np.all(np.isfinite(lla), axis=1))
        row = {"id": tid, "n_shots": int(m.size), "t_first": np.nan, "t_last": np.nan}
        if m.size == 0:
            rows.append(row)
            continue
        row["t_first"], row["t_last"] = float(np.nanmin(t0[m])), float(np.nanmax(t1[m]))
        origin = lla[m[0]]
        x_enu = lla_to_enu(lla[m], origin).reshape(-1, 3)
        c = cov[m]
        has_cov = np.all(np.isfinite(c)) and np.all(np.linalg.eigvalsh(c) > 0.0)
        if has_cov:
            xc, P, chi2_dof = _combine_one(x_enu, c)
        else:
            xc, P, chi2_dof = x_enu[:, [1, 0, 2]].mean(axis=0), np.full((3, 3), np.nan), float("nan")
        row.update(zip(("lat", "lon", "h"), enu_to_lla(xc[[1, 0, 2]], origin).reshape(3)))
        row.update(
            sigma_n=np.sqrt(P[0, 0]),
            sigma_e=np.sqrt(P[1, 1]),
            sigma_u=np.sqrt(P[2, 2]),
            cov_ne_m2=P[0, 1],
            cov_nu_m2=P[0, 2],
            cov_eu_m2=P[1, 2],
            shot_chi2_dof=chi2_dof,
        )
        rows.append(row)
    import pandas as pd  # here: only runs with targets combine shots (qc and export import this module for its ellipse)

    out = pd.DataFrame(rows, columns=["id", "lat", "lon", "h", *SIGMA_COLS, *CROSS_COLS, "n_shots", "shot_chi2_dof", "t_first", "t_last"])
    cov_ne = np.stack([np.column_stack([out.sigma_n**2, out.cov_ne_m2]), np.column_stack([out.cov_ne_m2, out.sigma_e**2])], axis=1)
    ell = horizontal_ellipse(cov_ne)
    out.insert(10, "ell95_major_m", ell.semi_major_m)
    out.insert(11, "ell95_minor_m", ell.semi_minor_m)
    out.insert(12, "ell95_azimuth_deg", ell.azimuth_deg)
    return out


TARGET_COLUMNS = (
    "id",
    "lat",
    "lon",
    "h",
    "sigma_n",
    "sigma_e",
    "sigma_u",
    "ell95_major_m",
    "ell95_minor_m",
    "ell95_azimuth_deg",
    "n_shots",
    "utm_zone",
    "utm_e_m",
    "utm_n_m",
    "cov_ne_m2",
    "cov_nu_m2",
    "cov_eu_m2",
    "shot_chi2_dof",
    "t_first",
    "t_last",
    "time_first_utc",
    "solution",
)


def combined_targets(run, solution: str, start_utc=None) -> tuple[pd.DataFrame, UtmZone]:
    """The combined targets of one solution of a run (`TARGET_COLUMNS`: `combine_shots` plus UTM
    in one zone for the job, the first shot's UTC and the solution), and that zone. Raises
    InvalidInputError when no target of the solution has a position."""
    shots = run.targets[run.targets["solution"] == solution]
    tab = combine_shots(shots)
    ok = np.isfinite(tab[["lat", "lon"]].to_numpy(float)).all(axis=1)
    if not ok.any():
        raise InvalidInputError(f"{run.path.name}/targets.parquet: solution '{solution}' has no target with a position")
    zone = zone_for(tab.loc[ok, "lat"], tab.loc[ok, "lon"])
    tab["utm_zone"] = zone.label
    tab["utm_e_m"], tab["utm_n_m"] = to_utm(tab["lat"], tab["lon"], zone)
    utc = utc_strings(tab["t_first"].to_numpy(float), start_utc, 0)
    tab["time_first_utc"] = np.where(np.isfinite(tab["t_first"]), utc, "") if utc is not None else ""
    tab["solution"] = solution
    return tab[list(TARGET_COLUMNS)], zone
