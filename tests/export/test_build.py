"""`export.build`: the default file of an export stays in the run directory whatever the run's
solution names are (they come from its own tables)."""

from __future__ import annotations

import numpy as np

from tests.report import synth
from tpos_cli.export.build import _default_path, export_run


def test_a_solution_name_cannot_lead_the_default_file_out_of_the_run(tmp_path):
    # session 7 audit: a run whose trajectory names a solution "../../../../tmp/x" was exported (with -s) to
    # RUN/trajectory_../../../../tmp/x.csv: refused only because RUN/trajectory_.. did not exist, with "-o None" in the message
    s = synth.write_session(tmp_path / "s", movement=True)
    bad = "../../../x/evil"
    traj = synth.trajectory_rows(bad, np.arange(0.0, 10.0 + 1e-9, 0.1), [0.0, 0.0, 0.0], sigma=(0.5, 0.5, 0.5))
    run = synth.write_run(tmp_path / "r", s, traj)
    res = export_run(run, "csv", solution=bad)
    assert res.path.parent == run and res.path.name.endswith("x_evil.csv") and ".." not in res.path.name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r", "s"]  # nothing written beside the run
    for name in ("a/b", "..", ".hidden", "C:\\x", "smoothed"):
        p = _default_path(run, "trajectory", name, "gpx")
        assert p.parent == run and ".." not in p.name[len("trajectory_"):-len(".gpx")], p
    assert _default_path(run, "targets", "fkf_cal", "csv").name == "targets_fkf_cal.csv"  # ordinary names unchanged


def test_csv_times_keep_the_epochs_of_a_fast_log():
    """t was written to 1 ms: a 285.7 Hz log's epochs (3.5 ms apart) came back up to 0.5 ms off
    (15 mm along track at 30 m/s, beside positions written to 0.1 mm); the UTC column was cut to ms too."""
    import io
    from datetime import UTC, datetime

    import pandas as pd

    from tpos_cli.export.build import format_csv
    from tpos_cli.report.format import utc_strings

    t = 46408.0 + np.arange(200) / 285.7
    back = pd.read_csv(io.BytesIO(format_csv(pd.DataFrame({"t": t}))))
    assert np.max(np.abs(back["t"].to_numpy() - t)) <= 5e-7
    utc = utc_strings(t, datetime(2018, 8, 3, tzinfo=UTC), 6)
    assert utc[1] == "2018-08-03T12:53:28.003500Z"
