"""Filter health without truth: NIS against chi-square per measurement kind, rejections, the
chain's own `flag` column, and forward/backward disagreement (so a user can judge a run that has
no truth)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.report import metrics
from tpos_cli.report.rundir import RunData, ordered_solutions
from tpos_cli.report.truth import covered, median_gap_limit

SIGMA_NED = ("sigma_n", "sigma_e", "sigma_d")


@dataclass(frozen=True)
class Health:
    nis: pd.DataFrame  # solution, kind, n, n_accepted, n_rejected, dof, mean_nis, mean_lo, mean_hi, frac_above_95, consistent
    flags: pd.DataFrame  # solution, n_epochs, n_flagged
    disagreement: pd.DataFrame  # a, b, n, rms_m, max_m, n_flagged, frac_flagged


def nis_table(innovations: pd.DataFrame | None) -> pd.DataFrame:
    cols = ["solution", "kind"] + list(metrics.NisStats.__dataclass_fields__)
    if innovations is None or innovations.empty:
        return pd.DataFrame(columns=cols)
    rows = []
    inn = innovations.assign(kind=innovations["kind"].astype(str))
    for sol in ordered_solutions(inn["solution"]):
        d = inn[inn["solution"] == sol]
        for kind in dict.fromkeys(d["kind"]):
            k = d[d["kind"] == kind]
            st = metrics.nis_stats(k["nis"].to_numpy(float), k["dof"].to_numpy(float), k["accepted"].fillna(False).to_numpy(bool))
            rows.append({"solution": sol, "kind": kind, **st.as_dict()})
    return pd.DataFrame(rows, columns=cols)


def disagreement_table(trajectory: pd.DataFrame | None, pairs=(("forward", "backward"),)) -> pd.DataFrame:
    """Position disagreement between solution pairs at the first one's epochs (linear interpolation
    of the second, no extrapolation, no bridging of gaps)."""
    cols = ["a", "b", "n", "rms_m", "max_m", "n_flagged", "frac_flagged"]
    if trajectory is None:
        return pd.DataFrame(columns=cols)
    rows = []
    present = set(trajectory["solution"])
    for a, b in pairs:
        if a not in present or b not in present:
            continue
        da = trajectory[trajectory["solution"] == a].sort_values("t")
        db = trajectory[trajectory["solution"] == b].sort_values("t")
        origin = da[["lat", "lon", "h"]].to_numpy(float)[0]
        na = lla_to_ned(da[["lat", "lon", "h"]].to_numpy(float), origin)
        nb = lla_to_ned(db[["lat", "lon", "h"]].to_numpy(float), origin)
        ta, tb = da["t"].to_numpy(float), db["t"].to_numpy(float)
        _, _, ok = covered(tb, ta, median_gap_limit(tb))
        nb_at = np.full_like(na, np.nan)
        nb_at[ok] = np.column_stack([np.interp(ta[ok], tb, nb[:, i]) for i in range(3)])
        var = None
        if all(c in da and c in db for c in SIGMA_NED):
            sa = da[list(SIGMA_NED)].to_numpy(float)
            sb = db[list(SIGMA_NED)].to_numpy(float)
            sb_at = np.full_like(sa, np.nan)
            sb_at[ok] = np.column_stack([np.interp(ta[ok], tb, sb[:, i]) for i in range(3)])
            var = sa**2 + sb_at**2
        st = metrics.disagreement(na - nb_at, var)
        rows.append({"a": a, "b": b, **st.__dict__})
    return pd.DataFrame(rows, columns=cols)


def flag_table(trajectory: pd.DataFrame | None) -> pd.DataFrame:
    cols = ["solution", "n_epochs", "n_flagged"]
    if trajectory is None or "flag" not in trajectory.columns:
        return pd.DataFrame(columns=cols)
    rows = []
    for sol in ordered_solutions(trajectory["solution"]):
        f = trajectory.loc[trajectory["solution"] == sol, "flag"].fillna(False).to_numpy(bool)
        rows.append({"solution": sol, "n_epochs": int(f.size), "n_flagged": int(f.sum())})
    return pd.DataFrame(rows, columns=cols)


def filter_health(run: RunData) -> Health:
    return Health(nis_table(run.innovations), flag_table(run.trajectory), disagreement_table(run.trajectory))
