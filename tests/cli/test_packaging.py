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


def test_pipelines_are_package_data(tmp_path):
    # the installed package's data, read from another directory (after a plain `pip install .` the tests import
    # the checkout, which has no tpos_cli.pipelines: audit, session 9); in this process pipelines_dir() finds the
    # same files either way
    code = ("import importlib.resources as r; "
            "print(' '.join(sorted(p.name for p in r.files('tpos_cli.pipelines').iterdir() if p.name.endswith('.toml'))))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == sorted(p.name for p in (REPO / "pipelines").glob("*.toml"))
    assert sorted(p.name for p in pipelines_dir().glob("*.toml")) == res.stdout.split()
    kinds = {k for p in list_pipelines() for k in p.kinds}
    assert kinds == {"drive", "target", "ranging"}


def test_pipelines_found_from_another_directory(tmp_path):
    res = subprocess.run([sys.executable, "-m", "tpos_cli", "pipelines"], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    for name in ("drive-smooth", "target-fkf", "ranging-fatci", "ingest"):
        assert name in res.stdout
