"""`tpos batch`: planning, the per-session task, resumability, pools, Dask, the batch record, the CLI.

The batch logic is tested with a stand-in for `process_session` whose behaviour each fake session
declares in a `behaviour` file (module-level functions, so that spawned workers and Dask can pickle
them); the real pipeline runs in `test_batch_e2e_sample_logs`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pandas as pd
import pytest
import typer
from typer.testing import CliRunner

from tpos_cli import batch as b
from tpos_cli.errors import InvalidInputError, ProcessingError

# --------------------------------------------------------------------------- stand-ins


def fake_fingerprint(session_dir: Path, pipeline: str | None) -> tuple[dict[str, str], str]:
    """What the stand-in pipeline records: sha256 of every file, and a config hash of the name."""
    inputs = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(session_dir.iterdir()) if p.is_file()}
    return inputs, hashlib.sha256(f"config:{pipeline}".encode()).hexdigest()


def fake_is_current(session_dir: Path, pipeline: str | None, summary) -> bool:
    inputs, config_sha = fake_fingerprint(session_dir, pipeline)
    return summary["inputs"] == inputs and summary["config_sha256"] == config_sha


def fake_process(session_dir: Path, pipeline: str | None, run_dir: Path):
    """Behave as the session's `behaviour` file says; on success write the run atomically."""
    behaviour = (session_dir / "behaviour").read_text().strip()
    if behaviour == "invalid":
        raise InvalidInputError(f"{session_dir.name}/imu.csv: column 'gyro_x', row 7: not a number")
    if behaviour == "error":
        raise ProcessingError("filter diverged\nat t = 12.5 s")  # two lines: the row keeps one
    if behaviour == "bug":
        raise ZeroDivisionError("division by zero")
    if behaviour == "crash":
        os._exit(3)  # a segfault or the OOM killer, as seen from the pool
    if behaviour == "hang":
        time.sleep(120)  # a session that takes too long
    if behaviour == "fifo":
        fifo = session_dir / "imu.fifo"
        os.mkfifo(fifo)
        open(fifo, "rb").read()  # blocks until a writer comes: never
    if behaviour == "stuck":
        signal.signal(signal.SIGALRM, signal.SIG_IGN)  # deaf to the alarm, as compiled code is
        time.sleep(120)
    if behaviour == "claim_and_hang":  # as process_session mid-run: its run directory locked, a temporary beside it
        from tpos_cli.io.run_dir import claim_run_dir

        claim_run_dir(run_dir)
        run_dir.with_name(f".{run_dir.name}.tmp-{os.getpid()}").mkdir()
        time.sleep(120)
    inputs, config_sha = fake_fingerprint(session_dir, pipeline)
    tmp = run_dir.with_name(f".{run_dir.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    n = len(list(run_dir.parent.glob("*.runs"))) if run_dir.parent.exists() else 0
    summary = {
        "pipeline": pipeline or "default", "config_sha256": config_sha, "inputs": inputs,
        "session": {"name": session_dir.name, "kind": "target" if behaviour == "target" else "drive"},
        "timings_s": {"load": 0.01, "filter": 0.02},
        "results": {"position": {"rms_h_m": 1.5, "max_h_m": 4.0}, "n_fixes": 10, "ok": True, "label": "x"},
        "warnings": ["imu.csv: 2 duplicate time stamps; the first sample of each kept"],
        "quality": {"verdict": "suspect" if behaviour == "suspect" else "ok",
                    "reasons": ["GPS late by 0.2 s: set [time] gps_offset_s = -0.2"] if behaviour == "suspect" else []},
    }
    (tmp / "summary.json").write_text(json.dumps(summary))
    # count how often each session really ran (to prove skips)
    counter = run_dir.parent / f"{run_dir.name}.runs"
    part = counter.with_name(counter.name + ".part")  # replaced whole: when another worker crashes, the pool kills
    part.write_text(str(int(counter.read_text()) + 1 if counter.exists() else 1))  # this one, maybe mid-write
    os.replace(part, counter)
    del n
    if run_dir.exists():
        shutil.rmtree(run_dir)
    os.replace(tmp, run_dir)
    return None  # no summary returned: the task must read summary.json


def make_sessions(root: Path, behaviours: dict[str, str]) -> list[Path]:
    paths = []
    for name, behaviour in behaviours.items():
        d = root / name
        d.mkdir(parents=True)
        (d / "behaviour").write_text(behaviour)
        (d / "imu.csv").write_text(f"t,gyro_x\n0,{len(name)}\n")
        paths.append(d)
    return paths


def runs(out: Path, name: str) -> int:
    f = out / f"{name}.runs"
    return int(f.read_text()) if f.exists() else 0


def tasks_for(sessions, out, **kw):
    return b.plan_batch(sessions, out, "p1", **kw)


# --------------------------------------------------------------------------- planning


def test_expand_sessions_globs_dirs_and_list_files(tmp_path):
    make_sessions(tmp_path / "logs", {"a": "ok", "b": "ok", "c": "ok"})
    (tmp_path / "logs" / "README.md").write_text("not a session")
    lst = tmp_path / "list.txt"
    lst.write_text("# field week\nlogs/c   # re-run\n\nlogs/a\n")
    got = b.expand_sessions(["logs/b", "list.txt", "logs/*"], cwd=tmp_path)
    # order of first mention, no repeats, README ignored by the glob, list paths relative to the list
    assert [p.name for p in got] == ["b", "c", "a"]
    assert all(p.is_absolute() for p in got)


@pytest.mark.parametrize("spec", ["nothing/*", "missing_dir"])
def test_expand_sessions_names_what_matched_nothing(tmp_path, spec):
    with pytest.raises(InvalidInputError, match=spec.replace("*", r"\*")):
        b.expand_sessions([spec], cwd=tmp_path)


def test_plan_rejects_two_sessions_with_one_name(tmp_path):
    s1 = make_sessions(tmp_path / "day1", {"run": "ok"})
    s2 = make_sessions(tmp_path / "day2", {"run": "ok"})
    with pytest.raises(InvalidInputError, match="share the name 'run'"):
        b.plan_batch(s1 + s2, tmp_path / "out")
    (t,) = b.plan_batch(s1, tmp_path / "out", "drive-smooth")
    assert Path(t.run_dir) == (tmp_path / "out" / "run").resolve() and t.pipeline == "drive-smooth"


# --------------------------------------------------------------------------- the task


@pytest.mark.parametrize(
    ("behaviour", "exit_code", "message"),
    [
        ("invalid", 2, "s/imu.csv: column 'gyro_x', row 7: not a number"),
        ("error", 1, "filter diverged at t = 12.5 s"),
        ("bug", 1, "ZeroDivisionError: division by zero (at test_batch.py:"),
    ],
)
def test_task_turns_errors_into_one_line_rows(tmp_path, behaviour, exit_code, message):
    (s,) = make_sessions(tmp_path, {"s": behaviour})
    (task,) = tasks_for([s], tmp_path / "out")
    r = b.run_session_task(task, fake_process, fake_is_current)
    assert (r.status, r.exit_code) == ("failed", exit_code)
    assert r.error.startswith(message) and "\n" not in r.error
    assert not (tmp_path / "out" / "s").exists()  # nothing half-written


def test_task_ok_reads_summary_and_report_figures(tmp_path):
    (s,) = make_sessions(tmp_path, {"s": "ok"})
    (plain,) = tasks_for([s], tmp_path / "out")
    r = b.run_session_task(plain, fake_process, fake_is_current)
    assert (r.status, r.exit_code, r.error, r.pipeline) == ("ok", 0, "", "p1")
    assert r.timings_s == {"load": 0.01, "filter": 0.02}
    assert r.accuracy == {}  # only with report
    (rep,) = tasks_for([s], tmp_path / "out", report=True, force=True)
    r = b.run_session_task(rep, fake_process, fake_is_current)
    # numeric results flattened with dotted keys; booleans and strings are not figures
    assert r.accuracy == {"position.rms_h_m": 1.5, "position.max_h_m": 4.0, "n_fixes": 10.0}


def test_resume_skips_current_runs_and_redoes_changed_or_half_written_ones(tmp_path):
    sessions = make_sessions(tmp_path / "logs", {"a": "ok", "b": "ok", "c": "ok", "d": "ok"})
    out = tmp_path / "out"
    first = b.run_batch(tasks_for(sessions, out), jobs=1, process=fake_process, is_current=fake_is_current)
    assert [r.status for r in first.results] == ["ok"] * 4 and first.exit_code == 0

    (sessions[0] / "imu.csv").write_text("t,gyro_x\n0,99\n")  # a: input changed
    (sessions[1] / "gps.csv").write_text("t,lat\n0,1\n")  # b: a new input file appeared
    shutil.rmtree(out / "c")  # c: killed midway: only the temporary directory is left
    (out / ".c.tmp").mkdir()
    second = b.run_batch(tasks_for(sessions, out), jobs=1, process=fake_process, is_current=fake_is_current)
    assert [r.status for r in second.results] == ["ok", "ok", "ok", "skipped"]
    assert [runs(out, n) for n in "abcd"] == [2, 2, 2, 1]
    assert second.results[3].timings_s == {"load": 0.01, "filter": 0.02}  # a skipped row still reports

    other_pipeline = b.run_batch(b.plan_batch(sessions, out, "p2"), jobs=1, process=fake_process, is_current=fake_is_current)
    assert [r.status for r in other_pipeline.results] == ["ok"] * 4  # config hash changed

    forced = b.run_batch(b.plan_batch(sessions, out, "p2", force=True), jobs=1, process=fake_process, is_current=fake_is_current)
    assert [r.status for r in forced.results] == ["ok"] * 4
    assert [runs(out, n) for n in "abcd"] == [4, 4, 4, 3]


def test_corrupt_summary_is_not_a_finished_run(tmp_path):
    (s,) = make_sessions(tmp_path, {"s": "ok"})
    (task,) = tasks_for([s], tmp_path / "out")
    b.run_session_task(task, fake_process, fake_is_current)
    (tmp_path / "out" / "s" / "summary.json").write_text('{"inputs": {"imu.csv"')  # truncated
    assert b.finished_summary(task, fake_is_current) is None
    assert b.run_session_task(task, fake_process, fake_is_current).status == "ok"


# --------------------------------------------------------------------------- executors


def test_process_pool_isolates_failures_and_crashes(tmp_path):
    behaviours = {"s0": "ok", "s1": "error", "s2": "crash", "s3": "ok", "s4": "invalid", "s5": "ok"}
    sessions = make_sessions(tmp_path / "logs", behaviours)
    seen = []
    res = b.run_batch(tasks_for(sessions, tmp_path / "out"), jobs=2, process=fake_process,
                      is_current=fake_is_current, on_result=lambda r: seen.append(r.name))
    assert [r.name for r in res.results] == list(behaviours)  # rows in task order
    assert sorted(seen) == sorted(behaviours)  # every row reported once as it completed
    assert [r.status for r in res.results] == ["ok", "failed", "failed", "ok", "failed", "ok"]
    assert res.results[2].error.startswith("worker process died")
    assert [r.exit_code for r in res.results] == [0, 1, 1, 0, 2, 0]
    assert res.exit_code == 1 and res.jobs == 2
    # the good sessions ran in worker processes, not in this one
    workers = {r.worker for r in res.results if r.status == "ok"}
    assert all(w and not w.endswith(f":{os.getpid()}") for w in workers)


def test_dask_local_cluster_runs_the_same_task(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    sessions = make_sessions(tmp_path / "logs", {"a": "ok", "b": "invalid", "c": "ok"})
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        res = b.run_batch(tasks_for(sessions, out), scheduler=cluster.scheduler_address,
                          process=fake_process, is_current=fake_is_current)
        assert [r.status for r in res.results] == ["ok", "failed", "ok"]
        assert res.results[1].exit_code == 2 and "row 7" in res.results[1].error
        assert res.scheduler == cluster.scheduler_address
        again = b.run_batch(tasks_for(sessions, out), scheduler=cluster.scheduler_address,
                            process=fake_process, is_current=fake_is_current)
        assert [r.status for r in again.results] == ["skipped", "failed", "skipped"]
    assert runs(out, "a") == 1 and runs(out, "c") == 1


def test_bad_jobs_is_invalid_input(tmp_path):
    with pytest.raises(InvalidInputError, match="--jobs"):
        b.run_batch((), jobs=0)


# --------------------------------------------------------------------------- the record


def test_batch_record_has_one_row_per_session(tmp_path):
    sessions = make_sessions(tmp_path / "logs", {"a": "ok", "b": "error"})
    tasks = tasks_for(sessions, tmp_path / "out", report=True)
    res = b.run_batch(tasks, jobs=1, process=fake_process, is_current=fake_is_current)
    lost = b._failed(tasks[1], "worker process died (NaN time)")  # a lost task: no time measured
    res = b.BatchResult(res.root, (res.results[0], lost), res.wall_time_s, 1, None)
    json_path, pq_path = b.write_batch_record(res, pipeline="p1")
    doc = json.loads(json_path.read_text())
    assert doc["counts"] == {"ok": 1, "skipped": 0, "failed": 1} and doc["exit_code"] == 1
    assert [s["name"] for s in doc["sessions"]] == ["a", "b"]
    assert doc["sessions"][1]["time_s"] is None and doc["sessions"][1]["error"] == "worker process died (NaN time)"
    df = pd.read_parquet(pq_path)
    assert list(df["name"]) == ["a", "b"] and list(df["status"]) == ["ok", "failed"]
    assert df.loc[0, "acc.position.rms_h_m"] == 1.5 and df.loc[0, "timing.filter"] == 0.02
    assert pd.isna(df.loc[1, "acc.position.rms_h_m"])


# --------------------------------------------------------------------------- CLI


@pytest.fixture
def cli(monkeypatch):
    from tpos_cli.cli.batch import batch

    monkeypatch.setattr(b, "_default_process", fake_process)
    monkeypatch.setattr(b, "run_is_current", fake_is_current)
    app = typer.Typer()
    app.command()(batch)
    runner = CliRunner()
    return lambda *args: runner.invoke(app, [str(a) for a in args])


def test_cli_exit_codes_table_and_resume(tmp_path, cli):
    make_sessions(tmp_path / "logs", {"good1": "ok", "broken": "invalid", "good2": "ok"})
    out = tmp_path / "out"
    r = cli(f"{tmp_path}/logs/*", "--out", out, "-j", "1", "--report")
    assert r.exit_code == 1, r.output
    assert "broken/imu.csv: column 'gyro_x', row 7: not a number" in r.output
    assert "2 ok, 0 skipped, 1 failed" in r.output
    assert (out / "good1" / "summary.json").exists() and not (out / "broken").exists()
    r = cli(f"{tmp_path}/logs/good*", "--out", out, "-j", "1")
    assert r.exit_code == 0, r.output
    assert "0 ok, 2 skipped, 0 failed" in r.output
    assert json.loads((out / "batch.json").read_text())["counts"]["skipped"] == 2


@pytest.mark.parametrize("args", [["nowhere/*", "--out", "o"], ["logs/*", "--out", "o", "--jobs", "0"], ["logs/*"]])
def test_cli_bad_arguments_exit_2(tmp_path, cli, args, monkeypatch):
    make_sessions(tmp_path / "logs", {"a": "ok"})
    monkeypatch.chdir(tmp_path)
    assert cli(*args).exit_code == 2
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------------- end to end


def _simulated_sessions(root: Path) -> list[Path]:
    from tpos_cli.sim.drive import simulate_drive
    from tpos_cli.sim.writer import write_session

    paths = [write_session(simulate_drive(30.0, seed=s, static_s=5.0, outages=(), name=f"drive{s}"), root / f"drive{s}", fmt="csv")
             for s in (1, 2)]
    broken = root / "broken"
    shutil.copytree(paths[0], broken)
    imu = (broken / "imu.csv").read_text().splitlines()
    cells = imu[5].split(",")
    imu[5] = ",".join([cells[0], "abc", *cells[2:]])  # data row 5, column 2 of the header
    (broken / "imu.csv").write_text("\n".join(imu) + "\n")
    return [*paths, broken]


def test_batch_e2e_real_pipeline_broken_session_and_resume(tmp_path):
    from tpos_cli.cli import app

    _simulated_sessions(tmp_path / "logs")
    header = (tmp_path / "logs" / "broken" / "imu.csv").read_text().splitlines()[0].split(",")
    out = tmp_path / "out"
    runner = CliRunner()
    args = ["batch", str(tmp_path / "logs" / "*"), "--out", str(out), "-p", "ingest", "--jobs", "2", "--report"]
    first = runner.invoke(app, args)
    assert first.exit_code == 1, first.output
    assert f"broken: broken/imu.csv: column '{header[1]}', row 5:" in first.output
    assert "2 ok, 0 skipped, 1 failed" in first.output
    doc = json.loads((out / "batch.json").read_text())
    rows = {r["name"]: r for r in doc["sessions"]}
    assert rows["drive1"]["status"] == "ok" and rows["drive1"]["accuracy"]["gps_valid_fixes"] > 0
    assert rows["broken"]["exit_code"] == 2 and not (out / "broken").exists()
    summary = json.loads((out / "drive1" / "summary.json").read_text())
    assert summary["pipeline"] == "ingest" and summary["inputs"]

    second = runner.invoke(app, args)
    assert second.exit_code == 1 and "0 ok, 2 skipped, 1 failed" in second.output, second.output

    # an edited input is processed again; the other stays skipped
    toml = tmp_path / "logs" / "drive2" / "session.toml"
    toml.write_text(toml.read_text() + "\n# edited\n")
    shutil.rmtree(tmp_path / "logs" / "broken")
    third = runner.invoke(app, [*args[:-3], "--jobs", "1"])
    assert third.exit_code == 0 and "1 ok, 1 skipped, 0 failed" in third.output, third.output
    rows = {r["name"]: r["status"] for r in json.loads((out / "batch.json").read_text())["sessions"]}
    assert rows == {"drive1": "skipped", "drive2": "ok"}


def report_threads(session_dir: Path, pipeline: str | None, run_dir: Path):
    """Stand-in that fails on purpose, carrying the worker's thread-limit environment in the message."""
    raise ProcessingError(f"OMP={os.environ.get('OMP_NUM_THREADS')} NUMBA={os.environ.get('NUMBA_NUM_THREADS')} "
                          f"TPOS={os.environ.get('TPOS_THREADS')}")


def test_pool_workers_compute_single_threaded(tmp_path, monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setenv("NUMBA_NUM_THREADS", "3")  # the user's own choice is kept
    monkeypatch.delenv("TPOS_THREADS", raising=False)  # tpos's helper threads too (chains.context.spare_cpu, s11-speed)
    sessions = make_sessions(tmp_path / "logs", {"a": "ok", "b": "ok"})
    res = b.run_batch(tasks_for(sessions, tmp_path / "out"), jobs=2, process=report_threads, is_current=fake_is_current)
    assert {r.error for r in res.results} == {"OMP=1 NUMBA=3 TPOS=1"}
    assert "OMP_NUM_THREADS" not in os.environ  # the parent's environment is restored


def test_batch_report_adds_errors_against_truth(tmp_path):
    # --report runs `tpos report` on each finished run: accuracy files in the run directory and the
    # headline errors against the session's truth in the row; a run with nothing to score gets a note.
    from tpos_cli.cli import app

    repo = Path(__file__).resolve().parents[1]
    shutil.copytree(repo / "sample_logs" / "drive_outage", tmp_path / "logs" / "drive")
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["batch", str(tmp_path / "logs" / "*"), "--out", str(out), "-p", "ingest", "-j", "1", "--report"])
    assert res.exit_code == 0, res.output
    rows = {r["name"]: r for r in json.loads((out / "batch.json").read_text())["sessions"]}
    # the ingest pipeline writes no solutions: nothing to score, said in the note
    assert rows["drive"]["report_note"].startswith("no report:")
    res = CliRunner().invoke(app, ["batch", str(tmp_path / "logs" / "drive"), "--out", str(out / "smooth"), "-j", "1", "--report"])
    assert res.exit_code == 0, res.output
    row = json.loads((out / "smooth" / "batch.json").read_text())["sessions"][0]
    assert row["report_note"] == ""
    assert 0.0 < row["accuracy"]["truth.smoothed.trajectory.rms_pos_h_m"] < 2.0  # sample drive: 1.5 m GPS noise, 30 s outage
    assert (out / "smooth" / "drive" / "report.pdf").exists() and (out / "smooth" / "drive" / "accuracy.json").exists()


# --------------------------------------------------------------------------- record merging, table, limits


REPORTS_BUILT: list[str] = []


def fake_report(run_dir: Path, summary) -> dict:
    """Stand-in for `tpos report` on a run: headline errors against truth, counted per call."""
    REPORTS_BUILT.append(run_dir.name)
    (run_dir / "accuracy.json").write_text("{}")
    return {"accuracy": {"truth.forward.trajectory.rms_pos_h_m": 3.0, "truth.smoothed.trajectory.rms_pos_h_m": 1.25,
                         "truth.smoothed.trajectory.rms_att_deg": 0.5}}


@pytest.fixture
def counted_reports(monkeypatch):
    REPORTS_BUILT.clear()
    monkeypatch.setattr(b, "_report", fake_report)
    return REPORTS_BUILT


def _batch(sessions, out, **kw):
    res = b.run_batch(tasks_for(sessions, out, **kw), jobs=1, process=fake_process, is_current=fake_is_current)
    b.write_batch_record(res, pipeline="p1")
    return {r["name"]: r for r in json.loads((out / "batch.json").read_text())["sessions"]}


def test_rows_carry_verdict_and_warnings(tmp_path):
    sessions = make_sessions(tmp_path / "logs", {"a": "ok", "b": "suspect"})
    out = tmp_path / "out"
    rows = _batch(sessions, out)
    assert (rows["a"]["verdict"], rows["b"]["verdict"]) == ("ok", "suspect")
    assert rows["b"]["quality_reasons"] == ["GPS late by 0.2 s: set [time] gps_offset_s = -0.2"]
    assert rows["a"]["warnings"] == ["imu.csv: 2 duplicate time stamps; the first sample of each kept"]
    df = pd.read_parquet(out / "batch.parquet").set_index("name")
    assert df.loc["b", "verdict"] == "suspect" and df.loc["a", "n_warnings"] == 1
    assert list(df.loc["a", "warnings"]) == rows["a"]["warnings"]


def test_reruns_merge_truth_figures_and_rebuild_reports_only_for_changed_runs(tmp_path, counted_reports):
    sessions = make_sessions(tmp_path / "logs", {"a": "ok", "b": "ok"})
    out = tmp_path / "out"
    rows = _batch(sessions, out, report=True)
    assert counted_reports == ["a", "b"] and rows["a"]["report"] == "built"
    assert rows["a"]["accuracy"]["truth.smoothed.trajectory.rms_pos_h_m"] == 1.25

    rows = _batch(sessions, out)  # no --report: the unchanged runs keep their figures
    assert rows["a"]["status"] == "skipped" and rows["a"]["report"] == "earlier"
    assert rows["a"]["accuracy"]["truth.smoothed.trajectory.rms_pos_h_m"] == 1.25

    rows = _batch(sessions, out, report=True)  # --report again: nothing changed, nothing rebuilt
    assert counted_reports == ["a", "b"] and rows["b"]["report"] == "reused"
    assert rows["b"]["accuracy"]["truth.smoothed.trajectory.rms_pos_h_m"] == 1.25

    (sessions[0] / "imu.csv").write_text("t,gyro_x\n0,7\n")  # a changes: its old figures are stale
    rows = _batch(sessions, out)
    assert rows["a"]["status"] == "ok" and rows["a"]["accuracy"] == {} and rows["a"]["report"] == ""
    assert rows["b"]["report"] == "earlier"
    rows = _batch(sessions, out, report=True)
    assert counted_reports == ["a", "b", "a"] and rows["a"]["report"] == "built"


def test_rows_of_sessions_not_named_again_are_kept_while_their_run_is(tmp_path):
    sessions = make_sessions(tmp_path / "logs", {"a": "ok", "b": "ok", "c": "invalid"})
    out = tmp_path / "out"
    _batch(sessions, out)
    res = b.run_batch(tasks_for(sessions[:1], out), jobs=1, process=fake_process, is_current=fake_is_current)
    b.write_batch_record(res)
    doc = json.loads((out / "batch.json").read_text())
    assert [(r["name"], r["in_this_batch"]) for r in doc["sessions"]] == [("a", True), ("b", False)]  # c failed: no run
    assert doc["counts"] == {"ok": 0, "skipped": 1, "failed": 0}  # this batch's
    shutil.rmtree(out / "b")
    b.write_batch_record(res)
    assert [r["name"] for r in json.loads((out / "batch.json").read_text())["sessions"]] == ["a"]


def test_final_table_fits_80_columns():
    rows = [
        b.SessionResult(name="rtklibexplorer_drive_0708_part1_with_a_long_suffix", session_dir="", run_dir="",
                        status="ok", exit_code=0, error="", time_s=1234.5, started_utc="", worker="",
                        accuracy={"truth.forward.trajectory.rms_pos_h_m": 3.0, "truth.smoothed.trajectory.rms_pos_h_m": 1.25,
                                  "truth.smoothed.trajectory.rms_att_deg": 0.5, "gps_error_states.sigma_h_m": 0.1},
                        verdict="unreliable", warnings=("w1", "w2")),
        b.SessionResult(name="wall", session_dir="", run_dir="", status="failed", exit_code=2, error="bad", time_s=float("nan"),
                        started_utc="", worker=""),
        b.SessionResult(name="target_wall", session_dir="", run_dir="", status="skipped", exit_code=0, error="", time_s=0.2,
                        started_utc="", worker="",
                        accuracy={"truth.fkf.targets.rms_pos_3d_m": 0.0312, "truth.lf1.targets.rms_pos_3d_m": 0.5,
                                  "truth.fkf.trajectory.rms_att_deg": 0.25}),
    ]
    from tpos_cli.report.solutions import rank_solutions

    lines = b.format_table(rows, rank_solutions)
    assert all(len(ln) <= 80 for ln in [*lines, *b.TABLE_LEGEND.splitlines()])
    assert lines[0].split() == ["session", "status", "verdict", "pos", "m", "att", "deg", "solution", "warn", "time", "s"]
    # both ends of a long name survive; the headline is the best solution's, not a config figure
    assert lines[1].split() == ["rtklibexp..ong_suffix", "ok", "unreliable", "1.25", "0.5", "smoothed", "2", "1234.5"]
    assert lines[2].split() == ["wall", "failed", "-", "-", "-", "-", "0", "-"]
    assert lines[3].split() == ["target_wall", "skipped", "-", "0.0312", "0.25", "fkf", "0", "0.2"]


def test_a_fixed_observer_without_targets_has_no_position_error():
    """A target pipeline's session with no shots (BROAD's hand-held trials): its trajectory is an
    attitude at a point it was given, so the table shows its attitude error and no position error."""
    acc = {"truth.fkf.trajectory.rms_pos_h_m": 0.314, "truth.fkf.trajectory.rms_att_deg": 1.2}
    obs = b.SessionResult(name="broad_25", session_dir="", run_dir="", status="ok", exit_code=0, error="", time_s=1.0,
                          started_utc="", worker="", pipeline="target-fkf", kind="target", accuracy=acc)
    car = b.SessionResult(name="car", session_dir="", run_dir="", status="ok", exit_code=0, error="", time_s=1.0,
                          started_utc="", worker="", pipeline="drive-smooth", kind="drive", accuracy=acc)
    assert b.headline_errors(obs) == ("fkf", None, 1.2)
    assert b.headline_errors(car) == ("fkf", 0.314, 1.2)
    # review (session 8): the observer was recognised by its pipeline's name; a user's own target pipeline
    # (`--pipeline wall.toml`, recorded as "wall") showed the observer's position as an error
    mine = dataclasses.replace(obs, pipeline="wall")
    assert b.headline_errors(mine) == ("fkf", None, 1.2)
    assert b.headline_errors(dataclasses.replace(car, pipeline="target-like-name")) == ("fkf", 0.314, 1.2)


def test_rows_record_the_session_kind_and_earlier_records_get_it_from_their_run(tmp_path):
    sessions = make_sessions(tmp_path / "logs", {"a": "ok", "t": "target"})
    out = tmp_path / "out"
    rows = _batch(sessions, out)
    assert (rows["a"]["kind"], rows["t"]["kind"]) == ("drive", "target")
    doc = json.loads((out / "batch.json").read_text())
    for r in doc["sessions"]:  # a record of session 8, before rows had it
        del r["kind"]
    (out / "batch.json").write_text(json.dumps(doc))
    assert {r.name: r.kind for r in b.earlier_rows(out, [])} == {"a": "drive", "t": "target"}


def test_batch_help_has_an_example():
    from tpos_cli.cli import app

    res = CliRunner().invoke(app, ["batch", "--help"])
    assert res.exit_code == 0 and "Example: tpos batch" in res.output and "--timeout" in res.output


@pytest.mark.parametrize("behaviour", ["hang", "fifo"])
def test_a_session_over_its_time_limit_fails_alone(tmp_path, behaviour):
    sessions = make_sessions(tmp_path / "logs", {"slow": behaviour, "fine": "ok"})
    t0 = time.monotonic()
    res = b.run_batch(tasks_for(sessions, tmp_path / "out", timeout_s=1.0), jobs=1, process=fake_process,
                      is_current=fake_is_current)
    assert time.monotonic() - t0 < 30
    assert [r.status for r in res.results] == ["failed", "ok"]
    assert res.results[0].exit_code == 1 and res.results[0].error.startswith("timed out after 1 s")
    assert signal.getsignal(signal.SIGALRM) in (signal.SIG_DFL, None) or callable(signal.getsignal(signal.SIGALRM))


def test_pool_kills_a_worker_deaf_to_its_alarm(tmp_path, monkeypatch):
    monkeypatch.setattr(b, "HARD_GRACE_S", 2.0)
    sessions = make_sessions(tmp_path / "logs", {"stuck": "stuck", "fine": "ok", "slow": "hang"})
    threads_before = set(threading.enumerate())
    t0 = time.monotonic()
    res = b.run_batch(tasks_for(sessions, tmp_path / "out", timeout_s=1.0), jobs=2, process=fake_process,
                      is_current=fake_is_current)
    assert time.monotonic() - t0 < 60
    assert [r.status for r in res.results] == ["failed", "ok", "failed"]
    assert "worker killed" in res.results[0].error and res.results[2].error.startswith("timed out after 1 s")
    # audit (session 11): the killed pool's manager thread outlived run_batch (and the queue's feeder
    # thread with it): a one-shot `tpos batch` then skipped its os._exit, and tests/cli/test_one_shot.py
    # failed when run after this file
    assert set(threading.enumerate()) <= threads_before, set(threading.enumerate()) - threads_before


def test_an_interrupted_batch_leaves_no_lock_or_temporary(tmp_path):
    """audit (session 11): Ctrl-C or kill during `tpos batch` left the running workers' `.NAME.lock` files
    (and `.NAME.tmp-PID` directories) in OUT until the next batch; they go with the workers."""
    import _thread

    sessions = make_sessions(tmp_path / "logs", {"a": "claim_and_hang", "b": "claim_and_hang", "c": "ok"})
    out = tmp_path / "out"

    def interrupt_when_both_run():
        deadline = time.monotonic() + 100  # before the workers' 120 s sleep ends
        while time.monotonic() < deadline and len(list(out.glob(".*.tmp-*"))) < 2:
            time.sleep(0.05)
        if time.monotonic() < deadline:
            _thread.interrupt_main()  # Ctrl-C, as the parent sees it

    # a test run in the background (nohup ... &) ignores SIGINT, and interrupt_main() then does nothing
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    watcher = threading.Thread(target=interrupt_when_both_run, daemon=True)
    try:
        watcher.start()
        with pytest.raises(KeyboardInterrupt):
            b.run_batch(tasks_for(sessions, out), jobs=2, process=fake_process, is_current=fake_is_current)
    finally:
        watcher.join()
        signal.signal(signal.SIGINT, previous)
    assert sorted(p.name for p in out.iterdir()) == [], sorted(p.name for p in out.iterdir())


def test_bad_timeout_is_invalid_input(tmp_path):
    (s,) = make_sessions(tmp_path, {"s": "ok"})
    with pytest.raises(InvalidInputError, match="--timeout"):
        b.plan_batch([s], tmp_path / "out", timeout_s=-1.0)


def test_a_session_list_that_includes_itself_is_refused(tmp_path, cli, monkeypatch):
    make_sessions(tmp_path / "logs", {"a": "ok"})
    (tmp_path / "all.txt").write_text("logs/a\nmore.txt\n")
    (tmp_path / "more.txt").write_text("# again\nall.txt\n")
    monkeypatch.chdir(tmp_path)
    r = cli("all.txt", "--out", "o")
    assert r.exit_code == 2 and "includes itself (all.txt -> more.txt -> all.txt)" in r.output
    os.mkfifo(tmp_path / "fifo.txt")
    r = cli("fifo.txt", "--out", "o")
    assert r.exit_code == 2 and "regular file" in r.output
    assert not (tmp_path / "o").exists()


def test_an_output_root_inside_a_session_is_refused(tmp_path):
    """Runs never go into their input: a root inside (or equal to) a session directory is exit 2."""
    ses = tmp_path / "logs" / "a"
    ses.mkdir(parents=True)
    for root in (ses / "runs", ses):
        with pytest.raises(InvalidInputError, match="inside the session directory"):
            b.plan_batch([ses], root)
    assert len(b.plan_batch([ses], tmp_path / "runs")) == 1
