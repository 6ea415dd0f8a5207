"""`tpos export` end to end on simulated sessions (`tpos simulate` target and drive): every format
opens with a standard parser, one row per target, coordinates match the exact truth within the
sigmas the export states."""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import stat
import xml.etree.ElementTree as ET
from pathlib import Path

import gpxpy
import numpy as np
import pytest
from scipy import stats
from typer.testing import CliRunner

from tpos_cli.cli import app
from tpos_cli.frames.geodetic import lla_to_ned
from tpos_cli.pipeline import process_session
from tpos_cli.report.truth import interpolate_positions
from tpos_cli.sim.drive import simulate_drive
from tpos_cli.sim.target import simulate_target
from tpos_cli.sim.writer import write_session

runner = CliRunner()
KML = "{http://www.opengis.net/kml/2.2}"
NEES3_999 = stats.chi2.ppf(0.999, 3)  # 1 in 1000 per target: a wrong sigma fails, chance does not


@pytest.fixture(scope="module")
def target_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("target")
    sim = simulate_target(90.0, seed=11)
    s = write_session(sim, d / "s")
    run = process_session(s, "target-fkf", d / "run").run_dir
    truth = {i: p for i, p, r in zip(sim.targets.ids, sim.targets.lla, sim.targets.role) if r == "truth"}
    return run, truth


@pytest.fixture(scope="module")
def drive_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("drive")
    sim = simulate_drive(120.0, seed=3, outages=((60.0, 20.0),), shots=4, shot_range_m=40.0)
    s = sim.write(d / "s")
    run = process_session(s, "drive-smooth", d / "run").run_dir
    return run, sim


def _export(run, *args):
    res = runner.invoke(app, ["export", str(run), *args])
    assert res.exit_code == 0, res.output
    return res


def _rows_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _check_against_truth(rows, truth):
    """rows: dicts with id, lat, lon, h, sigma_n/e/u (strings or floats); NEES of each truth target."""
    seen = 0
    for r in rows:
        if r["id"] not in truth:
            continue
        seen += 1
        e = lla_to_ned(np.array([float(r["lat"]), float(r["lon"]), float(r["h"])]), truth[r["id"]])
        e[2] = -e[2]  # north, east, up
        sd = np.array([float(r["sigma_n"]), float(r["sigma_e"]), float(r["sigma_u"])])
        nees = float(np.sum((e / sd) ** 2))  # the run writes no cross covariances for targets
        assert nees < NEES3_999, (r["id"], e, sd)
    assert seen == len(truth)


def test_target_session_all_formats(target_run):
    run, truth = target_run
    for fmt in ("csv", "kml", "geojson", "gpx"):
        res = _export(run, "--format", fmt)
        assert f"targets (fkf_cal, 5 targets, UTM 18N) -> {run}/targets_fkf_cal.{fmt}" in res.output
    rows = _rows_csv(run / "targets_fkf_cal.csv")
    ids = [r["id"] for r in rows]
    assert sorted(ids) == sorted(set(ids)) == ["REF", "T1", "T2", "T3", "T4"]  # one row per target
    assert {r["n_shots"] for r in rows if r["id"] in ("REF", "T1")} == {"2"}  # both shot twice in the scenario
    assert all("e" not in r["sigma_u"].lower() for r in rows)  # fixed decimals, no scientific notation
    _check_against_truth(rows, truth)

    # KML 2.2: one Point placemark per target plus the observer, lon,lat[,h] coordinates
    kml = ET.parse(run / "targets_fkf_cal.kml").getroot()
    assert kml.tag == KML + "kml"
    marks = kml.findall(f".//{KML}Placemark")
    assert sorted(m.findtext(KML + "name") for m in marks) == sorted(ids + ["observer"])
    for m in marks:
        data = {d.get("name"): d.findtext(KML + "value") for d in m.iter(KML + "Data")}
        lon, lat, _ = map(float, m.findtext(f"{KML}Point/{KML}coordinates").split(","))
        if m.findtext(KML + "name") in truth:
            assert (lat, lon) == pytest.approx((float(data["lat"]), float(data["lon"])), abs=1e-9)

    # GeoJSON RFC 7946: FeatureCollection, [lon, lat, h], WGS-84 (no crs member)
    gj = json.loads((run / "targets_fkf_cal.geojson").read_text())
    assert gj["type"] == "FeatureCollection" and "crs" not in gj
    feats = [f for f in gj["features"] if f["properties"]["role"] == "target"]
    rows_gj = [
        {
            "id": f["properties"]["id"],
            "lon": f["geometry"]["coordinates"][0],
            "lat": f["geometry"]["coordinates"][1],
            "h": f["geometry"]["coordinates"][2],
            **{k: f["properties"][k] for k in ("sigma_n", "sigma_e", "sigma_u")},
        }
        for f in feats
    ]
    assert len(rows_gj) == 5
    _check_against_truth(rows_gj, truth)

    # GPX 1.1 through gpxpy: one waypoint per target plus the observer, UTC times from start_utc
    g = gpxpy.parse((run / "targets_fkf_cal.gpx").read_text())
    assert g.version == "1.1" and len(g.waypoints) == 6
    wp = {w.name: w for w in g.waypoints}
    for r in rows:
        assert (wp[r["id"]].latitude, wp[r["id"]].longitude, wp[r["id"]].elevation) == pytest.approx(
            (float(r["lat"]), float(r["lon"]), float(r["h"])), abs=1e-4
        )
        assert wp[r["id"]].time is not None and wp[r["id"]].time.year == 2015


def test_drive_targets_and_trajectory(drive_run):
    run, sim = drive_run
    _export(run, "-f", "csv")
    rows = _rows_csv(run / "targets_smoothed.csv")
    assert [r["id"] for r in rows] == ["T1", "T2", "T3", "T4"]
    _check_against_truth(rows, dict(zip(sim.targets.ids, sim.targets.lla)))
    res = _export(run, "-f", "gpx", "--trajectory")
    assert "121 epochs at 1 Hz" in res.output  # 120 s at 1 Hz, both ends kept
    g = gpxpy.parse((run / "trajectory_smoothed.gpx").read_text())
    (seg,) = g.tracks[0].segments
    lla = np.array([[p.latitude, p.longitude, p.elevation] for p in seg.points])
    tt = run / "trajectory_smoothed.csv"
    _export(run, "-f", "csv", "--trajectory", "--rate", "1")
    tab = _rows_csv(tt)
    t = np.array([float(r["t"]) for r in tab])
    sd = np.array([[float(r["sigma_n"]), float(r["sigma_e"]), float(r["sigma_u"])] for r in tab])
    np.testing.assert_allclose(lla, [[float(r["lat"]), float(r["lon"]), float(r["h"])] for r in tab], atol=1e-4)
    truth_lla = interpolate_positions(sim.truth.t_s + sim.t0_s, sim.truth.lla, t, 0.05)  # exported epochs are IMU samples
    e = np.array([lla_to_ned(a[None, :], b)[0] for a, b in zip(lla, truth_lla)])
    e[:, 2] = -e[:, 2]
    # 5 SD per component: 6e-7 per value, so a consistent run fails 1 in ~5000 times over these 363 values
    assert np.max(np.abs(e / sd)) < 5.0, np.max(np.abs(e / sd), axis=0)
    # and the KML track has as many vertices, the GeoJSON a LineString plus one point per epoch
    _export(run, "-f", "kml", "--trajectory")
    kml = ET.parse(run / "trajectory_smoothed.kml").getroot()
    line = kml.find(f".//{KML}LineString/{KML}coordinates").text.split()
    assert len(line) == len(tab)
    _export(run, "-f", "geojson", "--trajectory")
    gj = json.loads((run / "trajectory_smoothed.geojson").read_text())
    assert gj["features"][0]["geometry"]["type"] == "LineString" and len(gj["features"]) == 1 + len(tab)
    assert gj["features"][0]["geometry"]["coordinates"][0][:2] == pytest.approx([lla[0, 1], lla[0, 0]], abs=1e-8)


def test_outputs_stdout_modes_and_errors(drive_run, tmp_path):
    run, _ = drive_run
    old = os.umask(0o022)
    try:
        _export(run, "-f", "geojson", "-o", str(tmp_path))
    finally:
        os.umask(old)
    out = tmp_path / "targets_smoothed.geojson"
    assert stat.S_IMODE(out.stat().st_mode) == 0o644 and [p.name for p in tmp_path.iterdir()] == [out.name]  # nothing else left
    res = runner.invoke(app, ["export", str(run), "-o", "-"])  # no --format: CSV
    assert res.exit_code == 0 and list(csv.DictReader(io.StringIO(res.stdout)))[0]["id"] == "T1"
    res = runner.invoke(app, ["export", str(run), "--trajectory", "-o", str(tmp_path / "drive.kml")])  # format from the name
    assert res.exit_code == 0 and ET.parse(tmp_path / "drive.kml").getroot().tag == KML + "kml"
    for args, msg in (
        (["-f", "csv", "-s", "forward"], "no solution 'forward'; the run has: smoothed"),
        (["-f", "shp"], "expected one of csv, kml, geojson, gpx"),
        (["-f", "csv", "--trajectory", "--rate", "0"], "must be a positive number"),
        (["-f", "csv", "-o", str(tmp_path / "nope" / "x.csv")], "does not exist"),
        # audit (session 12): KML was written into a file named .csv, exit 0
        (["-f", "kml", "-o", str(tmp_path / "x.csv")], "'kml' contradicts -o "),
        (["-f", "csv", "-o", str(tmp_path / "x.json")], "'csv' contradicts -o "),
    ):
        res = runner.invoke(app, ["export", str(run), *args])
        assert res.exit_code == 2 and msg in res.output, res.output
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "x.json").exists()
    res = runner.invoke(app, ["export", str(run), "-f", "GeoJSON", "-o", str(tmp_path / "x.json")])  # .json names geojson
    assert res.exit_code == 0 and json.loads((tmp_path / "x.json").read_text())["type"] == "FeatureCollection"


def _run_with_start_utc(run, tmp_path, start_utc: str):
    """A copy of `run` whose session copy states `start_utc`: (run copy, session copy, the session.toml as it was)."""
    summary = json.loads((run / "summary.json").read_text())
    s = shutil.copytree(summary["session"]["path"], tmp_path / "s")
    toml = (s / "session.toml").read_text()
    (s / "session.toml").write_text(toml.replace("[session]\n", f'[session]\nstart_utc = "{start_utc}"\n', 1))
    r = shutil.copytree(run, tmp_path / "r", ignore=shutil.ignore_patterns("*.csv", "*.kml", "*.gpx", "*.geojson"))
    summary["session"]["path"] = str(s)
    (r / "summary.json").write_text(json.dumps(summary))
    return r, s, toml


def test_a_log_stamped_in_unix_seconds_is_dated_from_1970_with_a_note(drive_run, tmp_path):
    """navego_canada_enav (audit, session 25): t in Unix seconds and start_utc the first sample's UTC gave "after
    today" and no UTC; the contract's t may have any origin, so 1970-01-01 + t dates it, and the export says so."""
    import pyarrow.parquet as pq

    r, _, _ = _run_with_start_utc(drive_run[0], tmp_path, "2018-09-04T21:43:26Z")
    tr = pq.read_table(r / "trajectory.parquet").to_pandas()
    t0 = 1536097406.0 - float(tr["t"].min())  # the first epoch at 2018-09-04T21:43:26Z read as Unix seconds
    tr["t"] += t0
    tr.to_parquet(r / "trajectory.parquet", index=False)
    if (r / "targets.parquet").exists():
        tg = pq.read_table(r / "targets.parquet").to_pandas()
        tg[["t_start", "t_end"]] += t0
        tg.to_parquet(r / "targets.parquet", index=False)
    res = _export(r, "-f", "csv", "--trajectory")
    assert "t counts Unix seconds" in res.stderr and "after today" not in res.stderr
    row = _rows_csv(r / "trajectory_smoothed.csv")[0]
    assert row["time_utc"].startswith("2018-09-04T21:43:26"), row["time_utc"]
    _export(r, "-f", "kml", "--trajectory", "-o", str(tmp_path / "d.kml"))
    desc = ET.parse(tmp_path / "d.kml").getroot().find(f"{KML}Document/{KML}description").text
    assert "UTC as 1970-01-01 + t (t counts Unix seconds" in desc


def test_no_utc_when_start_utc_plus_t_is_after_today(drive_run, tmp_path):
    """A session whose start_utc names its first sample while t counts Unix seconds (as
    navego_canada_enav) would date every epoch decades ahead: no times, and a note why."""
    r, s, toml = _run_with_start_utc(drive_run[0], tmp_path, "2099-12-31T23:59:00Z")
    res = _export(r, "-f", "gpx", "--trajectory")
    assert "start_utc 2099-12-31T23:59:00Z + t" in res.stderr and "after today" in res.stderr
    g = gpxpy.parse((r / "trajectory_smoothed.gpx").read_text())
    assert all(p.time is None for p in g.tracks[0].segments[0].points)
    res = _export(r, "-f", "csv", "--trajectory")
    assert "time_utc" not in _rows_csv(r / "trajectory_smoothed.csv")[0]
    (s / "session.toml").write_text(toml.replace("[session]\n", '[session]\nstart_utc = "2020-01-01T00:00:00Z"\n', 1))
    res = _export(r, "-f", "csv", "--trajectory")
    assert "note:" not in res.stderr and _rows_csv(r / "trajectory_smoothed.csv")[0]["time_utc"].startswith("2020-01-01T00:00:")


def test_an_export_never_replaces_a_run_or_session_file_or_a_device(drive_run, tmp_path):
    # audit (session 10): `tpos export RUN -o RUN/summary.json` wrote GeoJSON over the run's summary.json and
    # `-o RUN/trajectory.parquet` CSV over its trajectory (exit 0; the run was gone); `-o /dev/null` as root put a
    # regular file in the device's place (the export is written beside the target and renamed over it)
    run, _ = drive_run
    session = tmp_path / "s"
    session.mkdir()
    (session / "session.toml").write_text("[session]\n")
    (session / "gps.csv").write_text("t\n")
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    own_sub = run.parent / "s" / "sub"  # the fixture's session is run/../s
    own_sub.mkdir()
    dev = tmp_path / "dev"
    os.mkfifo(dev)  # a FIFO stands for a device here (no mknod in a test)
    (tmp_path / "link.csv").symlink_to(run / "summary.json")  # a link is replaced, never written through
    for out, msg in (
        (run / "summary.json", "is the run's own file, not an export"),
        (run / "trajectory.parquet", "is the run's own file, not an export"),
        (run / "accuracy.json", "is the run's own file, not an export"),
        (run / "report.pdf", "is the run's own file, not an export"),
        (session / "gps.csv", "is inside a session directory"),
        (session / "new.kml", "is inside a session directory"),
        (own_sub / "x.csv", "is inside a session directory"),  # anywhere in the run's own session
        (dev, "is not a regular file"),
    ):
        res = runner.invoke(app, ["export", str(run), "--trajectory", "-o", str(out)])
        assert res.exit_code == 2 and msg in res.output and len(res.output.strip().splitlines()) == 1, (out, res.output)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before and stat.S_ISFIFO(dev.lstat().st_mode)
    assert (session / "gps.csv").read_text() == "t\n" and sorted(p.name for p in session.iterdir()) == ["gps.csv", "session.toml"]
    _export(run, "--trajectory", "-o", str(run / "track.json"))  # an export's own name in the run: fine
    res = runner.invoke(app, ["export", str(run), "--trajectory", "-o", str(tmp_path / "link.csv")])
    assert res.exit_code == 2 and "is the run's own file" in res.output  # the link's target is the run's summary
    assert (run / "summary.json").read_bytes() == before["summary.json"] and not any(own_sub.iterdir())
    own_sub.rmdir()


def test_a_rate_above_the_solutions_own_is_said_not_claimed(drive_run, tmp_path):
    # audit (session 10): `--rate 1e9` printed "1201 epochs at 1e+09 Hz" for a 10 Hz solution
    run, _ = drive_run
    res = _export(run, "--trajectory", "--rate", "1e9", "-o", str(tmp_path / "a.csv"))
    every = len(_rows_csv(tmp_path / "a.csv"))
    assert "at 1e+09 Hz" not in res.stdout and f"{every} epochs," in res.stdout
    assert "note: --rate 1e+09 Hz is above the solution's own rate (about 10 Hz): every epoch is exported" in res.output
    res = _export(run, "--trajectory", "--rate", "2", "-o", str(tmp_path / "b.csv"))
    assert "at 2 Hz" in res.stdout and "note:" not in res.output and len(_rows_csv(tmp_path / "b.csv")) < every


def test_a_target_export_reads_only_the_trajectorys_times_and_positions(target_run, tmp_path, monkeypatch):
    # audit (session 10): exporting the 5 targets of a simulated target hour read its whole 2.2M-row trajectory
    # (peak 0.83-0.94 GB); it reads t, lat, lon, h and solution (0.52 GB), with the same file
    import pyarrow.parquet as pq

    from tpos_cli.export import build

    run, _ = target_run
    seen = []
    real = pq.read_table

    def spy(path, *a, **k):
        if str(path).endswith("trajectory.parquet"):
            seen.append(k.get("columns"))
        return real(path, *a, **k)

    monkeypatch.setattr(pq, "read_table", spy)
    _export(run, "-o", str(tmp_path / "a.csv"))
    assert len(seen) == 1 and sorted(seen[0]) == sorted(build.TARGET_EXPORT_TRAJECTORY)
    monkeypatch.setattr(build, "TARGET_EXPORT_TRAJECTORY", None)  # the whole table, as before
    _export(run, "-o", str(tmp_path / "b.csv"))
    assert seen[1] is None and (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def test_a_run_whose_targets_table_is_empty_is_read_once(drive_run, tmp_path, monkeypatch):
    # review (session 10): an empty targets.parquet made export_run read the run twice (summary, targets,
    # innovations, and the trajectory: 5 columns, then the whole table); it reads it once, whole
    import pandas as pd
    import pyarrow.parquet as pq

    run0, _ = drive_run
    run = tmp_path / "run"
    shutil.copytree(run0, run)
    tg = pd.read_parquet(run / "targets.parquet")
    tg.iloc[:0].to_parquet(run / "targets.parquet")
    seen = []
    real = pq.read_table

    def spy(path, *a, **k):
        seen.append((Path(path).name, k.get("columns")))
        return real(path, *a, **k)

    monkeypatch.setattr(pq, "read_table", spy)
    res = _export(run, "-o", str(tmp_path / "a.csv"))
    assert [n for n, _ in seen].count("trajectory.parquet") == 1 and ("trajectory.parquet", None) in seen, seen
    assert [n for n, _ in seen].count("targets.parquet") == 1 and "trajectory" in res.stdout


def test_a_kml_explains_the_fields_it_carries_only(target_run, drive_run, tmp_path):
    # audit (session 11): a targets KML's description explained velocity, roll, pitch ... (every field an export
    # can have); a target's placemarks carry none of them
    run, _ = target_run
    _export(run, "-f", "kml", "-o", str(tmp_path / "t.kml"))
    desc = ET.parse(tmp_path / "t.kml").getroot().find(f"{KML}Document/{KML}description").text
    assert "ell95_major_m:" in desc and "n_shots:" in desc
    assert "vn:" not in desc and "roll:" not in desc and "sigma_yaw:" not in desc
    drive, _ = drive_run
    _export(drive, "-f", "kml", "--trajectory", "-o", str(tmp_path / "d.kml"))
    desc = ET.parse(tmp_path / "d.kml").getroot().find(f"{KML}Document/{KML}description").text
    assert "vn:" in desc and "roll:" in desc and "n_shots:" not in desc and "shot_chi2_dof:" not in desc
