"""Session loading: valid sessions in both formats, recoverable oddities counted, frames and clocks."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from tests.helpers.sessions import G, write_minimal_session
from tpos_cli.session import load_session

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
