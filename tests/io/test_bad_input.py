"""The corpus of broken sessions: each is rejected with exit 2 and one clear line, and nothing is written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from tests.helpers.sessions import write_minimal_session
from tpos_cli.cli import app

runner = CliRunner()


def _edit_csv(path: Path, fn) -> None:
    df = pd.read_csv(path)
    fn(df).to_csv(path, index=False)


def truncated_csv(s):
    text = (s / "imu.csv").read_text()
    (s / "imu.csv").write_text(text[: text.rstrip("\n").rfind(",") - 3])  # cut the last line mid-field


def wrong_delimiter(s):
    pd.read_csv(s / "imu.csv").to_csv(s / "imu.csv", index=False, sep=";")


def header_only(s):
    (s / "imu.csv").write_text((s / "imu.csv").read_text().splitlines()[0] + "\n")


def empty_file(s):
    (s / "gps.csv").write_text("")


def missing_column(s):
    _edit_csv(s / "imu.csv", lambda d: d.drop(columns=["gyro_y"]))


def text_in_numeric(s):
    lines = (s / "imu.csv").read_text().splitlines()
    f = lines[6].split(",")
    f[4] = "abc"
    lines[6] = ",".join(f)
    (s / "imu.csv").write_text("\n".join(lines) + "\n")


def nan_time(s):
    _edit_csv(s / "imu.csv", lambda d: d.assign(t=np.where(np.arange(len(d)) == 5, np.nan, d.t)))


def reversed_time(s):
    _edit_csv(s / "imu.csv", lambda d: d.iloc[::-1])


def duplicated_rows(s):
    # A block of the log written twice: time jumps back where the copy starts.
    _edit_csv(s / "imu.csv", lambda d: pd.concat([d.iloc[:300], d.iloc[200:]]))


def degrees_for_radians(s):
    def f(d):
        n = len(d)
        d["gyro_z"] = np.rad2deg(2.0 * np.sin(np.linspace(0, 20, n)))  # 2 rad/s slews logged in deg/s
        return d

    _edit_csv(s / "imu.csv", f)


def acc_in_g(s):
    _edit_csv(s / "imu.csv", lambda d: d.assign(acc_x=d.acc_x / 9.80665, acc_y=d.acc_y / 9.80665, acc_z=d.acc_z / 9.80665))


def empty_parquet(s):
    df = pd.read_csv(s / "imu.csv").iloc[:0]
    (s / "imu.csv").unlink()
    df.to_parquet(s / "imu.parquet", index=False)


def corrupt_parquet(s):
    (s / "imu.csv").unlink()
    (s / "imu.parquet").write_bytes(b"PAR1" + bytes(range(256)) * 4)


def parquet_named_csv(s):
    df = pd.read_csv(s / "gps.csv")
    df.to_parquet(s / "gps.csv", index=False)


def missing_session_toml(s):
    (s / "session.toml").unlink()


def bad_toml(s):
    (s / "session.toml").write_text("[session\nname = 1\n")


def unknown_axes(s):
    (s / "session.toml").write_text((s / "session.toml").read_text().replace('axes = "FRD"', 'axes = "FRX"'))


def left_handed_axes(s):
    (s / "session.toml").write_text((s / "session.toml").read_text().replace('axes = "FRD"', 'axes = "FRU"'))


def anchors_without_origin(s):
    text = (s / "session.toml").read_text()
    (s / "session.toml").write_text(text[: text.index("[local]")])


def latitude_out_of_range(s):
    _edit_csv(s / "gps.csv", lambda d: d.assign(lat=np.where(np.arange(len(d)) == 3, 95.0, d.lat)))


def negative_range(s):
    _edit_csv(s / "ranges.csv", lambda d: d.assign(d2=np.where(np.arange(len(d)) == 7, -1.0, d.d2)))


def missing_imu(s):
    (s / "imu.csv").unlink()


def bad_kind(s):
    (s / "session.toml").write_text((s / "session.toml").read_text().replace('kind = "drive"', 'kind = "flight"'))


def bad_fix(s):
    _edit_csv(s / "gps.csv", lambda d: d.assign(fix=np.where(np.arange(len(d)) == 2, 7, d.fix)))


def unknown_anchor(s):
    _edit_csv(s / "anchor_ranges.csv", lambda d: d.assign(id=np.where(np.arange(len(d)) == 9, "A9", d.id)))


def ranges_without_baselines(s):
    text = (s / "session.toml").read_text()
    (s / "session.toml").write_text(text[: text.index("[rangefinders]")])


def both_csv_and_parquet(s):
    pd.read_csv(s / "imu.csv").to_parquet(s / "imu.parquet", index=False)


def negative_rate(s):
    (s / "session.toml").write_text((s / "session.toml").read_text().replace("rate_hz = 100.0", "rate_hz = -100.0"))


def shots_reversed(s):
    pd.DataFrame({"id": ["T1"], "t_start": [1005.0], "t_end": [1003.0]}).to_csv(s / "shots.csv", index=False)


def bad_target_role(s):
    pd.DataFrame({"id": ["T1"], "lat": [45.0], "lon": [-73.0], "h": [10.0], "role": ["guess"]}).to_csv(s / "targets.csv", index=False)


def bad_lever_arm(s):
    (s / "session.toml").write_text((s / "session.toml").read_text() + "\n[gps]\nlever_arm_m = [0.1, 0.2]\n")


def negative_odometry_speed(s):
    _edit_csv(s / "odometry.csv", lambda d: d.assign(speed_mps=np.where(np.arange(len(d)) == 4, -3.0, d.speed_mps)))


def bad_mounting(s):
    (s / "session.toml").write_text((s / "session.toml").read_text().replace("[imu]\n", "[imu]\nmounting_rpy_deg = [0.0, 0.0]\n"))


def _toml_replace(s, old, new):
    text = (s / "session.toml").read_text()
    assert old in text
    (s / "session.toml").write_text(text.replace(old, new, 1))


def start_before_gps_epoch(s):
    _toml_replace(s, 'kind = "drive"', 'kind = "drive"\nstart_utc = 1500-01-01T00:00:00Z')


def clock_offset_1e308(s):
    (s / "session.toml").write_text((s / "session.toml").read_text() + "\n[time]\ngps_offset_s = 1e308\n")


def acc_noise_1e308(s):
    _toml_replace(s, "[imu]\n", "[imu]\nacc_noise_mg = 1e308\n")


def negative_bias_sd(s):
    _toml_replace(s, "[imu]\n", "[imu]\ngyro_bias_dph = -5.0\n")


def baseline_1e308(s):
    _toml_replace(s, "baseline_12_m = 0.2", "baseline_12_m = 1e308")  # overflowed the target chain: internal error


def lever_arm_in_mm(s):
    (s / "session.toml").write_text((s / "session.toml").read_text() + "\n[gps]\nlever_arm_m = [1500.0, 0.0, 0.0]\n")


# (case, session options, file the message must name, column it must name or None)
CASES = [
    (truncated_csv, {}, "imu.csv", None),
    (wrong_delimiter, {}, "imu.csv", None),
    (header_only, {}, "imu.csv", None),
    (empty_file, {}, "gps.csv", None),
    (missing_column, {}, "imu.csv", "gyro_y"),
    (text_in_numeric, {}, "imu.csv", "acc_x"),
    (nan_time, {}, "imu.csv", "t"),
    (reversed_time, {}, "imu.csv", "t"),
    (duplicated_rows, {}, "imu.csv", "t"),
    (degrees_for_radians, {}, "imu.csv", "gyro_z"),  # audit (session 25): named gyro_x, the column in deg/s is gyro_z
    (acc_in_g, {}, "imu.csv", "acc_x"),
    (empty_parquet, {}, "imu.parquet", None),
    (corrupt_parquet, {}, "imu.parquet", None),
    (parquet_named_csv, {}, "gps.csv", None),
    (missing_session_toml, {}, "session.toml", None),
    (bad_toml, {}, "session.toml", None),
    (unknown_axes, {}, "session.toml", None),
    (left_handed_axes, {}, "session.toml", None),
    (anchors_without_origin, {"with_anchors": True}, "session.toml", None),
    (latitude_out_of_range, {}, "gps.csv", "lat"),
    (negative_range, {"with_ranges": True}, "ranges.csv", "d2"),
    (missing_imu, {}, "imu.*", None),
    (bad_kind, {}, "session.toml", None),
    (bad_fix, {}, "gps.csv", "fix"),
    (unknown_anchor, {"with_anchors": True}, "anchor_ranges.csv", "id"),
    (ranges_without_baselines, {"with_ranges": True}, "session.toml", None),
    (both_csv_and_parquet, {}, "imu.*", None),
    (negative_rate, {}, "session.toml", None),
    (shots_reversed, {}, "shots.csv", "t_end"),
    (bad_target_role, {}, "targets.csv", "role"),
    (bad_lever_arm, {}, "session.toml", None),
    (negative_odometry_speed, {"with_odometry": True}, "odometry.csv", "speed_mps"),
    (bad_mounting, {}, "session.toml", None),
    (start_before_gps_epoch, {}, "session.toml", None),
    (clock_offset_1e308, {}, "session.toml", None),
    (acc_noise_1e308, {}, "session.toml", None),
    (negative_bias_sd, {}, "session.toml", None),
    (baseline_1e308, {"with_ranges": True}, "session.toml", None),
    (lever_arm_in_mm, {}, "session.toml", None),
]


@pytest.mark.parametrize("case,opts,fname,column", CASES, ids=[c[0].__name__ for c in CASES])
def test_broken_session_is_rejected_cleanly(tmp_path, case, opts, fname, column):
    s = write_minimal_session(tmp_path / "s", **opts)
    case(s)
    before = {p.name: p.read_bytes() for p in s.iterdir()}

    res = runner.invoke(app, ["validate", str(s)])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert fname in lines[0]
    if column is not None:
        assert f"column '{column}'" in lines[0]
    assert "Traceback" not in res.output

    run = tmp_path / "run"
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(run)])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and res.exception is None or isinstance(res.exception, SystemExit)
    assert not run.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".run")]  # no temporary leftovers
    assert {p.name: p.read_bytes() for p in s.iterdir()} == before  # the input is untouched


def test_corpus_has_at_least_twenty_kinds():
    assert len(CASES) >= 20


@pytest.mark.parametrize("case, opts, message", [
    (start_before_gps_epoch, {}, "[session] start_utc 1500-01-01T00:00:00+00:00 is outside 1980-01-06"),
    (clock_offset_1e308, {}, "[time] gps_offset_s 1e+308 s is not a clock offset"),
    (acc_noise_1e308, {}, "[imu] acc_noise_mg = 1e+308 is outside 0 to 1000"),
    (negative_bias_sd, {}, "[imu] gyro_bias_dph = -5.0 is outside 0 to 36000"),
    (baseline_1e308, {"with_ranges": True}, "[rangefinders] baseline_12_m = 1e+308 is outside 0 to 10"),
    (lever_arm_in_mm, {}, "[gps] lever_arm_m [1500.0, 0.0, 0.0] has a component beyond 100 m"),
], ids=lambda v: v.__name__ if callable(v) else None)
def test_session_toml_nonsense_is_named(tmp_path, case, opts, message):
    s = write_minimal_session(tmp_path / "s", **opts)
    case(s)
    res = runner.invoke(app, ["validate", str(s)])
    assert res.exit_code == 2 and message in res.stderr, res.stderr
