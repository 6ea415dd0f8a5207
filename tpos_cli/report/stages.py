"""Where a report's time goes: named stages timed on the process's CPU clock.

`make_report`, `build_context` and `write_pdf` take an optional `StageClock`; `benchmarks/report.py`
passes one and prints each stage's share (loading, accuracy tables, each figure, PDF writing). The
CPU clock (`time.process_time`, seconds of this process on all its threads) is used rather than the
wall clock so that the shares hold on a machine other jobs share. Without a clock nothing is timed.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field


@dataclass
class StageClock:
    """CPU seconds per stage name, summed over repeated entries, in order of first entry."""

    cpu_s: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        t0 = time.process_time()
        try:
            yield
        finally:
            self.cpu_s[name] = self.cpu_s.get(name, 0.0) + time.process_time() - t0


def timed(clock: StageClock | None, name: str):
    """`clock.stage(name)`, or a context that times nothing when there is no clock."""
    return clock.stage(name) if clock is not None else nullcontext()
