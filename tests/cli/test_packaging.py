"""Packaging: the pipelines are package data found from any directory, and `tpos --version`.

`.ci/run` also builds an sdist and a wheel, installs the wheel into a fresh virtualenv and runs every
sample from another directory; these tests check the same facts on the installed checkout.
"""

import importlib.metadata
import importlib.resources
import subprocess
import sys
from pathlib import Path

from tpos_cli import __version__
from tpos_cli.config import list_pipelines, pipelines_dir

REPO = Path(__file__).resolve().parents[2]


def test_version_flag_prints_the_installed_version(tmp_path):
    res = subprocess.run([sys.executable, "-m", "tpos_cli", "--version"], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"tpos {__version__}"
    assert importlib.metadata.version("tpos") == __version__  # pyproject reads it from tpos_cli.__version__


def test_pipelines_are_package_data():
    data = importlib.resources.files("tpos_cli.pipelines")
    bundled = sorted(p.name for p in data.iterdir() if p.name.endswith(".toml"))
    assert bundled == sorted(p.name for p in (REPO / "pipelines").glob("*.toml"))
    assert Path(str(pipelines_dir())) == Path(str(data))
    kinds = {k for p in list_pipelines() for k in p.kinds}
    assert kinds == {"drive", "target", "ranging"}


def test_pipelines_found_from_another_directory(tmp_path):
    res = subprocess.run([sys.executable, "-m", "tpos_cli", "pipelines"], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    for name in ("drive-smooth", "target-fkf", "ranging-fatci", "ingest"):
        assert name in res.stdout
