"""The bundled pipelines: the TOML files beside this file, installed as the package `tpos_cli.pipelines`
(see setup.py) and read with importlib.resources (`tpos_cli.config.pipelines_dir`). Nothing here is code."""
