"""What a chain receives and returns: `RunContext` (timings, counts, warnings, progress) and
`ChainOutput` (tables and summary that `pipeline` writes). Chains import this module, never
`pipeline`, so that the wiring module can import every chain without a cycle."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterable
from dataclasses import dataclass, field

import pandas as pd


@dataclass(frozen=True)
class ChainOutput:
    """What a chain returns; `pipeline` writes it."""

    trajectory: pd.DataFrame | None = None
    targets: pd.DataFrame | None = None
    tables: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)


class RunContext:
    """Timings, counts, warnings and progress for one run; handed to the chain."""

    def __init__(self, progress: bool = False):
        self.timings_s: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self.warnings: list[str] = []
        self._progress = progress
        self._status = None
        self._t0 = time.perf_counter()

    @contextlib.contextmanager
    def stage(self, name: str):
        """Time a stage into summary.json; with progress on, show it on a status line."""
        t = time.perf_counter()
        if self._status is not None:
            self._status.update(f"[bold]{name.replace('_', ' ')}[/bold] ({time.perf_counter() - self._t0:.1f} s)")
        try:
            yield
        finally:
            self.timings_s[name] = self.timings_s.get(name, 0.0) + time.perf_counter() - t

    @contextlib.contextmanager
    def live(self, label: str):
        """A status line (rich) for the whole run when progress is on; nothing otherwise."""
        if not self._progress:
            yield
            return
        from rich.console import Console

        with Console(stderr=True).status(label) as status:
            self._status = status
            try:
                yield
            finally:
                self._status = None

    def count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + int(n)

    def warn(self, message: str) -> None:
        self.warnings.append(message)

    def progress(self, iterable: Iterable, total: int | None = None, label: str = "") -> Iterable:
        """Wrap a loop in a progress bar when enabled (a TTY and not --quiet)."""
        if not self._progress:
            return iterable
        from rich.progress import track

        return track(iterable, total=total, description=label or "working")
