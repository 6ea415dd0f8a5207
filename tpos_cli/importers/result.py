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


def gps_result(g: pd.DataFrame, name: str, notes: list[str], leap: str | None) -> ImportResult:
    """The `gps` table's result with the notes a receiver log's import ends with: `leap`
    (`gpstime.leap_table_note`, when there is one) and whether its velocities are differences of its
    own fixes (`velocity_timing.velocity_timing_note`)."""
    from tpos_cli.importers.velocity_timing import velocity_timing_note

    lag = velocity_timing_note(g, name)
    return ImportResult({"gps": g}, {}, (*notes, *([f"{name}: {leap}"] if leap else []), *([lag] if lag else [])))


def read_source(path: Path, clock: str, *, text: bool = True) -> bytes:
    """The bytes of a receiver log to import onto `clock`; a bad clock, a missing file, or one that is
    not a regular file of bounded size (a FIFO, /dev/zero; NULs in a text format) exits 2."""
    if clock not in CLOCKS:
        raise InvalidInputError(f"clock must be one of {', '.join(CLOCKS)}, got {clock!r}")
    return read_source_bytes(Path(path), text=text)
