"""Benchmark of the drive-smooth pipeline (issue 4): speed, memory, accuracy, real logs.

    python benchmarks/drive.py                 # everything (about 15 minutes on 2 cores)
    python benchmarks/drive.py --only speed    # or: accuracy, calibration, real
    python benchmarks/drive.py --only accuracy --drives 40   # NEES inside outages to +-0.7

Speed: a simulated one-hour drive (100 Hz IMU, 1 Hz GPS) processed by `tpos process` in a
subprocess (stage timings from summary.json; its own peak RSS and CPU, `run_measured`), against a bare numba
reference loop of the same algebra (15-state predict at every IMU sample, 6-dim update at
1 Hz, forward storing the states, backward, per-sample blend).
Accuracy: simulated MEMS drives with one 30 s outage and with two 60 s outages; horizontal
RMS / max error inside and outside the outages per solution, and the forward filter's NEES.
Calibration: the real-car case over 32 drives, the lever-arm and clock-offset states' errors over
their SDs (8 drives cannot tell a state whose SD is off by a third); and on the real drive logs, a
clock error planted on real sensors (GPS stamped 0.3 s late): the change of the clock estimates
against the planted change, over their SDs.
Real logs: GPS withheld (`--mask-gps`) in three 30 s windows while moving; forward and
smoothed errors inside the windows against the session's truth, and how often the sigma columns
cover them (GPS error states: `fusion.gps_error`).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from numba import njit
from scipy.stats import chi2

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.helpers import mistakes as M  # noqa: E402
from tpos_cli.chains.drive_smooth import _block_at_end, in_vehicle_axes, process_drive  # noqa: E402
from tpos_cli.config import DriveSmoothParams  # noqa: E402
from tpos_cli.frames.geodetic import lla_to_ned  # noqa: E402
from tpos_cli.fusion.layout import Block  # noqa: E402
from tpos_cli.session import load_session  # noqa: E402
from tpos_cli.sim.drive import simulate_drive  # noqa: E402
from tpos_cli.timeoffset import vertical_rate_rps  # noqa: E402

REAL = REPO.parent / "shared" / "data" / "real"
SOLUTIONS = ("forward", "backward", "smoothed", "two_filter", "rts", "simplified")


# --------------------------------------------------------------------------- reference loop
@njit(cache=True)
def _ref_pass(n, F, Qd, H, R, z_every, xs, Ps_diag):
    x = np.zeros(15)
    P = np.eye(15)
    Phi = np.eye(15) + F
    for k in range(n):
        x = Phi @ x
        P = Phi @ P @ Phi.T + Qd
        if k % z_every == 0:
            S = H @ P @ H.T + R
            K = np.linalg.solve(S, H @ P).T
            x = x + K @ (np.ones(6) * 0.1 - H @ x)
            P = (np.eye(15) - K @ H) @ P
        xs[k] = x
        for i in range(15):
            Ps_diag[k, i] = P[i, i]


@njit(cache=True)
def _ref_blend(xf, pf, xb, pb, out):
    for k in range(xf.shape[0]):
        for i in range(15):
            w = pf[k, i] / (pf[k, i] + pb[k, i])
            out[k, i] = xf[k, i] + w * (xb[k, i] - xf[k, i])


def reference_loop(n_imu: int, imu_per_fix: int) -> float:
    """Seconds for the bare algebra over n_imu samples (forward, backward, blend)."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((15, 15))
    F = 1e-4 * (A - A.T) - 1e-5 * np.eye(15)  # stable: a rotation plus a slight decay
    Qd = np.eye(15) * 1e-6
    H = np.zeros((6, 15))
    H[:, :6] = np.eye(6)
    R = np.eye(6)
    xf, xb, out = np.empty((n_imu, 15)), np.empty((n_imu, 15)), np.empty((n_imu, 15))
    pf, pb = np.empty((n_imu, 15)), np.empty((n_imu, 15))
    _ref_pass(100, F, Qd, H, R, imu_per_fix, xf[:100], pf[:100])  # compile
    _ref_blend(xf[:10], pf[:10], xf[:10], pf[:10], out[:10])
    t0 = time.perf_counter()
    _ref_pass(n_imu, F, Qd, H, R, imu_per_fix, xf, pf)
    _ref_pass(n_imu, F, Qd, H, R, imu_per_fix, xb, pb)
    _ref_blend(xf, pf, xb, pb, out)
    return time.perf_counter() - t0


# --------------------------------------------------------------------------- speed
# A child that a large parent starts (subprocess: vfork + exec) takes the parent's peak RSS into its
# own ru_maxrss at exec (Linux keeps the larger), so a benchmark that simulated an hour of data
# first would report its own peak as the child's (663 MB where the child's was 580). The command is
# therefore started by a small launcher that forks it and reports its own accounting.
_LAUNCHER = """import json, os, sys, time
t0 = time.perf_counter()
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[2], sys.argv[2:])
_, status, ru = os.wait4(pid, 0)
with open(sys.argv[1], "w") as f:
    json.dump([os.waitstatus_to_exitcode(status), ru.ru_maxrss, ru.ru_utime + ru.ru_stime, time.perf_counter() - t0], f)
"""


# BLAS/OpenMP thread limits a benchmark shell sets and a user's shell does not: the timed child runs without
# them, as `tpos` runs for a user (the CLI sets what it needs itself, `cli.main`). With them set, the speed
# figures hid what a user's run paid on a busy machine: OpenBLAS threads spin-waiting after the conventions
# checks' dot products (drive hour at load 8, 2 cores: 4.3 s CPU instead of 1.8 s).
_USER_UNSET = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def child_env() -> dict:
    """A timed `tpos` child's environment: the repository's package with its bytecode cached, as an
    installed package has it (pip compiles it at install): PYTHONDONTWRITEBYTECODE, set in some
    shells, is dropped, so the untimed warm-up run writes __pycache__; so are `_USER_UNSET`."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    for k in ("PYTHONDONTWRITEBYTECODE", *_USER_UNSET):
        env.pop(k, None)
    return env


def run_measured(cmd, env, cwd, stdout=None) -> tuple[float, float, float]:
    """Run `cmd`; (its own peak RSS in MB, its CPU seconds, its wall seconds), from the kernel's
    accounting of that process alone. Raises CalledProcessError when it fails."""
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "usage.json"
        subprocess.run([sys.executable, "-c", _LAUNCHER, str(out), *map(str, cmd)], env=env, cwd=cwd, stdout=stdout, check=True)
        code, maxrss_kb, cpu_s, wall_s = json.loads(out.read_text())
    if code != 0:
        raise subprocess.CalledProcessError(code, cmd)
    return maxrss_kb / 1024.0, cpu_s, wall_s


def speed(duration_s: float = 3600.0, correlated_gps_m: float = 0.0) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        sim = simulate_drive(duration_s, seed=11, outages=((600.0, 30.0), (1800.0, 60.0), (3000.0, 60.0)),
                             gps_correlated_sigma_neu_m=correlated_gps_m, gps_correlated_tau_s=60.0)
        path = sim.write(Path(tmp) / "drive_1h")
        n = sim.imu.t_s.size
        print(f"simulated {duration_s:.0f} s drive ({n} IMU samples) in {time.perf_counter() - t0:.1f} s")
        del sim
        cmd = [sys.executable, "-m", "tpos_cli", "process", str(path), "-o", str(Path(tmp) / "run"), "-q"]
        env = child_env()
        run_measured(cmd, env, tmp)  # warm the numba cache and the bytecode (a compile's memory is not the run's)
        reference_loop(1000, 100)  # and compile (or load) the reference kernels before timing them
        runs = []  # (whole-process ratio, wall, summary, reference): each pair timed back to back (the machine is shared)
        cpu_ratios = []  # whole process CPU (imports included) / reference CPU: less disturbed by other load
        rss = []
        for _ in range(3):
            mb, cpu_s, wall = run_measured(cmd, env, tmp)
            rss.append(mb)
            summ = json.loads((Path(tmp) / "run" / "summary.json").read_text())
            p0 = time.process_time()
            ref = reference_loop(n, 100)
            ref_cpu = time.process_time() - p0
            runs.append((wall / ref, wall, summ, ref))
            cpu_ratios.append(cpu_s / ref_cpu)
        rss_mb = max(rss)
    runs.sort(key=lambda r: r[0])
    ratio, wall, summ, ref = runs[1]  # the median of three
    ts = summ["timings_s"]
    print("\nstage              wall s   share   samples/s   (the median run of three)")
    for k, v in ts.items():
        if k != "total" and v > 0:
            print(f"{k:16s} {v:8.3f}  {100 * v / ts['total']:5.1f} %  {n / v:10.3g}")
    print(f"{'total':16s} {ts['total']:8.3f}")
    helper = "smoothing_rts_beside" in ts  # tpos_cli.chains.context.spare_cpu: a CPU was free
    print("(the RTS smoother ran in a helper thread beside the backward run on a second CPU: the shares overlap; the wall "
          "ratio below uses that CPU, the CPU ratio counts both threads)" if helper else
          "(one thread: the process had one CPU or the load average left none free)")
    threaded = sum("smoothing_rts_beside" in r[2]["timings_s"] for r in runs)
    print(f"{'process (wall)':16s} {wall:8.3f}   (incl. interpreter start and imports)")
    print(f"reference loop   {ref:8.3f}")
    print(f"ratio process wall/reference (the whole `tpos process`, as issue 16 counts it; bytecode cached): {ratio:.2f} "
          f"(median of {', '.join(f'{r[0]:.2f}' for r in runs)}; goal <= 1.5, issue 16); in-process stages/reference "
          f"{ts['total'] / ref:.2f}")
    print(f"process CPU/reference CPU (whole process, imports included): {np.median(cpu_ratios):.2f} "
          f"(median of {', '.join(f'{r:.2f}' for r in sorted(cpu_ratios))})")
    print(f"peak memory (max RSS of the timed processes, each its own): {rss_mb:.0f} MB (goal <= 600, issue 16)")
    print(f"timed runs with a helper thread: {threaded} of {len(runs)}")
    ge = summ["results"]["alignment"].get("gps_error_states", {})
    gm_h = _gps_error_sd_h_m(ge)
    print("GPS error states: " + (f"sigma_h {gm_h} m, tau {ge.get('tau_s')} s (18-state filter)" if gm_h else
                                   "none (15-state filter)"))


def _gps_error_sd_h_m(ge: dict) -> float:
    """Horizontal SD (m) of the GPS error states a run carried, 0 without them: the record of
    `gps_error_model = "gauss_markov"` names it sigma_h_m, that of "stated_split" gm_h_m (0 when the
    split did not engage)."""
    return float(ge.get("sigma_h_m") or ge.get("gm_h_m") or 0.0)


# --------------------------------------------------------------------------- accuracy
def _errors(sim, sol):
    """(K, 9) errors [NED m, NED m/s, phi rad] of a solution against the exact truth."""
    return sim.truth.navigation_errors(sol.idx, sol.nav, sol.C_nb)


GPS_1HZ = {"gps_sigma_h_m": 1.5, "gps_sigma_v_m": 2.5, "gps_sigma_vel_mps": 0.05}  # the accuracy cases' receiver
# a car as real logs are (issue 11 item 7): RTK-like fixes, GPS stamped 0.08 s early, the IMU turned
# on the car, the antenna 0.8 m ahead and 0.5 m right of it, vibration; session.toml states none of it
REAL_CAR = {"gps_sigma_h_m": 0.02, "gps_sigma_v_m": 0.03, "gps_sigma_vel_mps": 0.02, "gps_clock_offset_s": 0.08,
            "mounting_rpy_deg": (0.0, 2.0, -4.0), "lever_arm_m": (0.8, 0.5, 0.0), "vibration_mg": 30.0}


def _unstated_lever_arm(path: Path) -> None:
    """session.toml's [gps] lever_arm_m set to zero, as a user who never measured it writes it."""
    M.set_toml(path, "gps", "lever_arm_m", "[0.0, 0.0, 0.0]")


# a receiver that logs no SDs and whose fixes wander (0.2 m fix to fix, 1 m common over minutes);
# its datasheet accuracy, the root sum square, is what the user sets as gps_sigma_h_m / _v_m
WANDERING = {"gps_sigma_h_m": 0.2, "gps_sigma_v_m": 0.3, "gps_correlated_sigma_neu_m": (1.0, 1.0, 1.5),
             "gps_correlated_tau_s": 300.0}
WANDERING_STATED = {"drive_smooth.gps_sigma_h_m": float(np.hypot(0.2, 1.0)), "drive_smooth.gps_sigma_v_m": float(np.hypot(0.3, 1.5))}


def _no_receiver_sds(path: Path) -> None:
    """The session's gps table without its sigma columns, as from a receiver that logs none."""
    f = next(path.glob("gps.*"))
    d = pd.read_parquet(f) if f.suffix == ".parquet" else pd.read_csv(f)
    d = d.drop(columns=[c for c in ("sigma_n", "sigma_e", "sigma_u") if c in d])
    if f.suffix == ".parquet":
        d.to_parquet(f, index=False)
    else:
        d.to_csv(f, index=False)


def accuracy_case(label, outages, seeds, duration_s=600.0, overrides=None, grade="mems", sim_kw=None,
                  receiver_sds: bool = True):
    """Errors and NEES of every solution against the exact truth over simulated drives. With a
    lever arm in `sim_kw` the session states none, so the solutions are at the antenna (the point
    the stated zero lever arm refers to) and the truth is moved there; attitude in the car's axes.
    `receiver_sds` False: the gps table loses its sigma columns (`_no_receiver_sds`)."""
    sim_kw = {**GPS_1HZ, **(sim_kw or {})}
    lever_v = np.asarray(sim_kw.get("lever_arm_m", (0.0, 0.0, 0.0)), dtype=float)
    rows = {n: {"in": [], "out": [], "max": [], "nees_in": []} for n in SOLUTIONS}
    nees_frac, nees_mean, sig = {"forward": [], "smoothed": []}, {"forward": [], "smoothed": []}, []
    nees_blocks = {"forward": [], "smoothed": []}
    lever_z, clock_z = [], []
    clock_s = float(sim_kw.get("gps_clock_offset_s", 0.0))
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            sim = simulate_drive(duration_s, seed=seed, outages=outages, grade=grade, **sim_kw)
            path = sim.write(Path(tmp) / f"s{seed}")
            if np.any(lever_v):
                _unstated_lever_arm(path)
            if not receiver_sds:
                _no_receiver_sds(path)
            session = load_session(path)
            # filter SDs: the simulated receiver's, the IMU's [imu] figures
            given = {k.split(".", 1)[1]: v for k, v in (overrides or {}).items()}
            p = DriveSmoothParams(**{"gps_sigma_vel_mps": sim_kw["gps_sigma_vel_mps"], "smoother": "rts", **given})
            res = process_drive(session, p, None, names=SOLUTIONS)
            g = res.info["gps_noise"]
            ge = res.info.get("gps_error_states", {})
            sig.append([g["sigma_pos_h_m"], g["sigma_pos_v_m"], g["sigma_vel_h_mps"], _gps_error_sd_h_m(ge),
                        ge.get("tau_s", 0.0)])
            if np.any(lever_v):
                est, sd = _block_at_end(res.forward, Block.LEVER, 2)  # unrounded (summary.json rounds to mm)
                if est is not None:
                    lever_z.append((np.asarray(est)[:2] - lever_v[:2]) / np.asarray(sd)[:2])
            if clock_s:
                est, sd = _block_at_end(res.forward, Block.CLOCK, 2)
                if est is not None:  # a fix stamped t holds at IMU time t + d: d is the simulated offset
                    clock_z.append((np.asarray(est) - clock_s) / np.asarray(sd))
            for name in SOLUTIONS:
                sol = in_vehicle_axes(res.solutions[name], res.C_vb, res.forward)
                e = _errors(sim, sol)
                if np.any(lever_v):  # the truth at the antenna: + C_nv l (the car's attitude)
                    e[:, :3] -= np.einsum("kij,j->ki", sim.truth.C_nb[sol.idx], lever_v)
                eh = np.hypot(e[:, 0], e[:, 1])
                t = sim.truth.t_s[sol.idx]
                m = np.zeros(t.size, bool)
                for a, b in sim.gps_outages_s:
                    m |= (t >= a) & (t < b)
                rows[name]["in"].append(eh[m] ** 2)
                rows[name]["out"].append(eh[~m & (t > 30.0)] ** 2)
                rows[name]["max"].append(eh[m].max())
                rows[name]["nees_in"].append(np.mean(np.einsum("ki,ki->k", e[m], np.linalg.solve(sol.P9[m], e[m][..., None])[..., 0])))
                if name in nees_mean:
                    k = t > 30.0
                    nees = np.einsum("ki,ki->k", e[k], np.linalg.solve(sol.P9[k], e[k][..., None])[..., 0])
                    nees_frac[name].append(np.mean(nees < chi2.ppf(0.95, 9)))
                    nees_mean[name].append(np.mean(nees))
                    nees_blocks[name].append([np.mean(np.einsum("ki,ki->k", e[k][:, b:b + 3], np.linalg.solve(
                        sol.P9[k][:, b:b + 3, b:b + 3], e[k][:, b:b + 3, None])[..., 0])) / 3 for b in (0, 3, 6)])
    print(f"\n{label}: {len(seeds)} drives of {duration_s:.0f} s, {grade} IMU, GPS {sim_kw['gps_sigma_h_m']:g} m / "
          f"{sim_kw['gps_sigma_v_m']:g} m / {sim_kw['gps_sigma_vel_mps']:g} m/s at 1 Hz"
          + "".join(f", {k} {v}" for k, v in sim_kw.items() if k not in GPS_1HZ))
    if lever_z:
        z = np.array(lever_z)
        band = np.sqrt(chi2.ppf([0.025, 0.975], len(z)) / len(z))
        print(f"lever-arm correction (forward, right) error / its SD at the forward run's end: mean "
              f"{np.round(z.mean(axis=0), 2)}, RMS {np.round(np.sqrt(np.mean(z**2, axis=0)), 2)} (95 % band of the RMS "
              f"of {len(z)} consistent draws [{band[0]:.2f}, {band[1]:.2f}]), max |z| {np.abs(z).max():.2f}; estimated in "
              f"{len(z)} of {len(seeds)} drives; per drive forward {np.round(z[:, 0], 2).tolist()}, right "
              f"{np.round(z[:, 1], 2).tolist()}")
    if clock_z:
        z = np.array(clock_z)
        band = np.sqrt(chi2.ppf([0.025, 0.975], len(z)) / len(z))
        print(f"IMU-GPS clock offset (positions, velocities) error / its SD at the forward run's end: mean "
              f"{np.round(z.mean(axis=0), 2)}, RMS {np.round(np.sqrt(np.mean(z**2, axis=0)), 2)} (95 % band "
              f"[{band[0]:.2f}, {band[1]:.2f}]), max |z| {np.abs(z).max():.2f}; estimated in {len(z)} of {len(seeds)} drives")
    sg = np.mean(sig, axis=0)
    print(f"GPS SDs estimated from the logs (mean over drives): position h {sg[0]:.3f} m, v {sg[1]:.3f} m, "
          f"velocity {sg[2]:.4f} m/s; GPS error states kept in {np.mean(np.array(sig)[:, 3] > 0) * 100:.0f}% "
          f"of the drives, sigma_h mean {sg[3]:.3f} m")
    print(f"{'solution':12s} {'in RMS m':>9s} {'in max m':>9s} {'/forward':>9s} {'out RMS m':>10s} {'NEES in':>8s}")
    f_in = np.sqrt(np.mean(np.concatenate(rows["forward"]["in"])))
    for name in SOLUTIONS:
        r = rows[name]
        rin = np.sqrt(np.mean(np.concatenate(r["in"])))
        rout = np.sqrt(np.mean(np.concatenate(r["out"])))
        print(f"{name:12s} {rin:9.3f} {max(r['max']):9.3f} {rin / f_in:9.3f} {rout:10.3f} {np.mean(r['nees_in']):8.2f}")
    for name in nees_mean:
        print(f"{name} NEES (9 states, after 30 s): mean {np.mean(nees_mean[name]):.2f} (dof 9; per dof "
              f"{np.mean(nees_mean[name]) / 9:.2f}, issue 12: 0.3-2), fraction under the 95% chi-square bound "
              f"{np.mean(nees_frac[name]):.3f} (issue 12: >= 0.80); per dof position / velocity / attitude "
              f"{' / '.join(f'{v:.2f}' for v in np.mean(nees_blocks[name], axis=0))}")
    print("NEES in: mean 9-state NEES inside the outages (dof 9; with this few drives its SD is up to "
          f"{np.sqrt(18.0 / len(seeds)):.1f}, the rows of one outage being nearly one draw)")


def calibration(drives: int = 32, overrides=None) -> None:
    """The calibration states (lever arm, clock offsets) of the real-car case over more drives than
    `accuracy`: with 8 draws the RMS of z has a 95 % band of [0.52, 1.48], too wide to tell a
    state whose SD is off by a third; 32 draws narrow it to [0.75, 1.24]."""
    accuracy_case("calibration states, the real-car case of `accuracy`", ((300.0, 30.0),),
                  seeds=tuple(range(1, drives + 1)), overrides=overrides, sim_kw=REAL_CAR)
    planted_clock(overrides)


PLANTED_LATE_S = 0.3


def planted_clock(overrides=None, logs=None) -> None:
    """Each real drive log processed as it is and with its GPS rows stamped PLANTED_LATE_S late
    (the user's late GPS clock of the brief): the clock estimates must move by -PLANTED_LATE_S (a
    position stamped t was taken at IMU time t + d), within their SDs. The log's own offset is
    unknown; the planted change is exact truth on real sensors, vibration and all."""
    from tpos_cli.pipeline import process_session

    print(f"\nclock offset planted on real logs: GPS stamped {PLANTED_LATE_S} s late; change of the estimates "
          f"(expected {-PLANTED_LATE_S:+.3f} s), z = (change - expected) / SD of the planted run's estimate")
    print(f"{'session':34s} {'own pos / vel s':>17s} {'change pos':>11s} {'z':>6s} {'change vel':>11s} {'z':>6s}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in logs or (PART1, "rtklibexplorer_walk_0827", "comma2k19_seg40", "navego_canada_enav"):
            if not (REAL / name).exists():
                print(f"{name}: not found under {REAL}")
                continue
            est = []
            for late in (0.0, PLANTED_LATE_S):
                sdir = Path(tmp) / f"{name}_{late:g}"
                M.plant(REAL / name, sdir, M.gps_late(late))
                run = process_session(sdir, run_dir=Path(tmp) / f"run_{name}_{late:g}", overrides=overrides or {})
                c = run.summary["results"]["gps_clock_offset"]
                est.append((c["estimate_s"], c["sigma_s"], c["velocity_estimate_s"], c["velocity_sigma_s"]))
            (p0, _, v0, _), (p1, sp1, v1, sv1) = est
            dp, dv = p1 - p0, v1 - v0
            print(f"{name:34s} {p0:+8.3f} / {v0:+6.3f} {dp:+11.3f} {(dp + PLANTED_LATE_S) / sp1:+6.1f} "
                  f"{dv:+11.3f} {(dv + PLANTED_LATE_S) / sv1:+6.1f}")


def accuracy(drives: int = 8, overrides=None) -> None:
    seeds = tuple(range(1, drives + 1))
    accuracy_case("one 30 s outage (paper 003's case)", ((300.0, 30.0),), seeds=seeds, overrides=overrides)
    accuracy_case("two 60 s outages", ((200.0, 60.0), (420.0, 60.0)), seeds=seeds, overrides=overrides)
    accuracy_case("one 30 s outage, tactical-grade IMU", ((300.0, 30.0),), seeds=seeds, overrides=overrides, grade="tactical")
    accuracy_case("one 30 s outage, a car as real logs are (RTK-like fixes; clock offset, mounting, lever arm unstated)",
                  ((300.0, 30.0),), seeds=seeds, overrides=overrides, sim_kw=REAL_CAR)
    accuracy_case("one 30 s outage, a receiver without SDs whose fixes wander (1 m over minutes; its stated accuracy set)",
                  ((300.0, 30.0),), seeds=seeds, overrides={**WANDERING_STATED, **(overrides or {})}, sim_kw=WANDERING,
                  receiver_sds=False)


# --------------------------------------------------------------------------- real logs
def moving_windows(truth_t, speed, n=3, length=30.0, min_speed=0.3, t_start=40.0):
    """n windows of `length` s where the truth speed stays above min_speed, spread over the log."""
    ok = speed > min_speed
    cands = []
    t = t_start + truth_t[0]
    while t + length < truth_t[-1] - 10.0:
        m = (truth_t >= t) & (truth_t <= t + length)
        if m.sum() > 3 and ok[m].mean() > 0.9:
            cands.append(t)
            t += length + 20.0
        else:
            t += 2.0
    if len(cands) > n:
        cands = [cands[i] for i in np.linspace(0, len(cands) - 1, n).round().astype(int)]
    return [(c, c + length) for c in cands]


def _yaw_rms_deg(d, truth, after_s: float = -np.inf, skip=None):
    """(RMS, median) of solution yaw - truth yaw, deg, over truth rows after `after_s` and not in
    `skip`: a median far from 0 with a small spread is a fixed mounting rotation between the IMU
    axes and the truth's body axes, not a filter error."""
    if "yaw" not in truth.columns or truth["yaw"].isna().all():
        return float("nan"), float("nan")
    y = np.degrees(np.unwrap(np.radians(d["yaw"].to_numpy())))
    dy = (np.interp(truth["t"], d["t"], y) - truth["yaw"].to_numpy() + 180.0) % 360.0 - 180.0
    dy = dy[(truth["t"].to_numpy() > after_s) & (True if skip is None else ~skip)]
    return float(np.sqrt(np.nanmean(dy**2))), float(np.nanmedian(dy))


TRUTH_STEP_DEG = 5.0  # a truth yaw change this far from the gyro's over one truth interval (0.45 s on
# navego) is the truth's own jump: an uncalibrated MEMS gyro's bias (<= 1 deg/s) explains < 0.5 deg of it


def _truth_yaw_steps(sdir: Path, truth: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(step times, spike rows) of the truth's yaw against the IMU's own rotation about the local
    vertical (`timeoffset.vertical_rate_rps`, integrated over each truth interval): an interval
    whose truth yaw change is more than TRUTH_STEP_DEG from the gyro's is a jump of the reference
    (a visual or GNSS fix pulling its pose), not motion. Two such intervals in a row that cancel
    make one truth row a spike (a bool mask over truth rows); the others are steps (the times
    that end them, s). `real_logs` scores yaw also after the last step, without the spikes."""
    n = len(truth)
    if "yaw" not in truth.columns or truth["yaw"].isna().all():
        return np.zeros(0), np.zeros(n, bool)
    s = load_session(sdir, with_truth=False)
    rate = vertical_rate_rps(s.imu.t_s, s.imu.gyro_b_rps, s.imu.acc_b_mps2)
    t_imu = s.imu.t_s + s.t0_s
    turned = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t_imu))])
    tt, yaw = truth["t"].to_numpy(), np.radians(truth["yaw"].to_numpy())
    wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    off = np.degrees(wrap(wrap(np.diff(yaw)) - np.diff(np.interp(tt, t_imu, turned))))
    big = (np.abs(off) > TRUTH_STEP_DEG) & (tt[1:] > t_imu[0]) & (tt[:-1] < t_imu[-1])
    spike = np.zeros(n, bool)
    for i in np.flatnonzero(big[:-1] & big[1:]):
        if abs(off[i] + off[i + 1]) < TRUTH_STEP_DEG and not spike[i]:
            spike[i + 1] = True
            big[i] = big[i + 1] = False
    return tt[1:][big], spike


# real logs whose truth is the same receiver's RTK solution (the shared data README: "the same RTK
# solution"): stamped by the receiver's clock, at the antenna. The others' truth is the contract's:
# the IMU point on the logger's clock, where tpos's output is scored (`truth_clock_overrides`)
TRUTH_OF_THE_RECEIVER = ("rtklibexplorer_drive_0708_part1", "rtklibexplorer_walk_0827")


def truth_clock_overrides(name: str) -> dict:
    """Settings that put the output on the clock of the log's truth: the logger's for a truth as
    the contract has it (the output moves to the GPS clock only when the receiver is the truth)."""
    return {} if name in TRUTH_OF_THE_RECEIVER else {"drive_smooth.clock_apply_sd": 1e9}


PART1 = "rtklibexplorer_drive_0708_part1"
PART1_WINDOWS_S = ((100.0, 130.0), (250.0, 280.0))  # the issue's windows, s after the first IMU sample
# issue 11 goals on the car drive, GPS withheld in 30 s windows while moving
GOALS = {"forward_in_m": 10.0, "smoothed_in_m": 0.8, "smoothed_out_m": 0.10, "flagged": 0.10}


def _windows(name: str, sdir: Path, truth: pd.DataFrame) -> list:
    if name == PART1:
        t_imu0 = float(pq.read_table(sdir / "imu.parquet", columns=["t"]).column("t")[0].as_py())
        return [(t_imu0 + a, t_imu0 + b) for a, b in PART1_WINDOWS_S]
    if {"vn", "ve"} <= set(truth.columns):
        sp = np.hypot(truth["vn"], truth["ve"]).to_numpy()
    else:  # speed from the truth positions
        ned = lla_to_ned(truth[["lat", "lon", "h"]].to_numpy(), truth[["lat", "lon", "h"]].to_numpy()[0])
        sp = np.hypot(*np.gradient(ned[:, :2], truth["t"].to_numpy(), axis=0).T)
    short = truth["t"].iloc[-1] - truth["t"].iloc[0] < 120.0
    return moving_windows(truth["t"].to_numpy(), sp, t_start=5.0 if short else 40.0, length=15.0 if short else 30.0)


def real_logs(overrides: dict | None = None, logs: tuple | None = None) -> None:
    """The default pipeline on the real drive logs, GPS withheld in 30 s windows while moving, with
    the motion constraints on (default `platform = "auto"`) and off (`platform = "none"`), and on a
    log with odometry also without it (`auto-odo`)."""
    from tpos_cli.pipeline import process_session

    print("\nreal logs, default drive-smooth pipeline, GPS withheld in 30 s windows while moving")
    print("in 2sig / out 2sig: fraction of the masked / other epochs (after the first 20 s) with |error| < 2 sigma per "
          "horizontal axis (0.95 when consistent; out 2sig only where the truth is not the fixes themselves: a solution's "
          "residual to its own fix has variance R - P, not P)")
    print(f"scored on the clock of each log's truth: the receiver's for {', '.join(TRUTH_OF_THE_RECEIVER)} (the output "
          "moves to the GPS clock as by default), the logger's for the others (clock_apply_sd = 1e9: the output stays there)")
    print(f"issue 11 goals on {PART1}: forward in <= {GOALS['forward_in_m']} m, smoothed in <= {GOALS['smoothed_in_m']} m, "
          f"smoothed out <= {GOALS['smoothed_out_m']} m, flagged <= {100 * GOALS['flagged']:.0f} %")
    print(f"{'session':26s} {'platform':9s} {'solution':9s} {'in RMS m':>9s} {'in max m':>9s} {'in 2sig':>8s} {'out RMS m':>10s} "
          f"{'out 2sig':>8s} {'yaw RMS deg':>12s} {'yaw median':>10s} {'NaN':>4s}")
    for name in logs or (PART1, "navego_canada_enav", "rtklibexplorer_walk_0827", "comma2k19_seg40"):
        sdir = REAL / name
        if not sdir.exists():
            print(f"{name}: not found under {REAL}")
            continue
        truth = pd.read_csv(sdir / "truth.csv")
        wins = _windows(name, sdir, truth)
        tt = truth["t"].to_numpy()
        ref = truth[["lat", "lon", "h"]].to_numpy()
        inside = np.zeros(tt.size, bool)
        for a, b in wins:
            inside |= (tt >= a) & (tt < b)
        steps, spikes = _truth_yaw_steps(sdir, truth)
        yaw_after = {}
        variants = [("none", {"drive_smooth.platform": "none"}), ("auto", {})]
        if (sdir / "odometry.csv").exists() or (sdir / "odometry.parquet").exists():
            variants.insert(1, ("auto-odo", {"drive_smooth.use_odometry": False}))  # constraints, odometry off
        for platform, ov in variants:
            with tempfile.TemporaryDirectory() as tmp:
                out = process_session(sdir, "drive-smooth", Path(tmp) / "run", mask_gps_windows=wins,
                                      overrides={"drive_smooth.output_rate_hz": 0.0, **truth_clock_overrides(name), **ov,
                                                 **(overrides or {})})
                traj = pd.read_parquet(out.run_dir / "trajectory.parquet")
                summ = json.loads((out.run_dir / "summary.json").read_text())
            label = f"{name[:26]}"
            for sol in ("forward", "backward", "smoothed"):
                d = traj[traj["solution"] == sol]
                nan = int(d[["lat", "lon", "h"]].isna().any(axis=1).sum())
                lla = np.column_stack([np.interp(tt, d["t"], d[c]) for c in ("lat", "lon", "h")])
                e = lla_to_ned(lla, ref[0]) - lla_to_ned(ref, ref[0])
                eh = np.hypot(e[:, 0], e[:, 1])
                sd = np.column_stack([np.interp(tt, d["t"], d[c]) for c in ("sigma_n", "sigma_e")])
                cover = np.mean(np.abs(e[inside, :2]) < 2.0 * sd[inside]) if inside.any() else float("nan")
                rin = np.sqrt(np.mean(eh[inside] ** 2)) if inside.any() else float("nan")
                mx = eh[inside].max() if inside.any() else float("nan")
                out_ = ~inside & (tt > tt[0] + 20)
                rout = np.sqrt(np.mean(eh[out_] ** 2))
                cover_out = (np.mean(np.abs(e[out_, :2]) < 2.0 * sd[out_]) if name not in TRUTH_OF_THE_RECEIVER
                             else float("nan"))
                yr, ym = _yaw_rms_deg(d, truth)
                if steps.size or spikes.any():
                    yaw_after[sol] = _yaw_rms_deg(d, truth, steps[-1] if steps.size else -np.inf, spikes)[0]
                print(f"{label:26s} {platform:9s} {sol:9s} {rin:9.2f} {mx:9.2f} {cover:8.2f} {rout:10.3f} {cover_out:8.2f} "
                      f"{yr:12.1f} {ym:10.1f} {nan:4d}")
                label = ""
            if yaw_after:
                print(f"{'':26s} truth yaw jumps the gyro does not see (> {TRUTH_STEP_DEG:.0f} deg in one truth interval): "
                      f"steps at {[round(float(x - tt[0]), 1) for x in steps]} s, one-row spikes at "
                      f"{[round(float(x - tt[0]), 1) for x in tt[spikes]]} s; yaw RMS after the last step, spikes left out: "
                      + ", ".join(f"{k} {v:.1f}" for k, v in yaw_after.items()) + " deg")
            res = summ["results"]
            c = res.get("constraints", {})
            mnt = c.get("mounting", {})
            print(f"{'':26s} flagged {100 * res['flagged_fraction']:.1f} %; verdict {summ['quality']['verdict']}; platform "
                  f"{c.get('platform')} ({c.get('decided_by')}); stops {c.get('stops')} ({c.get('stopped_s')} s); mounting "
                  f"{mnt.get('mounting_rpy_deg')} ({mnt.get('source')})")
            la, clk = res.get("lever_arm") or {}, res.get("gps_clock_offset") or {}
            print(f"{'':28s}lever arm: {la.get('decided_by')}"
                  + (f"; correction fwd/right {la['correction_forward_right_m']} +- {la['sigma_forward_right_m']} m"
                     if la.get("estimated") else "")
                  + (f"; clock offset {clk['estimate_s']} +- {clk['sigma_s']} s (output on the {clk['output_clock']} clock)"
                     if clk else ""))
            for kind, ck in res["forward_nis_check"].items():
                if ck is not None:
                    print(f"{'':28s}forward {kind} NIS {ck['mean']:.2f}, dof {ck['dof']:.0f} [{ck['band95'][0]:.2f}, "
                          f"{ck['band95'][1]:.2f}], {ck['fixes']} applied, {res['gps_rejected'][f'forward_{kind}']} rejected"
                          + "".join(f"; {name} {r['mean']:.2f} [{r['band95'][0]:.2f}, {r['band95'][1]:.2f}] of {r['fixes']}"
                                    for name, r in (ck.get("by_regime") or {}).items()))
            for kind, ck in c.get("forward", {}).items():
                if isinstance(ck, dict) and "rows" in ck and ck["nis"] is not None:
                    print(f"{'':28s}forward {kind}: {ck['rows']} rows, {ck['rejected']} rejected, NIS {ck['nis']['mean']:.2f} "
                          f"(dof {ck['nis']['dof']:.0f})")
        print(f"{'':26s} windows (s from the first truth row): "
              f"{[(round(float(a - tt[0]), 1), round(float(b - tt[0]), 1)) for a, b in wins]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("speed", "accuracy", "calibration", "real"))
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--correlated-gps-m", type=float, default=0.0,
                    help="speed: add a Gauss-Markov GPS error of this SD (tau 60 s), so the 18-state filter runs")
    ap.add_argument("--drives", type=int, default=8, help="simulated drives per accuracy case (40: NEES to +-0.7)")
    ap.add_argument("--calibration-drives", type=int, default=32, help="simulated drives of the calibration check")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="accuracy, real: a drive_smooth setting for every run (TOML value), e.g. --set cov_step_s=0.2")
    ap.add_argument("--logs", default=None, help="real: comma-separated session names (default: the four drive logs)")
    a = ap.parse_args()
    overrides = {f"drive_smooth.{k}": tomllib.loads(f"v = {v}")["v"] for k, v in (kv.split("=", 1) for kv in a.set)}
    if a.only in (None, "speed"):
        speed(a.duration_s, a.correlated_gps_m)
    if a.only in (None, "accuracy"):
        accuracy(a.drives, overrides)
    if a.only in (None, "calibration"):
        calibration(a.calibration_drives, overrides)
    if a.only in (None, "real"):
        real_logs(overrides, tuple(a.logs.split(",")) if a.logs else None)


if __name__ == "__main__":
    main()
