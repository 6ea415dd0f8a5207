"""io.run_dir: summary.json's shape, checked where a run is read (`report.rundir.load_run`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from tpos_cli.cli import app
from tpos_cli.errors import InvalidInputError
from tpos_cli.io import bounded
from tpos_cli.io.run_dir import check_summary_shape
from tpos_cli.report.rundir import load_run

GOOD = {"tpos_version": "0.1.0", "session": {"name": "s", "kind": "drive", "t0": 1000.0, "duration_s": 10.0, "imu_samples": 1000},
        "pipeline": "drive-smooth", "config": {}, "timings_s": {"total": 1.0}, "warnings": [], "results": {},
        "quality": {"verdict": "ok", "reasons": [], "checks": {}}, "outputs": ["trajectory.parquet"], "accuracy_note": None}


@pytest.mark.parametrize("path, value, said", [
    (("session",), "x", "'session' must be an object, got str"),
    (("results",), [1, 2], "'results' must be an object, got list"),
    (("quality",), 5, "'quality' must be an object, got int"),
    (("warnings",), {"a": 1}, "'warnings' must be a list, got dict"),
    (("session", "t0"), "abc", "'session.t0' must be a number, got str"),
    (("session", "imu_samples"), True, "'session.imu_samples' must be a number, got bool"),
    (("quality", "reasons"), "r", "'quality.reasons' must be a list, got str"),
])
def test_a_summary_of_another_shape_is_one_line_at_the_door_of_report_and_export(tmp_path, path, value, said):
    # audit (session 9): a summary.json with 'session' as text or 'results' as a list ended `tpos report` and
    # `tpos export` in "internal error: AttributeError: 'str' object has no attribute 'get'" (exit 1)
    run = tmp_path / "run"
    run.mkdir()
    doc = json.loads(json.dumps(GOOD))
    cur = doc
    for k in path[:-1]:
        cur = cur[k]
    cur[path[-1]] = value
    (run / "summary.json").write_text(json.dumps(doc))
    with pytest.raises(InvalidInputError, match=said):
        check_summary_shape(doc, "run/summary.json")
    with pytest.raises(InvalidInputError, match=said):  # library callers get the same check (review, session 9)
        load_run(run)
    for cmd in (["report", str(run)], ["export", str(run), "-o", str(tmp_path / "x.csv")]):
        res = CliRunner().invoke(app, cmd)
        assert res.exit_code == 2 and res.output.strip() == f"error: run/summary.json: {said}: not a summary.json tpos " \
            "wrote (reprocess the session)", res.output
    assert not (tmp_path / "x.csv").exists() and sorted(p.name for p in run.iterdir()) == ["summary.json"]


def test_a_summary_as_tpos_writes_it_passes_and_other_files_are_named(tmp_path):
    check_summary_shape(GOOD, "summary.json")
    (tmp_path / "summary.json").write_text(json.dumps(GOOD))
    assert load_run(tmp_path).summary == GOOD
    with pytest.raises(InvalidInputError, match="no summary.json"):
        load_run(tmp_path / "nothing")
    (tmp_path / "summary.json").write_text("[1]")
    with pytest.raises(InvalidInputError, match="summary.json: the file must be a JSON object, got list"):
        load_run(tmp_path)
    (tmp_path / "summary.json").write_text("{")
    with pytest.raises(InvalidInputError, match="summary.json: not readable JSON"):
        load_run(tmp_path)


def test_report_and_export_read_summary_json_once(tmp_path, monkeypatch):
    # review (session 9): the CLI's door (io.run_dir.check_run_summary) and then report.rundir.load_run each read
    # summary.json; the shape check is in load_run now, so each command reads the file once
    import numpy as np
    import pandas as pd

    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps(GOOD))
    n = 50
    pd.DataFrame({"t": np.arange(n, dtype=float), "lat": 45.0 + 1e-6 * np.arange(n), "lon": np.full(n, 7.0),
                  "h": np.zeros(n), "roll": np.zeros(n), "pitch": np.zeros(n), "yaw": np.zeros(n),
                  "solution": ["smoothed"] * n}).to_parquet(run / "trajectory.parquet")
    reads = []
    real = bounded.read_bytes_bounded

    def counting(path, what, limit):
        reads.append(Path(path).name)
        return real(path, what, limit)

    monkeypatch.setattr(bounded, "read_bytes_bounded", counting)
    for cmd in (["export", str(run), "-o", str(tmp_path / "x.csv")], ["report", str(run)]):
        reads.clear()
        res = CliRunner().invoke(app, cmd)
        assert res.exit_code == 0, res.output
        assert reads.count("summary.json") == 1, (cmd[0], reads)
