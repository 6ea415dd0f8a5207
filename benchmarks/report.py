"""Benchmark of `tpos report` (issues 14 and 16): speed of the report of hour-long logs, each
stage's share, and a check that its accuracy figures are those of a plain full-rate computation.

    python benchmarks/report.py              # drive hour and target hour (about 6-10 minutes on 2 shared cores)
    python benchmarks/report.py --only drive # or: target

Drive: a simulated one-hour drive (100 Hz IMU, 1 Hz GPS, three outages) is processed, then
`tpos report` runs on it in a subprocess, as a user types it (interpreter start, imports, the
session load and input check, accuracy against truth, the PDF). Its time is divided by the bare
numba reference loop of `benchmarks/drive.py` (goal <= 1.5), the two timed alternately in the same
run, three times each: the median wall time and the median CPU time (user + system of the process;
steadier than wall time on a machine other jobs share) of each.
Target: a simulated one-hour target log (100 Hz IMU, shots every few seconds); `tpos process` and
`tpos report` of it timed alternately, three times each; the report's median time divided by the
process's (goal <= 2).
Stages: one in-process report after a first one (which pays the lazy imports and font loading);
CPU seconds and share of each stage (`tpos_cli.report.stages`): loading, accuracy tables, each
figure, PDF writing. The CLI's interpreter start and imports are timed on their own.
Bytecode: the timed `tpos` children run as an installed package does, with the package's bytecode
cached (pip compiles it at install; an editable install writes __pycache__ on first import):
PYTHONDONTWRITEBYTECODE, set in some shells, is dropped from their environment, so the untimed
warm-up run writes it. Each ratio is also printed without bytecode: the package imported from a copy
of its source without __pycache__ and PYTHONDONTWRITEBYTECODE=1, so that every run compiles it (the
libraries keep their installed bytecode either way).
Accuracy: every solution's errors recomputed here at full rate in the plainest way (truth at the
solution's epochs, pymap3d's geodetic2ned about the truth point, wrapped Euler differences) and
compared with the report's accuracy.parquet (segment `all`): the largest relative difference is
printed, and must stay at rounding level.
"""

from __future__ import annotations

import argparse
import gc
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

RUNS = 3
ACCURACY_RTOL = 1e-9  # rounding level: the report and this check sum the same numbers in another order


def _child_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _env(src: Path | None = None) -> dict:
    """A timed child's environment: the package with its bytecode cached (PYTHONDONTWRITEBYTECODE dropped),
    or, given `src` (`_source_copy`), from that copy compiled on every run (module docstring)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    if src is None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    else:
        env.update(PYTHONPATH=str(src), PYTHONDONTWRITEBYTECODE="1")
    return env


def _source_copy(tmp: Path) -> Path:
    """The package's source (and its pipelines, as installed) copied without bytecode or numba caches
    (once per `tmp`: the drive and target parts share it)."""
    if (tmp / "src" / "tpos_cli").exists():
        return tmp / "src"
    caches = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc")
    shutil.copytree(REPO / "tpos_cli", tmp / "src" / "tpos_cli", ignore=caches)
    shutil.copytree(REPO / "pipelines", tmp / "src" / "tpos_cli" / "pipelines", ignore=caches)
    return tmp / "src"


def _run(cmd, cwd, env: dict | None = None) -> tuple[float, float, str]:
    """Wall and CPU seconds (user + system) of one subprocess, and its stdout."""
    env = _env() if env is None else env
    c0, t0 = _child_cpu_s(), time.perf_counter()
    p = subprocess.run(cmd, check=True, env=env, cwd=cwd, capture_output=True, text=True)
    return time.perf_counter() - t0, _child_cpu_s() - c0, p.stdout


def _median(xs) -> float:
    return statistics.median(xs)


def _pages(out: str) -> str:
    m = re.search(r"(\d+) PDF pages", out)
    return m.group(1) if m else "?"


# ------------------------------------------------------------------------------------- stages


def _stage_group(name: str) -> str:
    if name.startswith("load:"):
        return "loading"
    if name.startswith("figure:") or name.startswith("allan"):
        return "figures"
    return name


def stages_in_fresh_process(run_dir: Path) -> None:
    """`stages` in a process of its own, as `tpos report` runs: this one holds the simulation's and the
    other runs' objects, which the cyclic garbage collector would scan during the report's stages."""
    _, _, out = _run([sys.executable, str(Path(__file__).resolve()), "--stages", str(run_dir)], run_dir.parent)
    print(out, end="")


def stages(run_dir: Path) -> None:
    """CPU seconds and share of each stage of a warm in-process report (the fastest of three)."""
    from tpos_cli.report.build import make_report
    from tpos_cli.report.stages import StageClock

    gc_s = [0.0, 0.0]  # CPU seconds in cyclic garbage collections, start of the current one

    def on_gc(phase, _info):
        if phase == "start":
            gc_s[1] = time.process_time()
        else:
            gc_s[0] += time.process_time() - gc_s[1]

    make_report(run_dir)  # lazy imports, fonts
    runs = []
    gc.callbacks.append(on_gc)
    for _ in range(RUNS):  # the fastest of three: the least disturbed by other jobs
        clock = StageClock()
        gc_s[0] = 0.0
        t0 = time.process_time()
        make_report(run_dir, clock=clock)
        runs.append((time.process_time() - t0, clock, gc_s[0]))
    gc.callbacks.remove(on_gc)
    total, clock, in_gc = min(runs, key=lambda r: r[0])
    groups: dict[str, float] = {}
    for name, s in clock.cpu_s.items():
        groups[_stage_group(name)] = groups.get(_stage_group(name), 0.0) + s
    print(f"  stages of a warm in-process report (fastest of {RUNS}), CPU {total:.2f} s:")
    for g, s in groups.items():
        print(f"    {g:28s} {s:6.3f} s {100 * s / total:5.1f} %")
        if g == "figures":
            for name, f in clock.cpu_s.items():
                if _stage_group(name) == "figures" and f >= 0.0005:
                    label = name.removeprefix("figure: ")
                    print(f"      {label:26s} {f:6.3f} s {100 * f / total:5.1f} %")
    rest = total - sum(groups.values())
    print(f"    {'other':28s} {rest:6.3f} s {100 * rest / total:5.1f} %")
    print(f"    (cyclic garbage collection {in_gc:.3f} s, {100 * in_gc / total:.1f} %, inside whichever stages triggered it)")


# ----------------------------------------------------------------------------------- accuracy


def _truth_at(session, t: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Truth lla and roll/pitch/yaw (deg) at logger-clock epochs `t`: the truth row of the same
    stamp (the simulator writes the solutions' epochs on the truth's grid), NaN elsewhere."""
    tr = session.truth
    tt = np.asarray(tr.t_s, dtype=float) + session.t0_s
    j = np.clip(np.searchsorted(tt, t), 0, tt.size - 1)
    j = np.where(np.abs(tt[np.maximum(j - 1, 0)] - t) < np.abs(tt[j] - t), np.maximum(j - 1, 0), j)
    same = np.abs(tt[j] - t) <= 1e-6
    lla = np.where(same[:, None], np.asarray(tr.lla, dtype=float)[j], np.nan)
    rpy = None
    if tr.rpy_deg is not None and np.isfinite(tr.rpy_deg).any():
        rpy = np.where(same[:, None], np.asarray(tr.rpy_deg, dtype=float)[j], np.nan)
    return lla, rpy


def accuracy_check(run_dir: Path, session_dir: Path) -> None:
    """The report's accuracy.parquet (segment `all`) against a plain full-rate recomputation."""
    from tpos_cli.session import load_session

    session = load_session(session_dir)
    traj = pd.read_parquet(run_dir / "trajectory.parquet")
    acc = pd.read_parquet(run_dir / "accuracy.parquet")
    acc = acc[(acc["segment"] == "all") & (acc["target"] == "")].set_index(["solution", "quantity"])
    worst, where, n_cells = 0.0, "", 0
    for sol, d in traj.groupby("solution", sort=False, observed=True):
        t = d["t"].to_numpy(float)
        lla, rpy = _truth_at(session, t)
        n, e, dn = pymap3d.geodetic2ned(d["lat"].to_numpy(), d["lon"].to_numpy(), d["h"].to_numpy(), lla[:, 0], lla[:, 1], lla[:, 2])
        errs = {"pos_h_m": np.hypot(n, e), "pos_v_m": -dn, "pos_3d_m": np.sqrt(n * n + e * e + dn * dn)}
        if rpy is not None:
            for k, q in enumerate(("roll_deg", "pitch_deg", "yaw_deg")):
                errs[q] = (d[["roll", "pitch", "yaw"]].to_numpy(float)[:, k] - rpy[:, k] + 180.0) % 360.0 - 180.0
        for q, x in errs.items():
            x = x[np.isfinite(x)]
            mine = {"n": x.size, "rms": np.sqrt(np.mean(x * x)), "max_abs": np.max(np.abs(x)), "p95": np.percentile(np.abs(x), 95)}
            for stat, v in mine.items():
                r = float(acc.loc[(str(sol), q), stat])
                rel = abs(r - v) / max(abs(v), 1e-12)
                n_cells += 1
                if rel > worst:
                    worst, where = rel, f"{sol} {q} {stat}: report {r:.12g}, full-rate {v:.12g}"
    verdict = "unchanged" if worst <= ACCURACY_RTOL else "DIFFERENT"
    print(f"  accuracy figures {verdict}: {n_cells} cells (n, RMS, max, p95 per solution and quantity) against a plain full-rate")
    print(f"    recomputation, largest relative difference {worst:.1e}" + (f" ({where})" if where else "") + f" (limit {ACCURACY_RTOL:g})")


# ---------------------------------------------------------------------------------------- runs


def drive(tmp: Path) -> None:
    from drive import reference_loop

    from tpos_cli.sim.drive import simulate_drive

    sim = simulate_drive(3600.0, seed=11, outages=((600.0, 30.0), (1800.0, 60.0), (3000.0, 60.0)))
    session = sim.write(tmp / "drive_1h")
    n = sim.imu.t_s.size
    del sim
    run = tmp / "drive_run"
    _run([sys.executable, "-m", "tpos_cli", "process", str(session), "-o", str(run), "-q"], tmp)
    cmd = [sys.executable, "-m", "tpos_cli", "report", str(run)]
    envs = {"": _env(), " (no bytecode)": _env(_source_copy(tmp))}
    for env in envs.values():
        _run(cmd, tmp, env)  # warm the file cache; with bytecode: write it
    reference_loop(n, 100)  # compile
    rep_wall, rep_cpu = {k: [] for k in envs}, {k: [] for k in envs}
    ref_wall, ref_cpu = [], []
    out = ""
    for _ in range(RUNS):  # alternately: all see the same load
        for k, env in envs.items():
            w, c, out = _run(cmd, tmp, env)
            rep_wall[k].append(w)
            rep_cpu[k].append(c)
        c0 = time.process_time()
        ref_wall.append(reference_loop(n, 100))
        ref_cpu.append(time.process_time() - c0)
    rw, rc = _median(ref_wall), _median(ref_cpu)
    w, c = _median(rep_wall[""]), _median(rep_cpu[""])
    print(f"drive hour ({n} IMU samples), {_pages(out)} pages; medians of {RUNS}; tpos_cli bytecode cached unless said:")
    for k in envs:
        print(f"  tpos report{k:15s} wall {_median(rep_wall[k]):5.2f} s, CPU {_median(rep_cpu[k]):5.2f} s")
    print(f"  reference{'':17s} wall {rw:5.2f} s, CPU {rc:5.2f} s")
    for k in envs:
        print(f"  ratio report/reference{k}: wall {_median(rep_wall[k]) / rw:.2f}, CPU {_median(rep_cpu[k]) / rc:.2f} (goal <= 1.5)")
    imports = "import tpos_cli.cli, tpos_cli.report.build, tpos_cli.report.pdf, matplotlib.backends.backend_pdf"
    imp = [_run([sys.executable, "-c", imports], tmp) for _ in range(RUNS)]
    iw, ic = _median(x[0] for x in imp), _median(x[1] for x in imp)
    print(f"  interpreter start and imports alone: wall {iw:.2f} s, CPU {ic:.2f} s ({ic / c:.0%} of the report's CPU)")
    stages_in_fresh_process(run)
    accuracy_check(run, session)


def target(tmp: Path) -> None:
    from tpos_cli.sim.target import simulate_target
    from tpos_cli.sim.writer import write_session

    session = write_session(simulate_target(3600.0, seed=11), tmp / "target_1h")
    run = tmp / "target_run"
    proc_cmd = [sys.executable, "-m", "tpos_cli", "process", str(session), "-o", str(run), "-q"]
    cmd = [sys.executable, "-m", "tpos_cli", "report", str(run)]
    envs = {"": _env(), " (no bytecode)": _env(_source_copy(tmp))}
    for env in envs.values():
        _run(proc_cmd, tmp, env)  # numba cache (of each copy); with bytecode: write it
        _run(cmd, tmp, env)
    times = {k: ([], [], [], []) for k in envs}  # process wall, CPU; report wall, CPU
    out = ""
    for _ in range(RUNS):
        for k, env in envs.items():
            w, c, _ = _run(proc_cmd, tmp, env)
            times[k][0].append(w)
            times[k][1].append(c)
            w, c, out = _run(cmd, tmp, env)
            times[k][2].append(w)
            times[k][3].append(c)
    print(f"target hour, {_pages(out)} pages; medians of {RUNS}; tpos_cli bytecode cached unless said:")
    for k in envs:
        pw, pc, w, c = (_median(x) for x in times[k])
        print(f"  tpos process{k:15s} wall {pw:5.2f} s, CPU {pc:5.2f} s")
        print(f"  tpos report{k:16s} wall {w:5.2f} s, CPU {c:5.2f} s")
        print(f"  ratio report/process{k}: wall {w / pw:.2f}, CPU {c / pc:.2f} (goal <= 2)")
    stages_in_fresh_process(run)
    accuracy_check(run, session)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("drive", "target"))
    ap.add_argument("--stages", type=Path, metavar="RUN", help="only the stage shares of the report of RUN")
    args = ap.parse_args()
    for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    if args.stages is not None:
        stages(args.stages)
        return
    with tempfile.TemporaryDirectory() as tmp:
        if args.only in (None, "drive"):
            drive(Path(tmp))
        if args.only in (None, "target"):
            target(Path(tmp))


if __name__ == "__main__":
    main()
