"""Reading a run directory (report.rundir)."""


def test_load_run_refuses_a_fifo_summary_at_once(tmp_path):
    """Issue 18: RUN/summary.json read bounded by the library too (a FIFO blocked a plain read)."""
    import os

    import pytest

    from tpos_cli.errors import InvalidInputError
    from tpos_cli.report.rundir import load_run

    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this platform")
    os.mkfifo(tmp_path / "summary.json")
    with pytest.raises(InvalidInputError, match="FIFO"):
        load_run(tmp_path)
