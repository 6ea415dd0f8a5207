"""Benchmark `tpos batch`: sessions per minute with --jobs 1 and --jobs 2 on simulated drives.

    python benchmarks/batch.py [--sessions 20] [--duration 600] [--jobs 1 2] [--work DIR]

Simulates N drive sessions (`tpos simulate drive OUT --duration D --seed N`, cached in the work
directory), warms the numba on-disk cache with one `tpos process`, then times a full
`tpos batch --force` subprocess per --jobs value: everything a user waits for, worker start-up
(imports, loading cached kernels) included. Prints sessions per minute, the speed-up over the
first --jobs value, and how much of the wall time the sessions themselves took.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TPOS = [sys.executable, "-m", "tpos_cli"]


def _simulate(out: Path, duration_s: float, seed: int) -> None:
    if (out / "session.toml").exists():
        return
    cmd = [*TPOS, "simulate", "drive", str(out), "--duration", str(duration_s), "--seed", str(seed)]
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    if r.returncode != 0:
        # `tpos simulate` not available in this build: the same simulator through the library
        from tpos_cli.sim.drive import simulate_drive
        from tpos_cli.sim.writer import write_session

        write_session(simulate_drive(duration_s, seed=seed, name=out.name), out, fmt="parquet", overwrite=True)


def _pipeline() -> str:
    # drive-smooth is the pipeline the issue names; until it exists, the default for drive sessions,
    # or the ingest health check
    names = {p.stem for p in (REPO / "pipelines").glob("*.toml")}
    for name in ("drive-smooth", "drive_smooth"):
        if name in names:
            return name
    return "ingest"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--duration", type=float, default=600.0, help="seconds per session")
    ap.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--work", type=Path, default=None, help="work directory (default: a temporary one)")
    ap.add_argument("--pipeline", default=None)
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="tpos-bench-batch-"))
    logs = work / "logs"
    pipeline = args.pipeline or _pipeline()

    t = time.perf_counter()
    for seed in range(1, args.sessions + 1):
        _simulate(logs / f"drive{seed:03d}", args.duration, seed)
    print(f"{args.sessions} sessions of {args.duration:.0f} s in {logs} ({time.perf_counter() - t:.1f} s to prepare)")
    warm = subprocess.run([*TPOS, "process", str(logs / "drive001"), "-p", pipeline, "-o", str(work / "warm"), "-q"],
                          cwd=REPO, capture_output=True, text=True)
    if warm.returncode != 0:
        sys.exit(f"warm-up run failed: {warm.stderr.strip() or warm.stdout.strip()}")
    print(f"pipeline {pipeline}; numba cache warmed by one `tpos process`")

    base = None
    for jobs in args.jobs:
        out = work / f"out-j{jobs}"
        cmd = [*TPOS, "batch", str(logs / "*"), "--out", str(out), "-p", pipeline, "--jobs", str(jobs), "--force", "-q"]
        t = time.perf_counter()
        r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
        wall = time.perf_counter() - t
        doc = json.loads((out / "batch.json").read_text())
        if r.returncode != 0:
            sys.exit(f"--jobs {jobs}: exit {r.returncode}\n{r.stdout}{r.stderr}")
        busy = sum(s["time_s"] for s in doc["sessions"])
        per_min = args.sessions / wall * 60.0
        base = base or per_min
        print(f"--jobs {jobs}: {per_min:7.1f} sessions/min  (wall {wall:6.1f} s, speed-up {per_min / base:4.2f}x, "
              f"session time {busy:6.1f} s = {busy / (wall * jobs):4.0%} of {jobs} x wall, "
              f"mean {busy / args.sessions:.2f} s/session)")


if __name__ == "__main__":
    main()
