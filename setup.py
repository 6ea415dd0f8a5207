"""Package layout; everything else about the build is in pyproject.toml.

The bundled pipelines stay in `pipelines/` at the repository root (data, edited as TOML) and are
installed as the package `tpos_cli.pipelines`, which the code reads with importlib.resources. A
`package_dir` entry maps the folder into the package, so a checkout, an editable install, an sdist
and a wheel all find the same files. (pyproject.toml's `packages.find` cannot add a package mapped
from outside the `tpos_cli/` tree, hence this file.)
"""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["tpos_cli", "tpos_cli.*"]), "tpos_cli.pipelines"],
    package_dir={"tpos_cli.pipelines": "pipelines"},
    package_data={"tpos_cli": ["py.typed"], "tpos_cli.pipelines": ["*.toml", "*.md"]},
)
