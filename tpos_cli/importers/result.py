"""What every importer returns: contract tables, `session.toml` additions, and notes for the user."""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd


@dataclass(frozen=True)
class ImportResult:
    tables: dict[str, pd.DataFrame]  # contract table name -> DataFrame with contract columns
    toml: dict = field(default_factory=dict)  # merged into session.toml
    notes: tuple[str, ...] = ()  # what was dropped, assumed or fitted (printed by the CLI)
