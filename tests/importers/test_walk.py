"""Import of the raw rtklibexplorer walk: IMU CSV (g, deg/s, mounting, time tags) and RTKLIB .pos.

The excerpts in tests/data/ make the tests stand alone; the full-size comparison with
../shared/data/real/rtklibexplorer_walk_0827 runs only when ../shared is present (skips otherwise).
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from typer.testing import CliRunner

from tpos_cli.cli import app
from tpos_cli.importers import import_into_session
from tpos_cli.importers.csv_table import import_csv
from tpos_cli.importers.mapping import load_mapping
from tpos_cli.importers.rtklib_pos import import_rtklib_pos

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "rtklibexplorer_walk_0827"
MAP = ROOT / "docs" / "mappings" / "rtklibexplorer_walk_0827_imu.toml"
from tests.helpers.paths import SHARED_DATA as SHARED
G0 = 9.80665


def _mapping_for(csv_name: str, tmp_path: Path) -> Path:
    text = MAP.read_text().replace('tag_file = "imu_1730.csv.tag"', f'tag_file = "{csv_name}.tag"')
    p = tmp_path / "map.toml"
    p.write_text(text)
    return p


def test_imu_csv_units_mounting_and_time_tags(tmp_path):
    r = import_csv(DATA / "imu_head.csv", load_mapping(_mapping_for("imu_head.csv", tmp_path)))
    imu = r.tables["imu"]
    raw = np.genfromtxt(DATA / "imu_head.csv", delimiter=",", skip_header=1)  # line 1 is truncated (6 fields)
    assert len(imu) == len(raw) == 399
    # mounting (180, 0, -90) deg: x_FRD = -y_imu, y_FRD = -x_imu, z_FRD = -z_imu (C = Rz(-90) Rx(180))
    assert_allclose(imu["acc_x"], -raw[:, 1] * G0, rtol=0, atol=1e-12)  # exact unit conversion
    assert_allclose(imu["acc_y"], -raw[:, 0] * G0, rtol=0, atol=1e-12)
    assert_allclose(imu["acc_z"], -raw[:, 2] * G0, rtol=0, atol=1e-12)
    assert_allclose(imu["gyro_x"], -np.radians(raw[:, 4]), rtol=0, atol=1e-15)
    assert_allclose(imu["gyro_y"], -np.radians(raw[:, 3]), rtol=0, atol=1e-15)
    assert_allclose(imu["gyro_z"], -np.radians(raw[:, 5]), rtol=0, atol=1e-15)
    # times: linear in the counter (ms); 2.6 s of tags with ~5 ms arrival jitter fix the clock rate
    # to about 0.5 % only (the full log: 1e-5), hence rtol 1e-2; GPS time of week of 2025-08-28
    # 17:30:40 GPST (the tag file's start, 408640.961 s) plus the lag of the first line
    dt_counter = np.diff(raw[:, 6]) * 1e-3
    assert_allclose(np.diff(imu["t"]), dt_counter, rtol=1e-2, atol=0)
    slope = np.polyfit(raw[:, 6] * 1e-3, imu["t"], 1)[0]
    assert np.ptp(imu["t"] - slope * raw[:, 6] * 1e-3) < 1e-6  # linear in the counter (float64 at 4e5 s and 3e3 s)
    assert 408640.96 < imu["t"].iloc[0] < 408641.10
    # nominal rate: 1 / median interval (6 ms counter steps, scaled by the fitted clock rate)
    assert r.toml["imu"] == {"axes": "FRD", "rate_hz": pytest.approx(1.0 / np.median(np.diff(imu["t"])), rel=1e-4)}


# The walk's .pos has no header line saying what its heights are; they are the receiver's heights
# above mean sea level: its NAV-PVT of the same epochs gives hMSL 1601.435 m, height 1580.048 m, so
# the geoid separation there is -21.387 m (UBX NAV-PVT at 17:30:21.75 GPST).
WALK_GEOID_SEP_M = -21.387


def test_rtklib_pos_excerpt():
    g = import_rtklib_pos(DATA / "gnss_head.pos", heights="geodetic", geoid_sep_m=WALK_GEOID_SEP_M).tables["gps"]
    assert len(g) == 41
    assert g["t"].iloc[0] == pytest.approx(408639.749, abs=1e-9)  # 2025/08/28 17:30:39.749 GPST = Thu 17:30:39.749 of the week
    assert_allclose(np.diff(g["t"]), 0.25, atol=1e-6)  # 4 Hz
    row = g.iloc[0]
    assert (row.lat, row.lon) == (40.0966916, -105.1471665)  # digits copied, not recomputed
    assert row.h == pytest.approx(1580.048, abs=1e-9)  # 1601.435 above the geoid - 21.387: the UBX ellipsoidal height
    assert row.vd == pytest.approx(-0.027) and row.vn == pytest.approx(0.001)  # vd = -vu
    assert (g["fix"] == 2).all()  # Q = 1 (fix) -> 2 (differential)
    assert (row.sigma_n, row.sigma_u, int(row.nsat)) == (0.0098995, 0.01, 25)


def test_cli_builds_one_session_from_two_imports(tmp_path):
    out = tmp_path / "walk"
    runner = CliRunner()
    res = runner.invoke(app, ["import", "csv", str(DATA / "imu_head.csv"), "--map", str(_mapping_for("imu_head.csv", tmp_path)), "-o", str(out)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["import", "rtklib-pos", str(DATA / "gnss_head.pos"), "-o", str(out)])
    assert res.exit_code == 2 and "does not say whether its heights are ellipsoidal or geodetic" in res.output
    assert not (out / "gps.csv").exists()
    pos_args = ["--heights", "geodetic", "--geoid-sep-m", str(WALK_GEOID_SEP_M)]
    res = runner.invoke(app, ["import", "rtklib-pos", str(DATA / "gnss_head.pos"), "-o", str(out), *pos_args])
    assert res.exit_code == 0, res.output
    from tpos_cli.session import load_session

    s = load_session(out)
    assert s.meta.axes == "FRD" and s.gps is not None and len(s.gps.t_s) == 41
    assert_allclose(s.meta.lever_arm_b_m, [0.0, -0.05, 0.0])
    # a second import of the same table is refused without --force (exit 2), accepted with it
    res = runner.invoke(app, ["import", "rtklib-pos", str(DATA / "gnss_head.pos"), "-o", str(out), *pos_args])
    assert res.exit_code == 2 and "--force" in res.output
    res = runner.invoke(app, ["import", "rtklib-pos", str(DATA / "gnss_head.pos"), "-o", str(out), "--force", *pos_args])
    assert res.exit_code == 0


@pytest.mark.skipif(not SHARED.exists(), reason="needs ../shared (the full raw and converted walk)")
def test_full_walk_matches_converted_session(tmp_path):
    raw, real = SHARED / "raw" / "rtklibexplorer_walk_0827", SHARED / "real" / "rtklibexplorer_walk_0827"
    out = tmp_path / "walk"
    import_into_session("csv", [raw / "imu_1730.csv"], out, mapping=MAP)
    import_into_session("rtklib-pos", [raw / "gnss_1730_sf.pos"], out, heights="geodetic", geoid_sep_m=WALK_GEOID_SEP_M)
    g, g_ref = pd.read_csv(out / "gps.csv"), pd.read_csv(real / "gps.csv")
    for c in ("lat", "lon"):
        assert np.abs(g[c] - g_ref[c]).max() * 111e3 < 1e-3  # within 1 mm (the bound)
    # the converted session kept the file's heights above the geoid; ours are ellipsoidal, and they
    # agree with the receiver's own ellipsoidal heights (UBX NAV-PVT) of the same epochs within 1 mm
    assert np.abs(g["h"] - (g_ref["h"] + WALK_GEOID_SEP_M)).max() < 1e-6
    from tpos_cli.importers.ubx import import_ubx

    u = import_ubx(raw / "gnss_1730.ubx").tables["gps"]
    m = pd.merge_asof(g, u, on="t", tolerance=0.01, direction="nearest", suffixes=("", "_ubx")).dropna(subset=["h_ubx"])
    assert len(m) == len(g) and np.abs(m["h"] - m["h_ubx"]).max() <= 1e-3 + 1e-9
    assert np.abs(g["t"] - g_ref["t"]).max() < 1e-6
    imu, ref = pd.read_parquet(out / "imu.parquet"), pd.read_parquet(real / "imu.parquet")
    cols = ["gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"]
    a, b = imu[cols].to_numpy(), ref[cols].to_numpy()
    # the converted session drops the first and last complete lines: align samples by value
    shift = min(range(len(a) - len(b) + 1), key=lambda s: np.abs(a[s : s + len(b)] - b).sum())
    big = np.abs(b) > 1e-3
    assert (np.abs(a[shift : shift + len(b)] - b)[big] / np.abs(b[big])).max() < 1e-3  # 0.1 % (issue)
    assert np.abs(imu["t"].to_numpy()[shift : shift + len(b)] - ref["t"].to_numpy()).max() < 0.02  # 0.02 s (issue)
