"""Importers: the session directory they write (`importers.session_out`)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tpos_cli.importers import session_out


def test_an_interrupted_table_write_leaves_no_temporary_and_the_old_table(tmp_path, monkeypatch):
    # Ctrl-C (or a full disk) while a table was written left '.imu.parquet.tmp' in the user's session
    imu = pd.DataFrame({"t": np.arange(5.0), **{c: np.zeros(5) for c in ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y")},
                        "acc_z": np.full(5, -9.8)})
    toml = {"session": {"kind": "drive"}, "imu": {"axes": "FRD", "rate_hz": 1.0}}
    session_out.write_session(tmp_path / "s", {"imu": imu}, toml)
    before = {p.name: p.read_bytes() for p in (tmp_path / "s").iterdir()}

    def interrupted(self, path, *a, **k):
        open(path, "wb").write(b"PAR1 half")
        raise KeyboardInterrupt

    monkeypatch.setattr(pd.DataFrame, "to_parquet", interrupted)
    with pytest.raises(KeyboardInterrupt):
        session_out.write_session(tmp_path / "s", {"imu": imu.assign(t=imu["t"] + 1)}, toml, force=True)
    assert {p.name: p.read_bytes() for p in (tmp_path / "s").iterdir()} == before


def test_an_import_goes_into_a_session_or_a_new_or_empty_directory_only(tmp_path):
    # audit (session 10): `tpos import ubx X -o s/../../../../etc` (run as root) wrote gps.csv and session.toml into /etc:
    # any existing directory took a session's files
    from tpos_cli.errors import InvalidInputError
    from tpos_cli.importers.session_out import write_session

    gps = pd.DataFrame({"t": [0.0, 1.0], "lat": [45.0, 45.0], "lon": [7.0, 7.0], "h": [1.0, 1.0], "fix": [2, 2]})
    other = tmp_path / "raw"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(InvalidInputError, match="holds other files and is not a session"):
        write_session(other, {"gps": gps}, {})
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert [p.name for p in write_session(empty, {"gps": gps}, {})] == ["gps.csv", "session.toml"]
    assert [p.name for p in write_session(tmp_path / "new", {"gps": gps}, {})] == ["gps.csv", "session.toml"]
    imu = pd.DataFrame({"t": [0.0, 0.01], **{c: [0.0, 0.0] for c in ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y")},
                        "acc_z": [-9.8, -9.8]})
    assert [p.name for p in write_session(empty, {"imu": imu}, {})] == ["imu.parquet", "session.toml"]  # a session now
