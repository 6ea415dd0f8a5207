"""What every importer returns: contract tables, `session.toml` additions, and notes for the user."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers.gpstime import CLOCKS
from tpos_cli.io.bounded import read_source_bytes


@dataclass(frozen=True)
class ImportResult:
    tables: dict[str, pd.DataFrame]  # contract table name -> DataFrame with contract columns
    toml: dict = field(default_factory=dict)  # merged into session.toml
    notes: tuple[str, ...] = ()  # what was dropped, assumed or fitted (printed by the CLI)


def read_source(path: Path, clock: str, *, text: bool = True) -> bytes:
    """The bytes of a receiver log to import onto `clock`; a bad clock, a missing file, or one that is
    not a regular file of bounded size (a FIFO, /dev/zero; NULs in a text format) exits 2."""
    if clock not in CLOCKS:
        raise InvalidInputError(f"clock must be one of {', '.join(CLOCKS)}, got {clock!r}")
    return read_source_bytes(Path(path), text=text)
