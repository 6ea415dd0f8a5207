"""`tpos report` through the CLI: outputs, --json, the PDF's pages, exit code 2 without truth."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from tests.helpers.paths import REPO
from tests.report import synth
from tpos_cli.cli import app

runner = CliRunner()


def _pdf_page_count(data: bytes) -> int:
    # matplotlib writes one uncompressed "/Type /Page" dictionary per page (and one "/Type /Pages")
    return len(re.findall(rb"/Type\s*/Page(?![a-zA-Z])", data))


def _run(tmp_path):
    s = synth.write_session(tmp_path / "s", movement=True)
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)
    traj = pd.concat(
        [
            synth.trajectory_rows("forward", t10, [3.0, 4.0, 0.0], (0.5, -0.3, 2.0), sigma=(1.0, 1.0, 1.0)),
            synth.trajectory_rows("smoothed", t10, [0.3, 0.4, 0.0], sigma=(0.5, 0.5, 0.5)),
        ]
    )
    rng = np.random.default_rng(3)
    inn = pd.DataFrame(
        {
            "t": synth.T0 + np.arange(20.0),
            "solution": "forward",
            "kind": "gps_position",
            "nis": rng.chisquare(3, 20),
            "dof": 3,
            "accepted": True,
        }
    )
    inn.loc[4, ["nis", "accepted"]] = [50.0, False]
    return synth.write_run(tmp_path / "r", s, traj, gps_outages=[[1005.0, 1012.0]], innovations=inn)


def test_report_writes_files_and_pdf_pages(tmp_path):
    r = _run(tmp_path)
    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 0, res.output
    assert "forward" in res.output and "truth.*" in res.output and "verdict: no verdict recorded" in res.output
    # audit (session 25): a drive's line gave yaw only; the forward solution's errors are 0.5/-0.3/2 deg (+- 1e-3)
    line = next(ln for ln in res.stdout.splitlines() if ln.strip().startswith("forward ("))
    assert line.endswith("attitude RMS roll 0.5, pitch 0.3, yaw 2 deg"), line
    acc = pd.read_parquet(r / "accuracy.parquet")
    assert {"solution", "segment", "quantity", "rms", "p95", "cep"} <= set(acc.columns)
    js = json.loads((r / "accuracy.json").read_text())
    assert js["truth"]["trajectory"]["source"] == "truth" and js["quality"] is None
    assert js["config_sha256"] == "ab" * 32 and js["health"]["nis"][0]["n_rejected"] == 1
    pdf = (r / "report.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and pdf.rstrip().endswith(b"%%EOF")
    from tpos_cli.report.build import make_report

    pages = make_report(r).pages
    sections = "+".join(pages).split("+")
    assert pages[0] == "summary"  # page 1 is the summary alone
    for name in ("accuracy", "innovations", "attitude", "figures_truth", "figures_outages", "figures_estimated", "warnings"):
        assert name in sections, name
    assert len(pages) <= 8 and _pdf_page_count((r / "report.pdf").read_bytes()) == len(pages)
    full = make_report(r, full=True).pages
    assert len(full) > len(pages) and "appendix_segments" in "+".join(full)


def test_report_json_to_stdout(tmp_path):
    r = _run(tmp_path)
    res = runner.invoke(app, ["report", str(r), "--json"])
    assert res.exit_code == 0
    js = json.loads(res.stdout)
    h = {row["solution"]: row for row in js["headline"]}
    assert abs(h["forward"]["rms_pos_h_m"] - 5.0) < 1e-6 and abs(h["smoothed"]["rms_pos_h_m"] - 0.5) < 1e-6


def test_report_session_moved_and_truth_override(tmp_path):
    r = _run(tmp_path)
    summary = json.loads((r / "summary.json").read_text())
    summary["session"]["path"] = str(tmp_path / "moved")
    (r / "summary.json").write_text(json.dumps(summary))
    res = runner.invoke(app, ["report", str(r)])  # the run alone: a quality-control report, said so
    assert res.exit_code == 0 and "note: session" in res.stderr and "not found" in res.stderr
    assert json.loads((r / "accuracy.json").read_text())["truth"] is None
    res = runner.invoke(app, ["report", str(r), "--truth", str(tmp_path / "s")])
    assert res.exit_code == 0 and json.loads((r / "accuracy.json").read_text())["truth"]["trajectory"]["source"] == "truth"
    assert runner.invoke(app, ["report", str(r), "--truth", str(tmp_path / "nowhere")]).exit_code == 2


def test_report_without_truth_is_a_quality_control_report(tmp_path):
    s = synth.write_session(tmp_path / "s", truth=False)
    traj = synth.trajectory_rows("forward", np.arange(0.0, 21.0), [0.0, 0.0, 0.0], sigma=(1.0, 1.0, 2.0))
    r = synth.write_run(tmp_path / "r", s, traj)
    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 0, res.output
    assert "truth: none (quality-control report)" in res.output
    js = json.loads((r / "accuracy.json").read_text())
    assert js["truth"] is None and js["headline"] == [] and js["estimated"][0]["solution"] == "forward"
    assert (r / "report.pdf").exists() and pd.read_parquet(r / "accuracy.parquet").empty


def test_report_shows_the_runs_verdict(tmp_path):
    r = _run(tmp_path)
    summary = json.loads((r / "summary.json").read_text())
    summary["quality"] = {
        "verdict": "suspect",
        "reasons": ["gps_pos NIS 9.1 above its band 2.5-3.5: GPS noise understated; set [gps] sigma"],
        "checks": {"nis": {"level": "suspect", "forward.gps_pos.mean": 9.1}},
    }
    (r / "summary.json").write_text(json.dumps(summary))
    from tpos_cli.report.build import build_context, make_report
    from tpos_cli.report.summary import headline_rows

    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 0 and 'verdict: suspect (1 reason(s) in report.pdf, in full under "The verdict\'s checks")' in res.output
    assert json.loads((r / "accuracy.json").read_text())["quality"]["verdict"] == "suspect"
    assert "verdict_checks" in "+".join(make_report(r).pages)
    rows = dict(headline_rows(build_context(r)))
    assert rows["Solution shown"].startswith("smoothed") and "RMS" in rows["Error against truth"]


def test_changed_inputs_are_refused_truth_changes_noted(tmp_path):
    r = _run(tmp_path)
    s = tmp_path / "s"
    (s / "truth.csv").write_text((s / "truth.csv").read_text() + "\n")  # report-only input: noted, used
    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 0 and "note: truth.csv changed since the run was processed" in res.stderr
    (s / "imu.csv").write_text((s / "imu.csv").read_text().replace("-9.8", "-9.81"))  # a processing input
    for p in r.glob("accuracy.*"):
        p.unlink()
    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 2
    (line,) = res.stderr.strip().splitlines()
    assert "imu.csv changed" in line and "reprocess" in line
    assert not list(r.glob("accuracy.*"))  # nothing written


def test_outputs_readable_by_others_and_no_temporaries_left(tmp_path, monkeypatch):
    r = _run(tmp_path)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    (r / f".report.pdf.{int(dead.stdout)}-0a1b2c3d.tmp").write_text("killed")  # a killed report's temporary
    (r / ".accuracy.json.x7k2m9qa.tmp").write_text("old")  # an older tpos's temporary (no pid)
    old = os.umask(0o022)
    try:
        assert runner.invoke(app, ["report", str(r)]).exit_code == 0
    finally:
        os.umask(old)
    for n in ("accuracy.parquet", "accuracy.json", "report.pdf"):
        assert stat.S_IMODE((r / n).stat().st_mode) == 0o644, n
    assert not list(r.glob(".*.tmp"))
    before = {n: (r / n).read_bytes() for n in ("accuracy.json", "report.pdf")}

    def interrupted(*a, **k):
        raise KeyboardInterrupt  # Ctrl-C while the PDF is being written

    monkeypatch.setattr("tpos_cli.report.pdf.write_pdf", interrupted)
    from tpos_cli.report.build import make_report

    with pytest.raises(KeyboardInterrupt):
        make_report(r)
    assert not list(r.glob(".*.tmp"))
    assert {n: (r / n).read_bytes() for n in before} == before  # the earlier report is intact


def test_report_not_a_run_or_nothing_to_report_exits_2(tmp_path):
    res = runner.invoke(app, ["report", str(tmp_path)])
    assert res.exit_code == 2 and "summary.json" in res.output
    s = synth.write_session(tmp_path / "s")
    r = synth.write_run(tmp_path / "r", s)  # a run without solutions (the ingest pipeline)
    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 2 and "nothing to report" in res.output


def test_truth_from_another_session_is_used_for_truth_only(tmp_path):
    r = _run(tmp_path)
    other = shutil.copytree(tmp_path / "s", tmp_path / "other")
    (other / "imu.csv").write_text((other / "imu.csv").read_text().replace("-9.8", "-9.81"))  # not the processed data
    res = runner.invoke(app, ["report", str(r), "--truth", str(other)])
    assert res.exit_code == 0 and "is not the session this run was processed from" in res.stderr
    js = json.loads((r / "accuracy.json").read_text())
    assert js["truth"]["trajectory"]["source"] == "truth" and js["session"]["inputs_verified"].startswith("no")


def test_the_report_is_titled_by_the_runs_kind_not_the_truth_sessions(tmp_path):
    # audit (session 12): a drive run reported with a target session's truth was titled "target survey"
    from tpos_cli.report.build import build_context

    r = _run(tmp_path)
    other = synth.write_session(tmp_path / "other", kind="target", movement=True)
    assert build_context(r, other).kind == "drive"


def _tpos_report_killed_mid_write(run, sig) -> tuple[int, list[str]]:
    """`tpos report RUN` in a process of its own, sent `sig` while its temporaries exist (the PDF
    being written); returns its exit code and the temporaries left. None if it finished first
    (also when it exits 0: on a loaded machine the signal can land after its last rename, while the
    process is leaving through os._exit, where no Python handler runs any more)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [sys.executable, "-m", "tpos_cli", "report", str(run)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        # as a terminal's foreground job: a test run in the background (nohup ... &) ignores SIGINT, and
        # its children would inherit that
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    while proc.poll() is None and not list(run.glob(".*.tmp")):
        time.sleep(0.005)
    if proc.poll() is not None:
        return None
    proc.send_signal(sig)
    code = proc.wait(timeout=60)
    if code == 0:  # the signal landed after the last rename, as the process left (os._exit): it had finished
        return None
    return code, sorted(p.name for p in run.glob(".*.tmp"))


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL], ids=["INT", "TERM", "KILL"])
def test_report_killed_mid_run_then_run_again(tmp_path, sig):
    """Issue 14: no temporary files after an interrupted report. Ctrl-C and kill remove them at
    once; kill -9 cannot, and the next report removes them; the earlier report stays whole."""
    r = _run(tmp_path)
    assert runner.invoke(app, ["report", str(r)]).exit_code == 0
    before = (r / "report.pdf").read_bytes()
    for _ in range(5):  # a report that finishes before the signal lands is tried again
        res = _tpos_report_killed_mid_write(r, sig)
        if res is not None:
            break
        before = (r / "report.pdf").read_bytes()  # it finished: its report (a new time stamp) is the one to keep
    assert res is not None, "the report always finished before it could be interrupted"
    code, left = res
    if sig == signal.SIGKILL:
        assert code == -signal.SIGKILL and 1 <= len(left) <= 3  # of accuracy.parquet, accuracy.json, report.pdf
    else:
        assert code == 130 and left == []
    assert (r / "report.pdf").read_bytes() == before
    old = os.umask(0o022)
    try:
        assert runner.invoke(app, ["report", str(r)]).exit_code == 0
    finally:
        os.umask(old)
    assert not list(r.glob(".*.tmp"))
    assert all(stat.S_IMODE((r / n).stat().st_mode) == 0o644 for n in ("accuracy.parquet", "accuracy.json", "report.pdf"))


def test_truth_that_does_not_overlap_the_run_in_time(tmp_path):
    # session 7 audit: `tpos report <comma run> --truth <walk>` exited 0 with "n=0 ... RMS n/a" lines and
    # numpy's "Mean of empty slice" warnings on stderr
    r = _run(tmp_path)
    other = shutil.copytree(tmp_path / "s", tmp_path / "other")
    tr = pd.read_csv(other / "truth.csv")
    tr["t"] += 1.0e5  # another day (or another clock)
    tr.to_csv(other / "truth.csv", index=False)
    res = runner.invoke(app, ["report", str(r), "--truth", str(other)])
    assert res.exit_code == 2 and "do not overlap in time" in res.stderr and "is it the session of this run?" in res.stderr
    assert not (r / "report.pdf").exists()  # nothing written
    shutil.copyfile(other / "truth.csv", tmp_path / "s" / "truth.csv")  # the run's own truth on another clock: noted, QC report
    res = runner.invoke(app, ["report", str(r)])
    assert res.exit_code == 0 and "do not overlap in time on the logger clock: no errors against it" in res.stderr
    assert "truth: none (quality-control report)" in res.output and "Warning" not in res.stderr


def test_an_attitude_logs_line_leads_with_the_total_angle(tmp_path):
    # a fixed observer's solutions are attitudes: the total angle first (near pitch +-90 deg the Euler roll and yaw
    # errors are large and cancel; BROAD 02: roll 1.14, yaw 1.19, total 0.51 deg), then the Euler angles
    s = synth.write_session(tmp_path / "s", kind="target")
    traj = synth.trajectory_rows("fkf", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.0, 0.0, 0.0], rpy_err_deg=(0.5, -0.3, 2.0))
    res = runner.invoke(app, ["report", str(synth.write_run(tmp_path / "r", s, traj))])
    assert res.exit_code == 0, res.output
    line = next(ln for ln in res.stdout.splitlines() if ln.strip().startswith("fkf (attitude"))
    # the three Euler errors compose to about their root sum of squares (2.08 deg) at the synthetic track's angles
    total = float(line.split("RMS total angle ")[1].split(" deg")[0])
    assert abs(total - np.sqrt(0.5**2 + 0.3**2 + 2.0**2)) < 0.02, line
    assert line.endswith(" deg (roll 0.5, pitch 0.3, yaw 2)"), line
