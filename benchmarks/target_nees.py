"""Target sigma honesty per IMU grade (issue 12): NEES of every target of simulated target sessions.

For each grade of `tpos simulate target` (paper, mems) and new seeds (not the tests'), a target
session (the contract's wall scenario, 10-15 m ranges) is simulated, written and processed with the
default `target-fkf` pipeline; each target's 3-D error e (NED, against the simulated truth) is
compared with its own covariance from `targets.parquet` (sigma_n/e/u and cov_ne/nu/eu): NEES = e^T P^-1 e.
Printed per grade and solution: the share of targets inside their 95 % ellipsoid (chi-square(3) 7.81;
goal >= 80 %) and the mean NEES per dof (goal within [0.3, 2]).

The simulated gyros carry their grade's constant scale/misalignment (`sim.target.GYRO_SCALE_PPM`); a third
argument sets its SD (ppm) for every grade instead (0: gyros without it, the sessions of main before session 9).

    python benchmarks/target_nees.py [seeds per grade, default 4] [grades, default paper,mems,tactical] [gyro scale ppm]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import chi2

from tpos_cli.frames import geodetic
from tpos_cli.pipeline import process_session
from tpos_cli.sim.sensor_errors import GRADES as OFFERED
from tpos_cli.sim.target import simulate_target
from tpos_cli.sim.writer import write_session

GRADES = tuple(sys.argv[2].split(",")) if len(sys.argv) > 2 else ("paper", "mems", "tactical")  # issue 12's grades
SOLUTIONS = ("fkf", "fkf_cal", "lf1", "lf2")
GYRO_SCALE_PPM = float(sys.argv[3]) if len(sys.argv) > 3 else None  # None: each grade's own figure


def target_covariance_ned(row) -> np.ndarray:
    """(3,3) NED covariance (m^2) of one `targets.parquet` row (up = -down)."""
    n, e, u = row.sigma_n, row.sigma_e, row.sigma_u
    return np.array([[n * n, row.cov_ne_m2, -row.cov_nu_m2],
                     [row.cov_ne_m2, e * e, -row.cov_eu_m2],
                     [-row.cov_nu_m2, -row.cov_eu_m2, u * u]])


def session_nees(grade: str, seed: int, tmp: Path) -> pd.DataFrame:
    """(solution, id, nees, err_m) of every target of one simulated session."""
    sim = simulate_target(90.0, seed=seed, grade=grade, gyro_scale_ppm=GYRO_SCALE_PPM)
    d = write_session(sim, tmp / f"{grade}_{seed}", overwrite=True)
    rs = process_session(d, "target-fkf", tmp / f"{grade}_{seed}_run")
    tg = pd.read_parquet(rs.run_dir / "targets.parquet")
    truth = dict(zip(sim.targets.ids, sim.targets.lla))
    out = []
    for r in tg[tg.id.isin(truth)].itertuples():
        e = geodetic.lla_to_ned(np.array([r.lat, r.lon, r.h]), truth[r.id])
        P = target_covariance_ned(r)
        out.append({"solution": r.solution, "id": r.id, "nees": float(e @ np.linalg.solve(P, e)),
                    "err_m": float(np.linalg.norm(e))})
    return pd.DataFrame(out)


def main(argv) -> int:
    n_seeds = int(argv[1]) if len(argv) > 1 else 4
    bound = chi2.ppf(0.95, 3)
    print(f"{'grade':9s} {'solution':9s} {'targets':>7s} {'in 95%':>7s} {'NEES/dof':>8s} {'mean err m':>10s}")
    with tempfile.TemporaryDirectory() as tmp:
        for grade in GRADES:
            if grade not in OFFERED:
                print(f"{grade:9s} (not a grade of `tpos simulate target`: {', '.join(OFFERED)})")
                continue
            df = pd.concat([session_nees(grade, 500 + s, Path(tmp)) for s in range(n_seeds)], ignore_index=True)
            for sol in SOLUTIONS:
                q = df[df.solution == sol]
                if q.empty:
                    continue
                print(f"{grade:9s} {sol:9s} {len(q):7d} {np.mean(q.nees < bound):7.2f} {q.nees.mean() / 3:8.2f} "
                      f"{q.err_m.mean():10.4f}")
    print("goal (issue 12): >= 0.80 inside the 95 % ellipsoid, mean NEES/dof within [0.3, 2]")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
