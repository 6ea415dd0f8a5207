"""Benchmark of the real-log importers and checks (issue 8), on the full-size logs in ../shared.

    python benchmarks/importers.py                  # everything (about a minute on 2 cores)
    python benchmarks/importers.py --only walk      # or: rover, offset, conventions

walk: the raw rtklibexplorer walk (IMU CSV in g and deg/s with time tags and mounting rotation,
RTKLIB .pos) imported with `tpos import` into a fresh session, compared with the converted session
`../shared/data/real/rtklibexplorer_walk_0827` (issue bounds: positions within 1 mm, IMU samples
within 0.02 s and 0.1 % in value), then processed end to end with the default pipeline.
rover: the NaveGo rover GPS CSV imported with docs/mappings/navego_canada_gps.toml, compared with
the converted session's gps.csv.
offset: the IMU-GPS time offset of each real session with GPS, as logged and with +-0.2 s injected.
conventions: `check_conventions` on every real session and sample log (should print nothing but
measured clock offsets).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
SHARED = REPO.parent / "shared" / "data"
MAPS = REPO / "docs" / "mappings"


def bench_walk(tmp: Path) -> None:
    from tpos_cli.importers import import_into_session
    from tpos_cli.pipeline import process_session

    raw, real = SHARED / "raw" / "rtklibexplorer_walk_0827", SHARED / "real" / "rtklibexplorer_walk_0827"
    out = tmp / "walk"
    t0 = time.perf_counter()
    import_into_session("csv", [raw / "imu_1730.csv"], out, mapping=MAPS / "rtklibexplorer_walk_0827_imu.toml")
    t1 = time.perf_counter()
    # the .pos has no height header: the shared conversion took its heights as ellipsoidal, so this
    # import says the same to reproduce it (they are the receiver's heights above its geoid, 21.4 m
    # above the ellipsoid here: the same receiver's UBX NAV-PVT gives both; GPS and truth share them)
    import_into_session("rtklib-pos", [raw / "gnss_1730_sf.pos"], out, heights="ellipsoidal")
    t2 = time.perf_counter()
    print(f"walk: import IMU CSV {t1 - t0:.2f} s, RTKLIB .pos {t2 - t1:.2f} s")
    g, g_ref = pd.read_csv(out / "gps.csv"), pd.read_csv(real / "gps.csv")
    lat0 = np.radians(g_ref["lat"].iloc[0])
    d_n = (g["lat"] - g_ref["lat"]).abs().max() * np.pi / 180 * 6.371e6
    d_e = (g["lon"] - g_ref["lon"]).abs().max() * np.pi / 180 * 6.371e6 * np.cos(lat0)
    print(f"walk gps: {len(g)} rows (converted {len(g_ref)}); max |dN| {1e3 * d_n:.3f} mm, |dE| {1e3 * d_e:.3f} mm, "
          f"|dh| {1e3 * (g['h'] - g_ref['h']).abs().max():.3f} mm, |dt| {(g['t'] - g_ref['t']).abs().max():.2e} s (bound 1 mm)")
    imu, ref = pd.read_parquet(out / "imu.parquet"), pd.read_parquet(real / "imu.parquet")
    cols = ["gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"]
    a, b = imu[cols].to_numpy(), ref[cols].to_numpy()
    shift = min(range(len(a) - len(b) + 1), key=lambda s: np.abs(a[s : s + len(b)] - b).sum())
    big = np.abs(b) > 1e-3
    rel = (np.abs(a[shift : shift + len(b)] - b)[big] / np.abs(b[big])).max()
    dt = np.abs(imu["t"].to_numpy()[shift : shift + len(b)] - ref["t"].to_numpy())
    print(f"walk imu: {len(imu)} rows (converted {len(ref)}, aligned at +{shift}); max |dt| {1e3 * dt.max():.2f} ms "
          f"(bound 20 ms), median {1e3 * np.median(dt):.2f} ms; max relative value error {100 * rel:.4f} % (bound 0.1 %)")
    t3 = time.perf_counter()
    res = process_session(out, run_dir=tmp / "walk_run")
    print(f"walk processed end to end with pipeline {res.summary['pipeline']}: {time.perf_counter() - t3:.1f} s, "
          f"outputs {', '.join(res.summary['outputs'])}, {len(res.summary['warnings'])} warnings")


def bench_rover(tmp: Path) -> None:
    from tpos_cli.importers import import_into_session

    out = tmp / "rover"
    t0 = time.perf_counter()
    import_into_session("csv", [SHARED / "raw" / "navego_canada" / "gps-latlong.txt"], out, mapping=MAPS / "navego_canada_gps.toml")
    g, g_ref = pd.read_csv(out / "gps.csv"), pd.read_csv(SHARED / "real" / "navego_canada_enav" / "gps.csv")
    print(f"rover gps: import {time.perf_counter() - t0:.2f} s; {len(g)} rows (converted {len(g_ref)})")
    n = min(len(g), len(g_ref))
    g, g_ref = g.iloc[:n], g_ref.iloc[:n]
    lat0 = np.radians(g_ref["lat"].iloc[0])
    d_n = (g["lat"] - g_ref["lat"]).abs().max() * np.pi / 180 * 6.371e6
    d_e = (g["lon"] - g_ref["lon"]).abs().max() * np.pi / 180 * 6.371e6 * np.cos(lat0)
    print(f"rover gps: max |dt| {(g['t'] - g_ref['t']).abs().max():.2e} s, |dN| {1e3 * d_n:.3f} mm, |dE| {1e3 * d_e:.3f} mm, "
          f"|dh| {1e3 * (g['h'] - g_ref['h']).abs().max():.3f} mm, fix equal {bool((g['fix'] == g_ref['fix']).all())}")


def bench_offset(tmp: Path) -> None:
    from tpos_cli.errors import TposError
    from tpos_cli.session import load_session
    from tpos_cli.timeoffset import estimate_session_offset

    for name in ("comma2k19_seg40", "navego_canada_enav", "rtklibexplorer_walk_0827"):
        for inj in (0.0, 0.2, -0.2):
            d = tmp / f"{name}_{inj:+.1f}"
            shutil.copytree(SHARED / "real" / name, d)
            gps = pd.read_csv(d / "gps.csv", dtype={"t": float})
            gps["t"] += inj
            gps.to_csv(d / "gps.csv", index=False, float_format="%.9f")
            t0 = time.perf_counter()
            try:
                r = estimate_session_offset(load_session(d))
                msg = (f"{r.offset_s:+.3f} +- {r.sigma_s:.3f} s (the log's own offset {r.offset_s + inj:+.3f} s), channels "
                       f"{'+'.join(r.channels)}, R2 {np.round(r.r2, 2).tolist()}, gains course {r.gain:.2f} along {r.gain_along:.2f}, {r.n_used} windows")
            except TposError as exc:
                msg = f"no estimate: {exc}"
            print(f"offset {name} injected {inj:+.1f} s: {msg} [{time.perf_counter() - t0:.2f} s]")


def bench_conventions(tmp: Path) -> None:
    from tpos_cli.conventions import check_conventions
    from tpos_cli.session import load_session

    dirs = sorted(p for p in (SHARED / "real").iterdir() if (p / "session.toml").exists())
    dirs += sorted(p for p in (REPO / "sample_logs").iterdir() if (p / "session.toml").exists())
    for d in dirs:
        t0 = time.perf_counter()
        w = check_conventions(load_session(d))
        print(f"conventions {d.name}: {len(w)} warnings [{time.perf_counter() - t0:.2f} s]" + "".join(f"\n    {x}" for x in w))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=["walk", "rover", "offset", "conventions"])
    args = ap.parse_args()
    if not SHARED.exists():
        sys.exit(f"needs {SHARED}")
    with tempfile.TemporaryDirectory() as td:
        for name, f in (("walk", bench_walk), ("rover", bench_rover), ("offset", bench_offset), ("conventions", bench_conventions)):
            if args.only in (None, name):
                f(Path(td))


if __name__ == "__main__":
    main()
