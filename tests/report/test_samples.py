"""`tpos report` end to end on the bundled sessions (a drive, a target survey, a ranging run), with
their truth and with the truth removed: exit 0, at most 8 pages, page 1 the summary, readable files."""

from __future__ import annotations

import json
import os
import re
import shutil
import stat

import pandas as pd
import pytest
from typer.testing import CliRunner

from tests.helpers.paths import REPO
from tpos_cli.cli import app
from tpos_cli.pipeline import process_session
from tpos_cli.report.appendix import PAPER_LAYOUTS
from tpos_cli.report.build import make_report

runner = CliRunner()
SAMPLE_LOGS = REPO / "sample_logs"
KINDS = ("drive_outage", "target_wall", "ranging_corridor")


def _strip_truth(session):
    for p in session.glob("truth.*"):
        p.unlink()
    t = session / "targets.csv"
    if t.exists():
        tg = pd.read_csv(t)
        tg[tg["role"] != "truth"].to_csv(t, index=False)


@pytest.fixture(
    scope="module", params=[(k, truth) for k in KINDS for truth in (True, False)], ids=lambda p: f"{p[0]}-{'truth' if p[1] else 'qc'}"
)
def run(request, tmp_path_factory):
    kind, truth = request.param
    d = tmp_path_factory.mktemp(kind)
    s = shutil.copytree(SAMPLE_LOGS / kind, d / "s")
    if not truth:
        _strip_truth(s)
    return process_session(s, None, d / "run").run_dir, kind, truth


def test_report(run):
    r, kind, truth = run
    old = os.umask(0o022)
    try:
        res = runner.invoke(app, ["report", str(r)])
    finally:
        os.umask(old)
    assert res.exit_code == 0, res.output
    pages = re.search(r"(\d+) PDF pages", res.output)
    assert pages and 1 <= int(pages.group(1)) <= 8
    for n in ("accuracy.parquet", "accuracy.json", "report.pdf"):
        assert stat.S_IMODE((r / n).stat().st_mode) == 0o644
    js = json.loads((r / "accuracy.json").read_text())
    assert (js["truth"] is not None) == truth or kind == "drive_outage"  # a drive keeps its GPS fixes as (non-independent) truth
    if kind == "target_wall":
        assert [t["id"] for t in js["targets_combined"]["rows"]] == ["REF", "T1", "T2", "T3", "T4"]


def test_full_report(run):
    """`--full` appends the appendix (every segment, innovation stream, shot, the papers' layouts):
    it once failed on a target run whose paper table holds labels in pandas' own string dtype."""
    r, kind, truth = run
    res = runner.invoke(app, ["report", str(r), "--full"])
    assert res.exit_code == 0, res.output
    pages = int(re.search(r"(\d+) PDF pages", res.output).group(1))
    js = json.loads((r / "accuracy.json").read_text())
    shown = [k for k in PAPER_LAYOUTS if js["paper_tables"].get(k)]  # the papers' layouts this run has
    assert [k for k in PAPER_LAYOUTS if f"appendix_{k}" in "+".join(make_report(r, full=True).pages)] == shown
    assert pages > 1 and (kind != "target_wall" or not truth or shown == ["paper000_table4"])
