"""Benchmark of `tpos report` (issues 14 and 16): speed of the report of hour-long logs.

    python benchmarks/report.py              # drive hour and target hour (about 3-5 minutes on 2 cores)
    python benchmarks/report.py --only drive # or: target

Drive: a simulated one-hour drive (100 Hz IMU, 1 Hz GPS, three outages) is processed, then
`tpos report` runs on it in a subprocess, as a user types it (interpreter start, imports, the
session load and input check, accuracy against truth, the PDF); its wall time is divided by the
bare numba reference loop of `benchmarks/drive.py` timed in the same run (goal <= 1.5).
Target: a simulated one-hour target log (100 Hz IMU, shots every few seconds); the report's wall
time is divided by the `tpos process` wall time of the same log (goal <= 2).
Each time is the median of three runs (this machine is shared and noisy); the stage shares come
from one in-process run.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

RUNS = 3


def _wall(cmd, cwd) -> tuple[float, str]:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    t0 = time.perf_counter()
    p = subprocess.run(cmd, check=True, env=env, cwd=cwd, capture_output=True, text=True)
    return time.perf_counter() - t0, p.stdout


def _median_wall(cmd, cwd) -> tuple[float, str]:
    res = [_wall(cmd, cwd) for _ in range(RUNS)]
    return statistics.median(r[0] for r in res), res[-1][1]


def _stages(run_dir: Path) -> str:
    """One in-process report twice: the first pays the lazy imports and font loading every
    `tpos report` pays; the second shows the work itself (context: run, session, input check,
    accuracy, health; PDF: the pages)."""
    from tpos_cli.report.build import build_context, build_summary
    from tpos_cli.report.pdf import write_pdf

    out = []
    for _ in range(2):
        t0 = time.perf_counter()
        ctx = build_context(run_dir)
        t1 = time.perf_counter()
        summary = build_summary(ctx)
        with tempfile.TemporaryDirectory() as tmp:
            pages = write_pdf(Path(tmp) / "r.pdf", ctx, summary)
        t2 = time.perf_counter()
        out.append((t1 - t0, t2 - t1, len(pages)))
    (c0, p0, n), (c1, p1, _) = out
    return f"in process: context {c1:.2f} s, PDF {p1:.2f} s for {n} pages (first run {c0:.2f} s and {p0:.2f} s: lazy imports, fonts)"


def drive(tmp: Path) -> None:
    from drive import reference_loop

    from tpos_cli.sim.drive import simulate_drive

    sim = simulate_drive(3600.0, seed=11, outages=((600.0, 30.0), (1800.0, 60.0), (3000.0, 60.0)))
    session = sim.write(tmp / "drive_1h")
    n = sim.imu.t_s.size
    del sim
    run = tmp / "drive_run"
    _wall([sys.executable, "-m", "tpos_cli", "process", str(session), "-o", str(run), "-q"], tmp)
    cmd = [sys.executable, "-m", "tpos_cli", "report", str(run)]
    _wall(cmd, tmp)  # warm the file cache
    wall, out = _median_wall(cmd, tmp)
    ref = statistics.median(reference_loop(n, 100) for _ in range(RUNS))
    pages = re.search(r"(\d+) PDF pages", out)
    print(
        f"drive hour ({n} IMU samples): tpos report {wall:.2f} s, reference loop {ref:.2f} s, "
        f"ratio {wall / ref:.2f} (goal <= 1.5); {pages.group(1) if pages else '?'} pages"
    )
    imports, _ = _median_wall(
        [sys.executable, "-c", "import tpos_cli.cli, tpos_cli.report.pdf, tpos_cli.session, matplotlib.backends.backend_pdf"], tmp
    )
    print(f"  interpreter start and imports alone: {imports:.2f} s ({imports / ref:.2f} of the reference)")
    print("  " + _stages(run))


def target(tmp: Path) -> None:
    from tpos_cli.sim.target import simulate_target
    from tpos_cli.sim.writer import write_session

    session = write_session(simulate_target(3600.0, seed=11), tmp / "target_1h")
    run = tmp / "target_run"
    proc_cmd = [sys.executable, "-m", "tpos_cli", "process", str(session), "-o", str(run), "-q"]
    _wall(proc_cmd, tmp)  # numba cache
    proc, _ = _median_wall(proc_cmd, tmp)
    cmd = [sys.executable, "-m", "tpos_cli", "report", str(run)]
    wall, out = _median_wall(cmd, tmp)
    pages = re.search(r"(\d+) PDF pages", out)
    print(
        f"target hour: tpos process {proc:.2f} s, tpos report {wall:.2f} s, ratio {wall / proc:.2f} (goal <= 2); "
        f"{pages.group(1) if pages else '?'} pages"
    )
    print("  " + _stages(run))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("drive", "target"))
    args = ap.parse_args()
    for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    with tempfile.TemporaryDirectory() as tmp:
        if args.only in (None, "drive"):
            drive(Path(tmp))
        if args.only in (None, "target"):
            target(Path(tmp))


if __name__ == "__main__":
    main()
