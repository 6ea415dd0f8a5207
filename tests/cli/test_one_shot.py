"""A one-shot `tpos process`/`report`/`batch` ends its process with os._exit after the command
(`_common.run_to_exit`, `_common.end_process`): exit codes and outputs are those of the same command
run under CliRunner, where nothing of it applies."""

import gc
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from tpos_cli.cli import _common, app

SAMPLE = Path(__file__).resolve().parents[2] / "sample_logs" / "drive_outage"


@pytest.fixture
def one_shot(monkeypatch):
    """`main()`'s marking of a one-shot process, undone after the test (collector, flags)."""
    monkeypatch.setattr(_common, "_one_shot", True)
    monkeypatch.setattr(_common, "_end_with_os_exit", False)
    yield
    gc.enable()


def test_nothing_ends_the_process_unless_a_one_shot_command_asked(monkeypatch):
    calls = []
    monkeypatch.setattr(os, "_exit", calls.append)
    _common.run_to_exit()  # not one-shot (tests, CliRunner): no effect
    assert gc.isenabled()
    _common.end_process(0)
    assert calls == []


@pytest.fixture
def only_thread(monkeypatch):
    """The test process as a one-shot command's is: its only thread, and atexit handlers recorded, not
    run. pytest's process may hold threads other tests' libraries keep for the process (dask.distributed's
    offload executor, started by tests/test_batch.py's Dask test, lives until exit), and running its
    atexit handlers mid-suite would shut down multiprocessing's machinery for the tests after."""
    ran = []
    monkeypatch.setattr(_common.threading, "active_count", lambda: 1)
    monkeypatch.setattr(_common.atexit, "_run_exitfuncs", lambda: ran.append("atexit"))
    return ran


def test_end_process_exits_with_the_commands_code(monkeypatch, one_shot, only_thread):
    calls = []
    monkeypatch.setattr(os, "_exit", calls.append)
    _common.run_to_exit()
    assert not gc.isenabled()
    for code in (None, 0, 1, 2):
        _common.end_process(code)
    assert calls == [0, 0, 1, 2] and only_thread == ["atexit"] * 4
    _common.end_process("a message")  # SystemExit("...") prints it: Python's own exit does that
    assert calls == [0, 0, 1, 2]


def test_end_process_leaves_the_exit_to_python_while_another_thread_runs(monkeypatch, one_shot):
    calls = []
    monkeypatch.setattr(os, "_exit", calls.append)
    monkeypatch.setattr(_common.atexit, "_run_exitfuncs", lambda: calls.append("atexit"))
    _common.run_to_exit()
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        _common.end_process(0)
    finally:
        stop.set()
        other.join()
    assert calls == []


def test_batch_keeps_the_collector(monkeypatch, one_shot):
    monkeypatch.setattr(os, "_exit", lambda code: None)
    _common.run_to_exit(pause_collector=False)
    assert gc.isenabled() and _common._end_with_os_exit


def _tables(run: Path) -> dict:
    return {p.name: pq.read_table(p) for p in sorted(run.glob("*.parquet"))}


def _summary(run: Path) -> dict:
    s = json.loads((run / "summary.json").read_text())
    for k in ("timings_s", "created_utc"):
        s.pop(k)
    return s


def test_a_one_shot_process_writes_what_cli_runner_writes(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    res = subprocess.run([sys.executable, "-m", "tpos_cli", "process", str(SAMPLE), "-o", str(tmp_path / "a")],
                         capture_output=True, text=True, timeout=600, env=env)
    ref = CliRunner().invoke(app, ["process", str(SAMPLE), "-o", str(tmp_path / "b")])
    assert res.returncode == 0 == ref.exit_code, res.stderr
    line_a = res.stdout.replace(str(tmp_path / "a"), "RUN").split(" in ")[0]  # up to the run's time
    assert line_a == ref.output.replace(str(tmp_path / "b"), "RUN").split(" in ")[0]
    a, b = _tables(tmp_path / "a"), _tables(tmp_path / "b")
    assert list(a) == list(b) == ["innovations.parquet", "trajectory.parquet"]
    for name in a:
        assert a[name].equals(b[name], check_metadata=True), name
    assert _summary(tmp_path / "a") == _summary(tmp_path / "b")


def test_a_one_shot_process_refusing_its_input_exits_2(tmp_path):
    res = subprocess.run([sys.executable, "-m", "tpos_cli", "process", str(tmp_path / "none"), "-o", str(tmp_path / "a")],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 2 and res.stderr.startswith("error: ") and res.stderr.count("\n") == 1, res.stderr
    assert not (tmp_path / "a").exists()


def test_unused_numpy_modules_load_on_first_use():
    """`_common.defer_unused_imports` (one-shot only): scipy's import, which touches every attribute of
    numpy, no longer runs numpy.f2py / numpy.testing; a caller that uses them gets them whole. In a
    fresh interpreter: this one may hold them already."""
    code = (
        "import sys\n"
        "from tpos_cli.cli import _common\n"
        "_common.defer_unused_imports()\n"  # not one-shot: nothing changes
        "assert 'numpy.f2py' not in sys.modules\n"
        "_common.mark_one_shot()\n"
        "_common.defer_unused_imports()\n"
        "import scipy.linalg, scipy.special, numpy\n"
        "assert 'numpy.f2py.crackfortran' not in sys.modules and 'numpy.testing._private.utils' not in sys.modules\n"
        "numpy.testing.assert_array_equal(numpy.arange(3), [0, 1, 2])\n"
        "from numpy.testing import assert_allclose\n"
        "assert_allclose(1.0, 1.0)\n"
        "import numpy.f2py\n"
        "assert callable(numpy.f2py.get_include) and 'numpy.f2py.crackfortran' in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[2])


def test_a_one_shot_report_leaves_the_unused_numpy_modules_unloaded(tmp_path):
    """`tpos report` defers numpy.f2py / numpy.testing as `tpos process` does (`_common.defer_unused_imports`):
    scipy.special's import, which the report's statistics need, no longer runs numpy.f2py's crackfortran
    (0.05 s of a report); nor does matplotlib's PDF backend import fontTools.subset (0.13 s) for pages in
    the standard PDF fonts, which are not embedded; nor pandas (0.34 s): the run's tables are read and the report's
    own written without it for a session in Parquet (`load_run(frames=False)`, `io.columns.to_arrow_as_pandas`),
    nor pyarrow.compute (0.06 s: its labels are read as dictionaries, not encoded).
    In a fresh interpreter, as a user runs it (-X importtime lists what it imports)."""
    assert CliRunner().invoke(app, ["process", str(SAMPLE), "-o", str(tmp_path / "run"), "-q"]).exit_code == 0
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    res = subprocess.run([sys.executable, "-X", "importtime", "-m", "tpos_cli", "report", str(tmp_path / "run")],
                         capture_output=True, text=True, timeout=600, env=env)
    assert res.returncode == 0, res.stderr[-2000:]
    imported = {line.rsplit("|", 1)[-1].strip() for line in res.stderr.splitlines() if line.startswith("import time:")}
    assert "scipy.special._ufuncs" in imported  # scipy.special loaded: the import that used to pull them in
    assert not {"numpy.f2py.crackfortran", "numpy.testing._private.utils"} & imported
    assert "matplotlib.backends.backend_pdf" in imported and "fontTools.subset" not in imported
    assert "pyarrow.parquet" in imported and not {"pandas", "pyarrow.compute"} & imported  # text read as dictionaries
    assert b"/BaseFont /Helvetica" in (tmp_path / "run" / "report.pdf").read_bytes()  # the standard font, as before


def test_a_deferred_font_subsetter_still_embeds_the_fonts_a_page_needs(tmp_path):
    """With fontTools.subset deferred (a one-shot `tpos report`), a page whose text the standard PDF fonts
    lack (Cyrillic, a mathtext sigma) is embedded as before: as Type 3 (the report's setting, which never
    uses the subsetter) and, with pdf.fonttype 42, as a TrueType subset, the subsetter loaded at its first
    use. In a fresh interpreter: this one may hold fontTools.subset already."""
    code = (
        "import sys\n"
        "from tpos_cli.cli import _common\n"
        "_common.mark_one_shot()\n"
        "_common.defer_unused_imports('fontTools.subset')\n"
        "import matplotlib\nmatplotlib.use('Agg')\n"
        "from matplotlib.backends.backend_pdf import PdfPages\nfrom matplotlib.figure import Figure\n"
        "from tpos_cli.report.pdf import core_fonts_if_they_fit\n"
        "assert 'fontTools.subset' in sys.modules and 'fontTools.subset.cff' not in sys.modules\n"
        "for fonttype in (3, 42):\n"
        "    fig = Figure(figsize=(4, 3))\n    fig.text(0.1, 0.8, 'session Проезд_03')\n"
        "    fig.text(0.1, 0.5, r'$\\sigma_{yaw}$ 1.2 deg')\n"
        f"    path = {str(tmp_path)!r} + f'/p{{fonttype}}.pdf'\n"
        "    with matplotlib.rc_context({'pdf.fonttype': fonttype}), core_fonts_if_they_fit([fig]), PdfPages(path) as pdf:\n"
        "        pdf.savefig(fig)\n"
        "    assert ('fontTools.subset.cff' in sys.modules) == (fonttype == 42)\n"  # the subsetter's code ran for 42 only
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[2])
    type3, truetype = ((tmp_path / f"p{k}.pdf").read_bytes() for k in (3, 42))
    assert b"/BaseFont /Helvetica" not in type3 and b"DejaVuSans" in type3 and b"/Type3" in type3
    assert b"/BaseFont /Helvetica" not in truetype and b"DejaVuSans" in truetype and b"FontFile2" in truetype


@pytest.mark.parametrize("given, expected", [(None, "1"), ("3", "3")])
def test_main_gives_blas_one_thread_unless_the_user_sets_it(given, expected):
    """`main()` sets OPENBLAS_NUM_THREADS=1 before numpy loads (threads spin-waiting after tpos's dot products took
    the CPU on a busy machine); a number the user set is kept. In a fresh interpreter (`--version`: numpy never loads)."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    code = ("import os, sys\nfrom tpos_cli import cli\nsys.argv = ['tpos', '--version']\n"
            "try:\n    cli.main()\nexcept SystemExit:\n    pass\nprint(os.environ.get('OPENBLAS_NUM_THREADS'), 'numpy' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2]).stdout
    assert out.split()[-2:] == [expected, "False"], out


def test_main_builds_only_the_command_it_runs():
    """`main()` runs `tpos COMMAND` with an app of that command alone (`cli.make_app`): typer builds the
    parameters of every command it holds when it starts. In a fresh interpreter (`tpos pipelines`)."""
    code = ("import atexit, sys\nimport typer.main as tm\nbuilt = []\norig = tm.get_command_from_info\n"
            "def spy(command_info, **kw):\n    built.append(command_info.name)\n    return orig(command_info=command_info, **kw)\n"
            "tm.get_command_from_info = spy\natexit.register(lambda: print('BUILT', *built))\n"
            "from tpos_cli import cli\nsys.argv = ['tpos', 'pipelines']\ncli.main()\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2]).stdout
    assert out.splitlines()[-1] == "BUILT pipelines" and "drive-smooth" in out, out


@pytest.mark.parametrize("name", ["process", "report", "batch", "import", "calibrate-mag"])
def test_a_one_command_app_parses_and_helps_as_the_whole_app(name, tmp_path):
    from tpos_cli.cli import make_app

    one = make_app((name,))
    runner = CliRunner()
    for args in ([name, "--help"], [name, "--no-such-option"], [name, str(tmp_path / "none")], ["--version"]):
        a, b = runner.invoke(one, args), runner.invoke(app, args)
        assert (a.exit_code, a.output) == (b.exit_code, b.output), args


@pytest.mark.parametrize("given, scanned", [(None, False), ("", True)])
def test_main_turns_pydantic_plugins_off_unless_the_user_sets_it(given, scanned):
    """`main()` sets PYDANTIC_DISABLE_PLUGINS=1 (no search of every installed distribution's entry points for
    plugins when the first pipeline model is validated); a value the user set is kept ("": plugins on, searched)."""
    env = {k: v for k, v in os.environ.items() if k != "PYDANTIC_DISABLE_PLUGINS"}
    if given is not None:
        env["PYDANTIC_DISABLE_PLUGINS"] = given
    code = ("import atexit, sys\nfrom pydantic.plugin import _loader\n"
            "atexit.register(lambda: print('SCANNED', _loader._plugins is not None))\n"
            "from tpos_cli import cli\nsys.argv = ['tpos', 'pipelines']\ncli.main()\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2]).stdout
    assert out.splitlines()[-1] == f"SCANNED {scanned}", out
