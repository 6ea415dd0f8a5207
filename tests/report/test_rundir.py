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


def _synthetic_run(tmp_path, alter):
    import numpy as np

    from tests.report import synth

    s = synth.write_session(tmp_path / "s", movement=True)
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)
    fwd = synth.trajectory_rows("forward", t10, [3.0, 4.0, 0.0], sigma=(1.0, 1.0, 1.0))
    alter(fwd)
    return synth.write_run(tmp_path / "r", s, fwd)


def _refused(run, match):
    import pytest

    from tpos_cli.errors import InvalidInputError
    from tpos_cli.report.rundir import load_run

    for frames in (True, False):  # DataFrames (`tpos export`) and Columns (the report): the same refusal
        with pytest.raises(InvalidInputError, match=match):
            load_run(run, frames=frames)


def test_an_inf_where_tpos_writes_numbers_is_refused_with_its_row(tmp_path):
    def alter(df):
        df.loc[4, "h"] = float("inf")

    _refused(_synthetic_run(tmp_path, alter), r"trajectory.parquet: column 'h', row 5: inf")


def test_text_where_tpos_writes_numbers_is_refused(tmp_path):
    def alter(df):
        df["lat"] = df["lat"].astype(str)

    _refused(_synthetic_run(tmp_path, alter), r"trajectory.parquet: column 'lat': object where tpos writes numbers")


def test_a_solution_without_any_position_is_refused(tmp_path):
    """It was an internal error (IndexError in qc.separation); export says the same in its words."""

    def alter(df):
        df["lat"] = float("nan")

    _refused(_synthetic_run(tmp_path, alter), r"column 'lat': solution 'forward' has no epoch with a position")


def test_an_empty_solution_label_is_refused_with_its_row(tmp_path):
    # audit (session 10): a trajectory whose solution column is null was an internal IndexError in report and export
    def alter(df):
        df["solution"] = None

    _refused(_synthetic_run(tmp_path, alter), r"trajectory.parquet: column 'solution', row 1: empty")


def test_a_sigma_whose_square_overflows_is_refused_with_its_row(tmp_path):
    # audit (session 10): sigma_n = 1e300 (or inf) in a trajectory ran the report with a dozen RuntimeWarning lines
    # ("overflow encountered in square") and exit 0; columns beyond the required ones are checked too
    def alter(df):
        df.loc[7, "sigma_n"] = 1e300

    _refused(_synthetic_run(tmp_path, alter), r"column 'sigma_n', row 8: 1e\+300 is not a value tpos writes")

    def alter_inf(df):
        df.loc[2, "sigma_e"] = float("-inf")

    _refused(_synthetic_run(tmp_path / "b", alter_inf), r"column 'sigma_e', row 3: -inf is not a value tpos writes")
