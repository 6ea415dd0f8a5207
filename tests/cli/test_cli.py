"""The CLI shape, exit codes and the provenance of a run directory."""

import json
import subprocess
import sys

import pandas as pd
import pytest
from typer.testing import CliRunner

from tests.helpers.sessions import write_minimal_session
from tpos_cli.cli import app

runner = CliRunner()


def test_console_script_help():
    res = subprocess.run([sys.executable, "-m", "tpos_cli", "--help"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0
    for cmd in ("validate", "inspect", "process", "pipelines"):
        assert cmd in res.stdout


@pytest.mark.parametrize("cmd", ["validate", "inspect", "process", "pipelines"])
def test_every_command_has_help_with_an_example(cmd):
    res = runner.invoke(app, [cmd, "--help"])
    assert res.exit_code == 0 and "Example" in res.output


def test_process_help_says_exit_zero_is_not_accuracy():
    res = runner.invoke(app, ["process", "--help"])
    assert "NOT a claim of accuracy" in " ".join(res.output.split())


def test_pipelines_lists_the_bundled_files():
    res = runner.invoke(app, ["pipelines"])
    assert res.exit_code == 0 and "ingest" in res.output


def test_inspect_json(tmp_path):
    s = write_minimal_session(tmp_path / "s", with_ranges=True)
    res = runner.invoke(app, ["inspect", str(s), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    assert info["tables"]["imu"]["rows"] == 1000
    assert abs(info["tables"]["imu"]["rate_hz"] - 100.0) < 1e-6
    assert info["tables"]["gps"]["fix_counts"] == {"2": 10}
    assert info["tables"]["ranges"]["no_return"] == {"d1": 0, "d2": 0, "d3": 0}


def test_process_writes_summary_with_provenance(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    run = tmp_path / "run"
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(run), "--mask-gps", "1002.5:1005.5"])
    assert res.exit_code == 0, res.output
    assert len(res.stdout.splitlines()) == 1  # not a terminal: no progress output, just the final line
    summary = json.loads((run / "summary.json").read_text())
    for key in ("tpos_version", "pipeline", "config", "config_sha256", "inputs", "timings_s", "counts", "warnings"):
        assert key in summary
    assert summary["pipeline"] == "ingest"
    assert set(summary["inputs"]) == {"session.toml", "imu.csv", "gps.csv"}
    assert summary["counts"]["gps_withheld_fixes"] == 3
    assert summary["gps_outages"] == [[1002.0, 1006.0]]
    withheld = pd.read_parquet(run / "withheld_gps.parquet")
    assert withheld["t"].tolist() == [1003.0, 1004.0, 1005.0]
    # A second run replaces the first only when complete, and leaves no temporary directory.
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(run)])
    assert res.exit_code == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "s"]
    assert not (run / "withheld_gps.parquet").exists()


def test_usage_errors_exit_2(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    assert runner.invoke(app, ["process", str(s), "-p", "no-such-pipeline", "-o", str(tmp_path / "r")]).exit_code == 2
    assert runner.invoke(app, ["process", str(s), "--mask-gps", "abc"]).exit_code == 2
    # a window on the wrong clock (seconds from the start; the log's t starts at 1000) withholds nothing
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "--mask-gps", "2:5", "-o", str(tmp_path / "r")])
    assert res.exit_code == 2 and "--mask-gps 2:5: no GPS fix in that window" in res.output, res.output
    assert runner.invoke(app, ["process", str(s), "-p", "ingest", "--set", "ingest.bogus=1", "-o", str(tmp_path / "r")]).exit_code == 2
    assert runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(s)]).exit_code == 2  # never over an input
    assert not (tmp_path / "r").exists()


def test_partial_output_of_a_killed_run_is_cleaned(tmp_path):
    s = write_minimal_session(tmp_path / "s")
    stale = tmp_path / ".run.tmp-999999999"  # no such process: a run killed midway
    stale.mkdir()
    (stale / "trajectory.parquet").write_bytes(b"half")
    res = runner.invoke(app, ["process", str(s), "-p", "ingest", "-o", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    assert not stale.exists() and (tmp_path / "run" / "summary.json").exists()


@pytest.mark.parametrize("args, option", [
    (["--duration", "1e9"], "--duration"),  # asked numpy for 894 GiB: "internal error: MemoryError"
    (["--rate", "1e9"], "--rate"),
    (["--duration", "nan"], "--duration"),
    (["--seed", "-1"], "--seed"),
    (["--t0", "1e308"], "--t0"),
    (["--outage", "nan:3"], "--outage"),
    (["--duration", "20000", "--rate", "2000"], "--duration"),  # 40 million samples: past the table row limit
])
def test_simulate_refuses_numbers_that_are_no_log(tmp_path, args, option):
    res = CliRunner().invoke(app, ["simulate", "drive", str(tmp_path / "d"), *args])
    assert res.exit_code == 2 and option in res.output and "internal error" not in res.output, res.output
    assert not (tmp_path / "d").exists()


def test_noise_plot_default_path_never_follows_the_session_name(tmp_path, monkeypatch):
    s = write_minimal_session(tmp_path / "s", seconds=150.0)  # static
    (tmp_path / "victim").mkdir()
    text = (s / "session.toml").read_text().replace('name = "minimal"', 'name = "../victim/evil"')
    (s / "session.toml").write_text(text)
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    res = runner.invoke(app, ["noise", str(s)])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "cwd").iterdir()) == ["s_allan.png"]
    assert not list((tmp_path / "victim").iterdir())


def test_objects_are_kept_from_the_collector_only_in_a_one_shot_process(monkeypatch):
    """`keep_until_exit` (after a report) freezes the heap only once `main()` marked the process as
    one-shot: CliRunner, tests and `tpos batch` go on running and must get their memory back."""
    import gc

    from tpos_cli.cli import _common

    assert gc.get_freeze_count() == 0
    _common.keep_until_exit()
    assert gc.get_freeze_count() == 0
    monkeypatch.setattr(_common, "_one_shot", True)
    try:
        _common.keep_until_exit()
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()


def test_batch_into_a_directory_it_cannot_write_is_one_line_before_any_session_runs(tmp_path, monkeypatch):
    """`tpos batch ... -o <read-only>` ran every session (each failing to claim its run directory), then
    ended in "tpos: internal error: OSError: [Errno 30] Read-only file system" from the record's mkdir."""

    s = write_minimal_session(tmp_path / "s")
    import errno
    import pathlib

    out = tmp_path / "ro" / "out"
    real_mkdir = pathlib.Path.mkdir

    def mkdir(self, *a, **k):
        if self == out:
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return real_mkdir(self, *a, **k)

    monkeypatch.setattr(pathlib.Path, "mkdir", mkdir)
    res = runner.invoke(app, ["batch", str(s), "-o", str(out), "-j", "1", "-q"])
    assert res.exit_code == 1, res.output
    assert res.output.strip() == f"error: -o {out}: cannot create the directory (Read-only file system)"


def test_ctrl_c_in_process_and_batch_says_what_was_kept(tmp_path, monkeypatch):
    """Ctrl-C in `tpos process` or `tpos batch` ended with exit 130 and not a word (typer's own handling)."""
    import tpos_cli.batch as b
    import tpos_cli.pipeline as pl

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    s = write_minimal_session(tmp_path / "s")
    monkeypatch.setattr(pl, "process_session", interrupted)
    res = runner.invoke(app, ["process", str(s), "-o", str(tmp_path / "run")])
    assert res.exit_code == 130 and "tpos process: interrupted; no run was written" in res.output
    assert not (tmp_path / "run").exists()
    monkeypatch.setattr(b, "run_batch", interrupted)
    res = runner.invoke(app, ["batch", str(s), "-o", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 130 and "interrupted; the sessions finished so far are in" in res.output


def test_a_warning_the_verdict_gives_as_its_reason_is_printed_once(tmp_path, monkeypatch):
    # review (session 8): the target chain's heading terms warn and the verdict names them with the same sentence
    # (quality.unsupported_heading_text): the console showed it twice; other warnings are printed as before
    from types import SimpleNamespace

    import tpos_cli.pipeline as pl
    from tpos_cli.quality import unsupported_heading_text

    said = unsupported_heading_text(0.62, 7.25)
    summary = {"session": {"name": "s"}, "pipeline": "target-fkf", "outputs": ["summary.json"], "timings_s": {"total": 1.0},
               "warnings": ["ranges: none in this session", said],
               "quality": {"verdict": "suspect", "reasons": [said]}}
    monkeypatch.setattr(pl, "process_session", lambda *a, **k: SimpleNamespace(summary=summary, run_dir=tmp_path / "run"))
    s = write_minimal_session(tmp_path / "s")
    res = runner.invoke(app, ["process", str(s), "-o", str(tmp_path / "run")])
    assert res.exit_code == 0 and res.output.count(said) == 1 and "warning: ranges: none in this session" in res.output
    summary["quality"] = {"verdict": "ok", "reasons": []}  # no verdict printed: the warning is
    res = runner.invoke(app, ["process", str(s), "-o", str(tmp_path / "run")])
    assert res.exit_code == 0 and f"warning: {said}" in res.output


@pytest.mark.parametrize("cmd", ["validate", "inspect", "export", "import"])
def test_ctrl_c_in_every_command_is_one_line_and_exit_130(tmp_path, monkeypatch, cmd):
    """Ctrl-C in validate / inspect / export / import ended with exit 130 and not a word: typer turns
    KeyboardInterrupt into a silent exit before main()'s handler sees it."""
    import tpos_cli.export.build as eb
    import tpos_cli.importers as imp
    import tpos_cli.session as sess

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    s = write_minimal_session(tmp_path / "s")
    for mod, name in ((sess, "load_session"), (eb, "export_run"), (imp, "import_into_session")):
        monkeypatch.setattr(mod, name, interrupted)
    args = {"validate": [str(s)], "inspect": [str(s)], "export": [str(tmp_path), "-o", str(tmp_path / "x.csv")],
            "import": ["csv", str(s / "imu.csv"), "-o", str(tmp_path / "new")]}[cmd]
    res = runner.invoke(app, [cmd, *args])
    lines = res.output.strip().splitlines()
    assert res.exit_code == 130 and len(lines) == 1 and lines[0].startswith(f"tpos {cmd}: interrupted"), res.output
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "new").exists()


def test_force_replaces_a_session_never_a_directory_of_other_files(tmp_path, monkeypatch):
    # audit (session 10): `tpos simulate drive DIR --force` deleted every file of any DIR (`.` included), and
    # `tpos calibrate-mag S -o DIR --force` any DIR, the one holding S too
    other = tmp_path / "important"
    (other / "sub").mkdir(parents=True)
    (other / "a.txt").write_text("precious")
    monkeypatch.chdir(tmp_path)
    for cmd in (["simulate", "drive", str(other), "--duration", "5", "--force", "-q"],
                ["calibrate-mag", str(write_minimal_session(tmp_path / "s")), "-o", str(other), "--force"]):
        res = CliRunner().invoke(app, cmd)
        assert res.exit_code == 2 and "is not a tpos session (no session.toml)" in res.output, res.output
    assert (other / "a.txt").read_text() == "precious" and (other / "sub").is_dir()
    sim = tmp_path / "sim"
    assert CliRunner().invoke(app, ["simulate", "drive", str(sim), "--duration", "5", "-q"]).exit_code == 0
    res = CliRunner().invoke(app, ["simulate", "drive", str(sim), "--duration", "5", "-q"])
    assert res.exit_code == 2 and "use --force" in res.output
    assert CliRunner().invoke(app, ["simulate", "drive", str(sim), "--duration", "5", "--force", "-q"]).exit_code == 0
    monkeypatch.chdir(sim)  # a session that holds the current directory, or the input session, is not replaced
    res = CliRunner().invoke(app, ["simulate", "drive", ".", "--duration", "5", "--force", "-q"])
    assert res.exit_code == 2 and "holds the current directory" in res.output
    monkeypatch.chdir(tmp_path)
    (sim / "inner").mkdir()
    write_minimal_session(sim / "inner" / "s")
    res = CliRunner().invoke(app, ["calibrate-mag", str(sim / "inner" / "s"), "-o", str(sim), "--force"])
    assert res.exit_code == 2 and "holds the input session" in res.output
    assert (sim / "session.toml").is_file() and (sim / "inner" / "s" / "session.toml").is_file()


@pytest.mark.parametrize("cmd", ["process", "export"])
def test_kill_pid_is_an_interrupt_that_leaves_nothing(tmp_path, cmd):
    """audit (session 11): `kill PID` (SIGTERM) ended `tpos process` where it stood (exit -15, no word) with
    .run.lock and .run.tmp-PID left beside the run directory; only `tpos report` treated it as Ctrl-C."""
    import os

    s = write_minimal_session(tmp_path / "s")
    out = tmp_path / "out"
    out.mkdir()
    if cmd == "export":
        assert runner.invoke(app, ["process", str(s), "-p", "drive-smooth", "-o", str(tmp_path / "run")]).exit_code == 0
    # SIGTERM arrives while the outputs are being written (a Parquet table into the temporary run directory, or
    # the export's bytes into its temporary file)
    patch = {"process": "import pyarrow.parquet as pq; pq.write_table = kill",
             "export": "import pathlib; pathlib.Path.write_bytes = kill"}[cmd]
    code = ("import os, signal, sys\n"
            "def kill(*a, **k):\n    os.kill(os.getpid(), signal.SIGTERM)\n"
            f"{patch}\n"
            "from tpos_cli.cli import main\nsys.argv[0] = 'tpos'\nmain()\n")
    args = {"process": ["process", str(s), "-p", "drive-smooth", "-o", str(out / "run")],
            "export": ["export", str(tmp_path / "run"), "-o", str(out / "x.csv")]}[cmd]
    res = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=240,
                         env=dict(os.environ, NUMBA_NUM_THREADS="1"))
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 130 and len(lines) == 1 and lines[0].startswith(f"tpos {cmd}: interrupted"), (res.returncode, lines)
    assert sorted(p.name for p in out.iterdir()) == []  # no run, lock, temporary directory or file


def _commands():
    import typer

    return typer.main.get_command(app).commands


@pytest.mark.parametrize("cmd", sorted(_commands()))
def test_each_help_example_is_one_runnable_command_line(cmd):
    # audit (session 25): `tpos simulate --help` ran its two examples into one paragraph ("... --outage 150:20
    # RTK-like fixes: tpos simulate drive ..."), which no shell runs as printed. Each example paragraph holds one
    # `tpos CMD` line whose options the command has.
    command = _commands()[cmd]
    known = {o for p in command.params for o in (*p.opts, *p.secondary_opts)}
    res = runner.invoke(app, [cmd, "--help"], terminal_width=200)
    assert res.exit_code == 0
    paragraphs = [" ".join(p.split()) for p in res.output.split("\n\n")]
    examples = [p for p in paragraphs if p.startswith("Example")]
    assert examples, res.output
    for ex in examples:
        assert ex.count("tpos ") == 1, ex
        line = ex[ex.index(f"tpos {cmd}"):].split()
        unknown = [w for w in line if w.startswith("-") and w.split("=")[0] not in known]
        assert not unknown, (ex, unknown)


def test_calibrate_mag_never_writes_its_copy_into_the_input_session(tmp_path):
    # audit (session 25): `tpos calibrate-mag broad_02 -o broad_02/cal` wrote the calibrated copy inside the
    # session it read (exit 0), the session directory changed; `tpos process -o` refuses the same.
    s = write_minimal_session(tmp_path / "s")
    before = sorted(p.name for p in s.iterdir())
    res = CliRunner().invoke(app, ["calibrate-mag", str(s), "-o", str(s / "cal")])
    assert res.exit_code == 2 and "inside the input session" in res.output, res.output
    assert sorted(p.name for p in s.iterdir()) == before
