"""Export metadata read from the run's session: bounded, never blocking."""

import os

import pytest

from tpos_cli.export.meta import read_start_utc


def test_start_utc_of_a_session(tmp_path):
    (tmp_path / "session.toml").write_text('[session]\nname = "s"\nkind = "drive"\nstart_utc = "2024-05-01T12:00:00Z"\n')
    assert read_start_utc(tmp_path).isoformat() == "2024-05-01T12:00:00+00:00"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_fifo_session_toml_gives_none_without_blocking(tmp_path):
    """A FIFO named session.toml (issue 18) would block a plain read forever: it is refused at once."""
    os.mkfifo(tmp_path / "session.toml")
    assert read_start_utc(tmp_path) is None
