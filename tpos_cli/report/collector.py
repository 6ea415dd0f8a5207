"""Python's cyclic garbage collector during a report.

A report builds some 10^5 matplotlib objects, all alive until the PDF is written, and its first
call imports pandas, pyarrow, scipy.special and matplotlib (~10^6 objects). The cyclic collector,
triggered by allocation counts, scans them again and again meanwhile: about 0.16 s (320
collections) of a 2.4 s `tpos report` of the simulated drive hour, measured by counting
`gc.callbacks` over the whole command. Reference counting frees everything not in a cycle; the
cycles (artists and their figures) are collected once the collector resumes. Light on purpose: it
is imported before the heavy imports it pauses the collector for.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def cyclic_gc_paused() -> Iterator[None]:
    """Pause the cyclic garbage collector inside the block; resume it only if it was running."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()
