"""The verdict (`summary.json["quality"]`) on clean simulations, planted mistakes and the shared real logs.

    python benchmarks/verdict.py                    # everything: clean + planted (3 seeds), real logs
    python benchmarks/verdict.py --only real        # or: clean, planted
    python benchmarks/verdict.py --seeds 601 602    # other seeds

Prints one row per run: the session, the mistake planted (if any), the verdict, whether a reason
names the planted mistake (a keyword of its cause), the time the verdict took, and the first
reason. A planted mistake counts as caught when the run is refused with a one-line error (exit 2)
or finishes "suspect"/"unreliable" with a reason naming it. Seeds are not those of the tests.

For real logs where the verdict suggests a fix (a GPS clock offset, a lever arm), the log is
processed again with the fix and both runs are scored with `tpos report` against the session's
truth: the advice must not make the smoothed horizontal RMS worse. The real drive logs are also
run with their GPS stamped 0.3 s late (a planted clock offset on real sensors).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data" / "real"
sys.path.insert(0, str(REPO))

from tests.helpers import mistakes as M  # noqa: E402
from tpos_cli.errors import TposError  # noqa: E402
from tpos_cli.pipeline import process_session  # noqa: E402
from tpos_cli.sim import SCENARIOS  # noqa: E402
from tpos_cli.sim.writer import write_session  # noqa: E402

sys.path.insert(0, str(REPO / "benchmarks"))
from drive import TRUTH_OF_THE_RECEIVER, truth_clock_overrides  # noqa: E402

LEVER_M = (1.0, 0.0, -1.5)  # antenna 1 m ahead of and 1.5 m above the IMU (FRD)
# (kind, planter, keyword a reason must contain, simulation overrides)
PLANTED = [
    ("drive", M.gyro_degps, "deg/s", {}),
    ("drive", M.acc_g, "g units", {}),
    ("drive", M.axes("FLU"), "axes", {}),
    ("drive", M.gps_late(0.3), "gps_offset_s", {"duration_s": 300.0, "outages": ((150.0, 30.0),)}),
    ("drive", M.gps_late(1e6), "GPS clock", {}),
    ("drive", M.gps_late(5.0), "gps_offset_s", {}),  # seconds off: the course-against-gyro lag (audit2, session 12)
    ("drive", M.odometry_late(20.0), "odometry_offset_s", {"odometry_rate_hz": 20.0}),
    ("drive", M.mounting_stated("[0.0, 0.0, 1.5708]", "mounting_radians"), "mounting_rpy_deg", {"mounting_rpy_deg": (0.0, 0.0, 90.0)}),
    ("drive", M.antenna_offset(LEVER_M, LEVER_M), None, {"duration_s": 300.0, "gps_sigma_h_m": 0.3, "gps_sigma_v_m": 0.5}),
    ("drive", M.antenna_offset(LEVER_M, [-v for v in LEVER_M]), "lever_arm",
     {"duration_s": 300.0, "gps_sigma_h_m": 0.3, "gps_sigma_v_m": 0.5}),
    ("target", M.axes("RBD"), "axes", {}),
    ("target", M.baseline("baseline_12_m", 0.25), "baseline_12_m", {}),
    ("target", M.baseline("baseline_13_m", 0.16), "baseline_13_m", {}),
    ("target", M.mag_disturbance(50.0, 0.5), "magnetometer", {}),
    ("ranging", M.anchor_moved("A2", 0.0, 1.0), "A2", {}),
    ("ranging", M.anchor_moved("A4", 0.0, -1.0), "A4", {}),
]


def verdict_of(session: Path, run_dir: Path, overrides: dict | None = None) -> dict:
    t0 = time.perf_counter()
    try:
        r = process_session(session, None, run_dir, overrides=overrides)
    except TposError as exc:
        return {"verdict": f"refused (exit {exc.exit_code})", "reasons": [str(exc)], "t_quality_s": 0.0,
                "t_total_s": time.perf_counter() - t0}
    q = r.summary["quality"]
    return {"verdict": q["verdict"], "reasons": q["reasons"], "checks": q["checks"],
            "t_quality_s": r.summary["timings_s"].get("quality", 0.0), "t_total_s": time.perf_counter() - t0}


def row(name: str, mistake: str, v: dict, keyword: str | None) -> str:
    named = "-"
    if keyword is not None:
        hit = any(keyword.lower() in x.lower() for x in v["reasons"])
        caught = hit and (v["verdict"] in ("suspect", "unreliable") or v["verdict"].startswith("refused"))
        named = "yes" if caught else "NO"
    first = next((x for x in v["reasons"] if keyword and keyword.lower() in x.lower()), v["reasons"][0] if v["reasons"] else "")
    return (f"{name:40s} {mistake:24s} {v['verdict']:15s} {named:5s} {v['t_quality_s']:6.2f} s  "
            f"{first[:160]}")


def simulate(kind: str, seed: int, out: Path, **kw) -> Path:
    sim = SCENARIOS[kind](seed=seed, **kw)
    write_session(sim, out, fmt="parquet")
    return out


def bench_clean_and_planted(tmp: Path, seeds, planted: bool, clean: bool) -> None:
    print(f"{'session':40s} {'mistake':24s} {'verdict':15s} {'named':5s} {'verdict time':>8s}  first reason")
    for seed in seeds:
        base = {}
        for kind in ("drive", "target", "ranging"):
            base[kind] = simulate(kind, seed, tmp / f"{kind}_{seed}")
            if clean:
                v = verdict_of(base[kind], tmp / "runs" / f"{kind}_{seed}")
                print(row(f"{kind} seed {seed}", "(clean)", v, None) + ("" if v["verdict"] == "ok" else "   <- clean run not ok"))
        if not planted:
            continue
        for kind, planter, keyword, sim_kw in PLANTED:
            src = base[kind]
            if sim_kw:
                key = (kind, repr(sorted(sim_kw.items())))
                if key not in base:
                    base[key] = simulate(kind, seed, tmp / f"{kind}_{seed}_variant{len(base)}", **sim_kw)
                src = base[key]
            d = M.plant(src, tmp / f"{kind}_{seed}_{planter.__name__}", planter)
            v = verdict_of(d, tmp / "runs" / d.name)
            print(row(f"{kind} seed {seed}" + (" (300 s)" if sim_kw.get("duration_s") else ""), planter.__name__, v, keyword))


def _report_h_rms(run_dir: Path) -> float | None:
    p = subprocess.run([sys.executable, "-m", "tpos_cli", "report", str(run_dir), "--json"], capture_output=True, text=True)
    if p.returncode != 0:
        return None
    d = json.loads(p.stdout)
    return next((h["rms_pos_h_m"] for h in d["headline"] if h["solution"] == "smoothed"), None)


def bench_real(tmp: Path) -> None:
    if not SHARED.exists():
        print(f"no shared real logs at {SHARED}")
        return
    print(f"{'real log':40s} {'':24s} {'verdict':15s} {'':5s} {'verdict time':>8s}  reasons")
    for d in sorted(p for p in SHARED.iterdir() if (p / "session.toml").exists()):
        run = tmp / "runs" / d.name
        ov = truth_clock_overrides(d.name) if 'kind = "drive"' in (d / "session.toml").read_text() else None
        v = verdict_of(d, run, ov)
        print(row(d.name, "", v, None))
        for x in v["reasons"][1:]:
            print(f"{'':93s}{x[:160]}")
        _check_advice(tmp, d, run, v, ov)
    bench_real_injected(tmp)


def bench_real_injected(tmp: Path, late_s: float = 0.3) -> None:
    """Real drive logs with their GPS stamped `late_s` late: is the clock named, and does the advice help?"""
    if not SHARED.exists():
        return
    print(f"\n{'real log, GPS stamped late':40s} {'mistake':24s} {'verdict':15s} {'named':5s} {'verdict time':>8s}  reason")
    for name in ("comma2k19_seg40", "navego_canada_enav", "rtklibexplorer_drive_0708_part1", "rtklibexplorer_walk_0827"):
        d = M.plant(SHARED / name, tmp / f"{name}_late", M.gps_late(late_s))
        run = tmp / "runs" / d.name
        v = verdict_of(d, run)
        print(row(name, f"gps_late_{late_s:g}", v, "gps_offset_s"))
        _check_advice(tmp, d, run, v)


def _h_rms_at_antenna(session_dir: Path, run_dir: Path) -> float:
    """Smoothed horizontal RMS of the run's antenna (its rows plus C_nb l, l the session's lever arm
    in the IMU's logged axes, C_nb from the rows' attitude and the run's mounting) against the
    truth of the receiver, over the truth's epochs inside the run."""
    from tpos_cli.frames.geodetic import lla_to_ned
    from tpos_cli.frames.rotation import euler_to_dcm
    from tpos_cli.session import load_session

    session = load_session(session_dir)
    summ = json.loads((run_dir / "summary.json").read_text())
    mnt = ((summ["results"].get("constraints") or {}).get("mounting") or {}).get("mounting_rpy_deg")
    C_vb = euler_to_dcm(*np.radians(mnt)) if mnt is not None else np.eye(3)
    tr = pd.read_parquet(run_dir / "trajectory.parquet")
    tr = tr[tr["solution"] == "smoothed"].sort_values("t")
    truth = pd.read_csv(session_dir / "truth.csv")
    t = truth["t"].to_numpy(float)
    t = t[(t >= tr["t"].iloc[0]) & (t <= tr["t"].iloc[-1])]
    cols = {c: np.interp(t, tr["t"], np.unwrap(np.radians(tr[c])) if c in ("roll", "pitch", "yaw") else tr[c])
            for c in ("lat", "lon", "h", "roll", "pitch", "yaw")}
    C_nb = euler_to_dcm(cols["roll"], cols["pitch"], cols["yaw"]) @ C_vb  # the rows' attitude is the vehicle's
    ref = truth[["lat", "lon", "h"]].to_numpy(float)[0]
    ant = lla_to_ned(np.column_stack([cols["lat"], cols["lon"], cols["h"]]), ref) + C_nb @ session.meta.lever_arm_b_m
    tru = truth.set_index("t").loc[t, ["lat", "lon", "h"]].to_numpy(float)
    e = ant - lla_to_ned(tru, ref)
    return float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))


def _check_advice(tmp: Path, d: Path, run: Path, v: dict, overrides: dict | None = None) -> None:
    """Each suggested fix applied alone to a copy of the session, scored against its truth, run
    with the `overrides` of the run that gave the advice."""
    for i, (section, key, value) in enumerate(_suggested_fixes(v)):
        fixed = tmp / f"{d.name}_fixed{i}"
        shutil.rmtree(fixed, ignore_errors=True)
        shutil.copytree(d, fixed)
        M.set_toml(fixed, section, key, value)
        note = ""
        receiver = d.name in TRUTH_OF_THE_RECEIVER
        if key == "gps_offset_s" and receiver:
            truth = pd.read_csv(fixed / "truth.csv")
            truth["t"] = truth["t"] + float(value)  # the receiver's truth moves with its fixes (no [time] offset before)
            truth.to_csv(fixed / "truth.csv", index=False)
            note = " (truth on the GPS clock: moved with it)"
        process_session(fixed, None, tmp / "runs" / fixed.name, overrides=overrides)
        if receiver:
            before, after = _h_rms_at_antenna(d, run), _h_rms_at_antenna(fixed, tmp / "runs" / fixed.name)
            note += " (scored at the antenna)"
        else:
            before, after = _report_h_rms(run), _report_h_rms(tmp / "runs" / fixed.name)
        def m(v):
            return "n/a" if v is None else f"{v:.3f}"

        print(f"{'':93s}advice [{section}] {key} = {value}{note}: smoothed horizontal RMS against truth {m(before)} -> {m(after)} m"
              + ("   <- WORSE" if before is not None and after is not None and after > before else ""))
        if key == "lever_arm_m" and receiver:
            # the default run estimated the lever arm itself, so the fix mostly moves its prior: the
            # same pair without the lever-arm states shows whether the suggested value is right
            off = {"drive_smooth.lever_arm": "off"}
            process_session(d, None, tmp / "runs" / f"{d.name}_nolever", overrides=off)
            process_session(fixed, None, tmp / "runs" / f"{fixed.name}_nolever", overrides=off)
            b, a = (_h_rms_at_antenna(x, tmp / "runs" / f"{x.name}_nolever") for x in (d, fixed))
            print(f"{'':93s}  the same without lever-arm states (lever_arm = off): {m(b)} -> {m(a)} m"
                  + ("   <- WORSE" if a > b else ""))


def _suggested_fixes(v: dict) -> list:
    fixes = []
    for x in v["reasons"]:
        m = re.search(r"set \[time\] gps_offset_s = (-?[0-9.]+)", x)
        if m:
            fixes.append(("time", "gps_offset_s", m.group(1)))
        m = re.search(r"set \[gps\] lever_arm_m = (\[[^\]]*\])", x)
        if m:
            fixes.append(("gps", "lever_arm_m", m.group(1)))
    return fixes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=["clean", "planted", "real"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[501, 502, 503])
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="tpos-verdict-") as t:
        tmp = Path(t)
        if a.only in (None, "clean", "planted"):
            bench_clean_and_planted(tmp, a.seeds, planted=a.only in (None, "planted"), clean=a.only in (None, "clean"))
        if a.only in (None, "real"):
            bench_real(tmp)


if __name__ == "__main__":
    main()
