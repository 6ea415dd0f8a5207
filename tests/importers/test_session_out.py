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
