"""`tpos pipelines`: list the bundled pipelines."""

from __future__ import annotations

import typer

from tpos_cli.cli._common import exit_on_error


def pipelines() -> None:
    """List the pipelines in pipelines/ with one-line descriptions and the session kinds they are the default for.

    Example: tpos pipelines
    """
    from tpos_cli.config import list_pipelines

    with exit_on_error():
        for p in list_pipelines():
            kinds = f" [default for: {', '.join(p.kinds)}]" if p.kinds else ""
            typer.echo(f"{p.path.stem:16s} {p.description}{kinds}")
