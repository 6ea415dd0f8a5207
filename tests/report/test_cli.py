"""`tpos report` through the CLI: outputs, --json, the PDF's pages, exit code 2 without truth."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from tests.report import synth
from tpos_cli.cli import app

runner = CliRunner()


def _pdf_page_count(data: bytes) -> int:
    # matplotlib writes one uncompressed "/Type /Page" dictionary per page (and one "/Type /Pages")
    return len(re.findall(rb"/Type\s*/Page(?![a-zA-Z])", data))


def _run(tmp_path):
    s = synth.write_session(tmp_path / "s", movement=True)
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)
    traj = pd.concat([
        synth.trajectory_rows("forward", t10, [3.0, 4.0, 0.0], (0.5, -0.3, 2.0), sigma=(1.0, 1.0, 1.0)),
        synth.trajectory_rows("smoothed", t10, [0.3, 0.4, 0.0], sigma=(0.5, 0.5, 0.5)),
    ])
    rng = np.random.default_rng(3)
    inn = pd.DataFrame({"t": synth.T0 + np.arange(20.0), "solution": "forward", "kind": "gps_position",
                        "nis": rng.chisquare(3, 20), "dof": 3, "accepted": True})
    inn.loc[4, ["nis", "accepted"]] = [50.0, False]
    return synth.write_run(tmp_path / "r", s, traj, gps_outages=[[1005.0, 1012.0]], innovations=inn)


def test_report_writes_files_and_pdf_pages(tmp_path):
    r = _run(tmp_path)
    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 0, res.output
    assert "forward" in res.output and "truth.*" in res.output
    acc = pd.read_parquet(r / "accuracy.parquet")
    assert {"solution", "segment", "quantity", "rms", "p95", "cep"} <= set(acc.columns)
    js = json.loads((r / "accuracy.json").read_text())
    assert js["truth"]["trajectory"]["source"] == "truth"
    assert js["config_sha256"] == "ab" * 32 and js["health"]["nis"][0]["n_rejected"] == 1
    pdf = (r / "report.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and pdf.rstrip().endswith(b"%%EOF")
    # cover, summary, outage table, 2 segment pages, health, 1 map page (2 solutions), position error,
    # 2 attitude pages, attitude error, NIS
    from tpos_cli.report.build import make_report

    pages = make_report(r).pages
    assert pages[0] == "cover" and pages[1] == "summary"
    for kind in ("paper003_outages", "segments", "health", "trajectory", "position_error", "attitude", "attitude_error", "nis"):
        assert kind in pages
    assert pages.count("attitude") == 2
    assert _pdf_page_count((r / "report.pdf").read_bytes()) == len(pages)


def test_report_json_to_stdout(tmp_path):
    r = _run(tmp_path)
    res = runner.invoke(app, ["report", str(r), "--json"])
    assert res.exit_code == 0
    js = json.loads(res.stdout)
    h = {row["solution"]: row for row in js["headline"]}
    assert abs(h["forward"]["rms_pos_h_m"] - 5.0) < 1e-6 and abs(h["smoothed"]["rms_pos_h_m"] - 0.5) < 1e-6


def test_report_truth_override(tmp_path):
    r = _run(tmp_path)
    summary = json.loads((r / "summary.json").read_text())
    summary["session"]["path"] = str(tmp_path / "moved")
    (r / "summary.json").write_text(json.dumps(summary))
    assert runner.invoke(app, ["report", str(r)]).exit_code == 2  # session not found
    assert runner.invoke(app, ["report", str(r), "--truth", str(tmp_path / "s")]).exit_code == 0


def test_report_without_truth_exits_2(tmp_path):
    s = synth.write_session(tmp_path / "s", truth=False)
    r = synth.write_run(tmp_path / "r", s, synth.trajectory_rows("forward", np.arange(0.0, 21.0), [0.0, 0.0, 0.0]))
    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 2
    assert "no truth" in res.output
    assert not (r / "report.pdf").exists()


def test_report_not_a_run_exits_2(tmp_path):
    res = runner.invoke(app, ["report", str(tmp_path)])
    assert res.exit_code == 2 and "summary.json" in res.output
