"""Session loading: valid sessions in both formats, recoverable oddities counted, frames and clocks."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from tests.helpers.sessions import G, write_minimal_session
from tpos_cli.errors import InvalidInputError
from tpos_cli.session import load_imu, load_session

EXCERPTS = Path(__file__).parent / "data" / "real_excerpts"


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_minimal_session_loads(tmp_path, fmt):
    s = load_session(write_minimal_session(tmp_path / "s", fmt=fmt, with_ranges=True))
    assert s.meta.kind == "drive" and s.t0_s == 1000.0
    assert s.imu.t_s[0] == 0.0 and s.imu.t_s.size == 1000
    assert_allclose(np.median(s.imu.acc_b_mps2[:, 2]), -G, atol=0.01)  # FRD: z down reads -g at rest
    assert s.gps.t_s.size == 10 and s.gps.valid.all()
    assert s.ranges.range_m.shape == (100, 3)
    assert s.counts == {} and s.warnings == ()
    assert set(s.file_hashes) >= {"session.toml", f"imu.{fmt}", f"gps.{fmt}"}


@pytest.mark.parametrize("name", sorted(p.name for p in EXCERPTS.iterdir() if (p / "session.toml").exists()))
def test_real_sessions_written_by_other_tools_validate(name):
    s = load_session(EXCERPTS / name)
    assert s.imu.t_s.size > 100 and not s.warnings
    # Every real log here is right-side up at its start: gravity on the body's down axis (FRD) reads -g.
    assert_allclose(np.linalg.norm(np.median(s.imu.acc_b_mps2[:50], axis=0)), G, rtol=0.05)


def test_axes_rotate_into_frd(tmp_path):
    d = write_minimal_session(tmp_path / "s")
    imu = pd.read_csv(d / "imu.csv")
    # Re-log the same motion in RFU axes: x = right (FRD y), y = forward (FRD x), z = up (-FRD z).
    rfu = imu.rename(columns={"acc_x": "acc_y", "acc_y": "acc_x", "gyro_x": "gyro_y", "gyro_y": "gyro_x"})
    rfu["acc_z"] *= -1
    rfu["gyro_z"] *= -1
    rfu.to_csv(d / "imu.csv", index=False)
    (d / "session.toml").write_text((d / "session.toml").read_text().replace('"FRD"', '"RFU"'))
    s = load_session(d)
    assert_allclose(s.imu.acc_b_mps2, imu[["acc_x", "acc_y", "acc_z"]].to_numpy(), atol=1e-12)
    assert_allclose(s.imu.gyro_b_rps, imu[["gyro_x", "gyro_y", "gyro_z"]].to_numpy(), atol=1e-12)


def test_recoverable_oddities_are_counted(tmp_path):
    d = write_minimal_session(tmp_path / "s")
    imu = pd.read_csv(d / "imu.csv")
    imu.loc[10, "gyro_x"] = np.nan                      # an isolated NaN sample
    imu = pd.concat([imu.iloc[:51], imu.iloc[50:]])     # one duplicated stamp
    imu = imu.drop(index=range(500, 540))               # a 0.4 s gap
    imu.to_csv(d / "imu.csv", index=False)
    gps = pd.read_csv(d / "gps.csv")
    gps.loc[[3, 4, 5], "fix"] = 0                       # three rows without a fix: an outage from 2 to 6 s
    gps.loc[[3, 4, 5], ["lat", "lon", "h"]] = np.nan
    gps.to_csv(d / "gps.csv", index=False)
    s = load_session(d)
    assert s.counts["imu_nan_samples"] == 1
    assert s.counts["duplicate_stamps_imu"] == 1
    assert s.counts["imu_gaps"] == 1 and s.imu_gaps_s.shape == (1, 2)
    assert s.counts["gps_no_fix_rows"] == 3
    assert_allclose(s.gps_outages_s, [[2.0, 6.0]])
    assert s.imu.t_s.size == 1000 - 1 - 40
    assert len(s.warnings) == 3


def test_time_offsets_are_added(tmp_path):
    d = write_minimal_session(tmp_path / "s", with_ranges=True)
    (d / "session.toml").write_text((d / "session.toml").read_text() + "\n[time]\ngps_offset_s = 0.25\nranges_offset_s = -0.1\n")
    s = load_session(d)
    assert_allclose(s.gps.t_s[:2], [0.25, 1.25])
    assert_allclose(s.ranges.t_s[:2], [-0.1, 0.0], atol=1e-12)


def test_anchors_in_enu_and_lla_agree(tmp_path):
    s = load_session(write_minimal_session(tmp_path / "s", with_anchors=True))
    assert_allclose(s.anchors.ned_m[1], [0.0, 10.0, -2.0], atol=1e-9)
    assert s.anchor_ranges.range_m.size == 400 and set(s.anchor_ranges.anchor) == {0, 1, 2, 3}


# --- the contract's optional odometry table and [imu] mounting_rpy_deg ---------------------------

def test_real_odometry_excerpt_loads_on_the_imu_clock():
    """comma2k19's CAN speed (written by another tool) becomes Session.odometry, on the IMU clock."""
    d = EXCERPTS / "comma2k19_seg40"
    raw = pd.read_csv(d / "odometry.csv")
    s = load_session(d)
    assert s.odometry is not None and s.odometry.t_s.size == len(raw)
    assert_allclose(s.odometry.t_s, raw["t"].to_numpy() - s.t0_s, atol=1e-9)
    assert_allclose(s.odometry.speed_mps, raw["speed_mps"].to_numpy())
    assert "odometry.csv" in s.file_hashes
    assert s.meta.mounting_rpy_deg is None  # absent: unknown, not zero


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_odometry_in_both_formats_with_offset_and_nan(tmp_path, fmt):
    d = write_minimal_session(tmp_path / "s", fmt=fmt, with_odometry=True)
    odo = pd.read_csv(d / "odometry.csv") if fmt == "csv" else pd.read_parquet(d / "odometry.parquet")
    odo.loc[[3, 4], "speed_mps"] = np.nan
    odo.loc[10, "speed_mps"] = 2.5
    odo.to_csv(d / "odometry.csv", index=False) if fmt == "csv" else odo.to_parquet(d / "odometry.parquet", index=False)
    (d / "session.toml").write_text((d / "session.toml").read_text() + "\n[time]\nodometry_offset_s = 0.125\n")
    s = load_session(d)
    assert s.odometry.t_s.size == len(odo) - 2
    assert s.counts["odometry_nan_samples"] == 2 and any("odometry" in w for w in s.warnings)
    # Rows 0..2 kept, then 5.. : row 10 of the file is index 8 of the kept rows.
    assert s.odometry.speed_mps[8] == 2.5
    assert_allclose(s.odometry.t_s[:3], np.arange(3) / 50.0 + 0.125)


@pytest.mark.parametrize("edit, message", [
    (lambda o: o.assign(speed_mps=np.where(np.arange(len(o)) == 7, -0.4, o.speed_mps)), "column 'speed_mps', row 8: speed -0.4 m/s is negative"),
    (lambda o: o.assign(t=o.t + 3600.0), "no odometry row falls within the IMU's time span"),
    (lambda o: o.iloc[::-1], "column 't', row 2: time goes backwards"),
    (lambda o: o.drop(columns=["speed_mps"]), "column 'speed_mps': required column is missing"),
    (lambda o: o.assign(speed_mps=np.nan), "no row carries a speed value"),
    # audit (session 13): both were read with exit 0 (one row of all kept; the first of two speed columns)
    (lambda o: o.assign(t=10.0), "rows repeat the time stamp before them: t cannot resolve the samples"),
    (lambda o: pd.concat([o, o[["speed_mps"]] * 2.0], axis=1), "column 'speed_mps': the column appears 2 times in the header"),
])
def test_bad_odometry_is_refused(tmp_path, edit, message):
    d = write_minimal_session(tmp_path / "s", with_odometry=True)
    edit(pd.read_csv(d / "odometry.csv")).to_csv(d / "odometry.csv", index=False)
    with pytest.raises(InvalidInputError) as exc:
        load_session(d)
    assert "odometry.csv" in str(exc.value) and message in str(exc.value)


def test_mounting_rpy_deg_read_when_present(tmp_path):
    d = write_minimal_session(tmp_path / "s")
    (d / "session.toml").write_text((d / "session.toml").read_text().replace("[imu]\n", "[imu]\nmounting_rpy_deg = [0.0, -6.8, 5.4]\n"))
    s = load_session(d)
    assert s.meta.mounting_rpy_deg.shape == (3,)
    assert_allclose(s.meta.mounting_rpy_deg, [0.0, -6.8, 5.4])
    assert load_session(write_minimal_session(tmp_path / "t")).meta.mounting_rpy_deg is None


@pytest.mark.parametrize("value, message", [
    ("[0.0, 1.0]", "must be three finite numbers"),
    ('"0,0,0"', "must be three finite numbers"),
    ("[0.0, nan, 0.0]", "must be three finite numbers"),
    ("[0.0, 1e308, 0.0]", "pitch 1e+308 is outside ±90 degrees"),
    ("[0.0, 95.0, 0.0]", "pitch 95 is outside ±90 degrees"),
    ("[200.0, 0.0, 0.0]", "roll 200 is outside ±180 degrees"),
])
def test_bad_mounting_rpy_deg_is_refused(tmp_path, value, message):
    d = write_minimal_session(tmp_path / "s")
    (d / "session.toml").write_text((d / "session.toml").read_text().replace("[imu]\n", f"[imu]\nmounting_rpy_deg = {value}\n"))
    with pytest.raises(InvalidInputError) as exc:
        load_session(d)
    assert "[imu] mounting_rpy_deg" in str(exc.value) and message in str(exc.value)


def test_truth_is_read_for_reports_only(tmp_path):
    """`load_session(with_truth=False)` (what `tpos process` uses) leaves the truth table unread, so a
    broken truth file is the report's problem, not the processing's; the full load still refuses it."""
    d = write_minimal_session(tmp_path / "s")
    (d / "truth.csv").write_text("t,lat,lon,h\n0.0,45.0,7.0,not-a-number\n")
    with pytest.raises(InvalidInputError, match="truth"):
        load_session(d)
    s = load_session(d, with_truth=False)
    assert s.truth is None and s.imu.t_s.size > 0


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_session_without_its_imu_and_the_imu_loaded_later(tmp_path, fmt):
    """`with_imu=False` (reports of a processed run) reads the IMU's times only: the same t0, gaps,
    hashes and other tables; `load_imu` then gives the IMU the full load gives."""
    d = write_minimal_session(tmp_path / "s", fmt=fmt, with_ranges=True)
    full, lite = load_session(d), load_session(d, with_imu=False)
    assert lite.imu is None and lite.t0_s == full.t0_s and lite.file_hashes == full.file_hashes
    np.testing.assert_array_equal(lite.imu_gaps_s, full.imu_gaps_s)
    np.testing.assert_array_equal(lite.gps.t_s, full.gps.t_s)
    imu = load_imu(lite)
    for a in ("t_s", "gyro_b_rps", "acc_b_mps2"):
        np.testing.assert_array_equal(getattr(imu, a), getattr(full.imu, a))
    assert load_imu(full) is full.imu


def test_unknown_session_toml_keys_are_warned_with_a_suggestion(tmp_path):
    """The contract ignores keys it does not define, but a misspelt one would silently lose its
    setting: each unknown section or key is a warning naming it, with the nearest known name."""
    import shutil

    d = tmp_path / "s"
    shutil.copytree(Path(__file__).parent.parent / "sample_logs" / "drive_outage", d)
    toml = (d / "session.toml").read_text()
    (d / "session.toml").write_text(toml.replace("[imu]\n", "[imu]\ngyro_noise_dsp = 0.1\n") + "\n[imu2]\nfoo = 1\n")
    w = load_session(d, with_imu=False).warnings
    assert "session.toml: [imu] gyro_noise_dsp: unknown key, ignored (did you mean gyro_noise_dps?)" in w
    assert "session.toml: [imu2]: unknown section, ignored (did you mean [imu]?)" in w
    assert not [x for x in load_session(Path(__file__).parent.parent / "sample_logs" / "drive_outage", with_imu=False).warnings
                if "unknown" in x]


def test_session_toml_keys_have_one_source():
    # review (session 8): session._known_keys kept a second list of session.toml's keys beside the parser's;
    # now schema.SESSION_TOML_KEYS is the one list (sections, unknown-key warnings, the [imu] noise figures)
    import dataclasses

    from tpos_cli import schema, session

    assert session.SECTIONS == tuple(schema.SESSION_TOML_KEYS)
    assert tuple(f.name for f in dataclasses.fields(session.ImuNoise)) == schema.IMU_NOISE_KEYS
    assert all(k in schema.SESSION_TOML_KEYS[sec] for sec, k in session.PLAUSIBLE_SESSION_VALUES)
    doc = (Path(__file__).parent.parent / "docs" / "log-format.md").read_text()
    assert [(sec, k) for sec, keys in schema.SESSION_TOML_KEYS.items() if sec != "time" for k in keys
            if k not in doc or f"[{sec}]" not in doc] == []


def _refusal(d) -> str:
    with pytest.raises(InvalidInputError) as exc:
        load_session(d)
    assert len(exc.value.problems) == 1, exc.value.problems
    return str(exc.value.problems[0])


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_hostile_values_are_refused_with_file_column_and_row(tmp_path, fmt):
    # audit (session 9): an inf in the IMU, a GPS velocity or an odometry speed was dropped as "empty/NaN" or used;
    # one 1e300 gyro sample ended in "internal error: LinAlgError"; integer nanoseconds in t passed validate; a
    # 1e6 m/s odometry speed was used
    def session(name, table, change, **kw):
        d = write_minimal_session(tmp_path / f"{name}_{fmt}", fmt=fmt, **kw)
        f = d / f"{table}.{fmt}"
        df = pd.read_csv(f) if fmt == "csv" else pd.read_parquet(f)
        df = change(df)
        df.to_csv(f, index=False) if fmt == "csv" else df.to_parquet(f, index=False)
        return d

    def at(col, row, val):
        def change(df):
            df[col] = df[col].astype(float)
            df.loc[row, col] = val
            return df
        return change

    assert _refusal(session("inf", "imu", at("acc_z", 7, np.inf))).endswith(
        "imu." + fmt + ": column 'acc_z', row 8: inf is not a measurement (a missing value is an empty cell or NaN)")
    assert "column 'vn', row 3: -inf is not a measurement" in _refusal(
        session("vn", "gps", lambda df: at("vn", 2, -np.inf)(df.assign(vn=0.0, ve=0.0, vd=0.0))))
    assert "column 'speed_mps', row 5: inf is not a measurement" in _refusal(
        session("odo_inf", "odometry", at("speed_mps", 4, np.inf), with_odometry=True))
    assert "column 'gyro_x', row 10: 1e+300 rad/s is beyond any gyro's range" in _refusal(
        session("huge", "imu", at("gyro_x", 9, 1e300)))
    assert "column 'mag_y', row 3: 1000000000.0 µT is beyond any magnetometer's range" in _refusal(
        session("mag", "imu", lambda df: at("mag_y", 2, 1e9)(df.assign(mag_x=20.0, mag_y=0.0, mag_z=40.0))))
    assert "column 'speed_mps', row 5: speed 1000000.0 m/s is beyond any wheeled vehicle's" in _refusal(
        session("odo_fast", "odometry", at("speed_mps", 4, 1e6), with_odometry=True))
    assert "column 't', row 2: samples are 1e+07 apart with [imu] rate_hz = 100: t is in nanoseconds" in _refusal(
        session("ns", "imu", lambda df: df.assign(t=(df["t"] * 1e9).round().astype("int64"))))


def test_session_toml_arrays_take_numbers_only(tmp_path):
    # audit (session 9): mounting_rpy_deg = [true, 0, 0] was read as [1, 0, 0]; ["1", "2", "3"] as numbers
    for i, val in enumerate(("[true, 0.0, 0.0]", '["1", "2", "3"]')):
        d = write_minimal_session(tmp_path / f"s{i}")
        toml = (d / "session.toml").read_text()
        (d / "session.toml").write_text(toml.replace("[imu]\n", f"[imu]\nmounting_rpy_deg = {val}\n"))
        assert "[imu] mounting_rpy_deg must be three finite numbers" in _refusal(d)


def test_gps_on_another_clock_gets_one_answer_from_validate_and_process(tmp_path):
    """audit (session 11): GPS `t` in seconds of the GPS week beside an IMU on the logger's clock: `tpos
    validate` warned (exit 0) and `tpos process` refused it (exit 2). Both now refuse a drive session with
    the same line (file, column, the first fix's row); a ranging or target session, whose chain may run
    without the GPS, keeps the warning."""
    from typer.testing import CliRunner

    from tpos_cli.cli import app

    d = write_minimal_session(tmp_path / "s")
    gps = pd.read_csv(d / "gps.csv")
    gps.assign(t=gps.t - gps.t.iloc[0] + 345600.0, fix=np.where(np.arange(len(gps)) < 2, 0, gps.fix)).to_csv(
        d / "gps.csv", index=False)
    with pytest.raises(InvalidInputError) as exc:
        load_session(d)
    assert "gps.csv: column 't', row 3: no position fix falls within the IMU's time span (fixes 345602.000-" in str(exc.value)
    runner = CliRunner()
    checked = runner.invoke(app, ["validate", str(d)])
    processed = runner.invoke(app, ["process", str(d), "-o", str(tmp_path / "run")])
    assert checked.exit_code == processed.exit_code == 2
    line = "gps.csv: column 't', row 3: no position fix falls within the IMU's time span"
    assert line in checked.output and line in processed.output and not (tmp_path / "run").exists()

    r = write_minimal_session(tmp_path / "r", with_anchors=True)
    gps = pd.read_csv(r / "gps.csv")
    gps.assign(t=gps.t + 345600.0).to_csv(r / "gps.csv", index=False)
    s = load_session(r)
    assert s.meta.kind == "ranging" and s.counts["gps_outside_imu_span"] == 1
    assert any("no GPS fix falls within the IMU's time span" in w for w in s.warnings)


@pytest.mark.parametrize("rows,lat,lon,hint", [(slice(None), -105.1, 40.1, True),  # the columns exchanged
                                                (slice(3, 4), 95.0, -73.0, False),   # one glitch, lon far from a latitude
                                                (slice(3, 4), 95.0, 40.1, False),    # one glitch
                                                (slice(None), 95.0, 120.0, False)])  # exchanged would not be in range
def test_latitude_out_of_range_says_when_lat_and_lon_are_exchanged(tmp_path, rows, lat, lon, hint):
    # audit (session 25): the RTK drive with its lat and lon columns exchanged read "-105.1474483 is outside
    # ±90 degrees" and no more; when every lat is a longitude and every lon a latitude, the exchange is the
    # likely mistake.
    d = write_minimal_session(tmp_path / "s")
    gps = pd.read_csv(d / "gps.csv")
    gps.loc[gps.index[rows], "lat"] = lat
    gps["lon"] = lon
    gps.to_csv(d / "gps.csv", index=False)
    with pytest.raises(InvalidInputError, match="outside ±90 degrees") as exc:
        load_session(d)
    assert ("lat and lon look exchanged" in str(exc.value)) == hint


def test_dropped_and_duplicate_samples_name_their_first_row(tmp_path):
    # audit (session 25): "imu.csv: 1 samples with empty/NaN gyro or acc values dropped" named no row, so a user
    # could not find the sample in a 60 000-line file; rows count from 1 over the data rows, as in the refusals.
    d = write_minimal_session(tmp_path / "s")
    imu = pd.read_csv(d / "imu.csv")
    imu.loc[[5, 7], "acc_y"] = np.nan
    imu.loc[12, "t"] = imu.loc[11, "t"]
    imu.to_csv(d / "imu.csv", index=False)
    w = load_session(d).warnings
    assert "imu.csv: 2 samples with empty/NaN gyro or acc values dropped (the first at row 6)" in w, w
    assert "imu.csv: 1 duplicate time stamps (the first at row 13); the first sample of each kept" in w, w
