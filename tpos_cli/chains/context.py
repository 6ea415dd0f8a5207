"""What a chain receives and returns: `RunContext` (timings, counts, warnings, progress) and
`ChainOutput` (tables and summary that `pipeline` writes). Chains import this module, never
`pipeline`, so that the wiring module can import every chain without a cycle."""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pandas as pd

    from tpos_cli.io.columns import Columns


@dataclass(frozen=True)
class ChainOutput:
    """What a chain returns; `pipeline` writes it. Tables are DataFrames or `io.columns.Columns` (the
    drive chain's: no pandas in its process); `quality` and `advice` read either."""

    trajectory: pd.DataFrame | Columns | None = None
    targets: pd.DataFrame | Columns | None = None
    tables: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)


def spare_cpu() -> bool:
    """Whether a second CPU is free for this process: independent work then goes to a helper thread
    (`warm_numba`, `pipeline._beside`, `drive_smooth.process_drive`; the results are the same bits
    either way). Free: the process may run on more than one CPU and the system's one-minute load
    average is below their number less a half (on a busy machine a second thread only competes
    with the others' work and costs CPU). TPOS_THREADS in the environment decides instead: 1 keeps
    every run on one thread (e.g. one process per core), 2 or more uses a helper thread."""
    env = os.environ.get("TPOS_THREADS", "").strip()
    if env.isdigit():
        return int(env) > 1
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # not available on this system
        load = 0.0
    return n > 1 and load < n - 0.5


def warm_numba() -> threading.Thread | None:
    """With a spare CPU, numba's first-dispatch set-up (its typing and lowering registries, ~0.2 s
    CPU, scipy.linalg's import among it) started in a helper thread, so that it overlaps the
    reading of the session (pyarrow and numpy release the GIL); under numba's compiler lock, which
    the first kernel dispatch then waits for. Returns the thread (join it before exiting), or None."""
    if not spare_cpu():
        return None

    def refresh() -> None:
        from numba.core.compiler_lock import global_compiler_lock
        from numba.core.registry import cpu_target

        try:
            with global_compiler_lock:
                cpu_target.target_context.refresh()
        except Exception:  # noqa: BLE001 - the first dispatch repeats it and reports what fails
            pass

    th = threading.Thread(target=refresh, name="tpos-numba-warm", daemon=True)
    th.start()
    return th


class RunContext:
    """Timings, counts, warnings and progress for one run; handed to the chain."""

    def __init__(self, progress: bool = False):
        self.timings_s: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self.warnings: list[str] = []
        self._progress = progress
        self._status = None
        self._stage = ""
        self._compiling = 0
        self._t0 = time.perf_counter()

    def _show(self) -> None:
        """The status line: the stage, the time since the start, and whether numba is compiling."""
        if self._status is not None:
            doing = " - compiling kernels (first run only)" if self._compiling else ""
            self._status.update(f"[bold]{self._stage}[/bold] ({time.perf_counter() - self._t0:.1f} s){doing}")

    @contextlib.contextmanager
    def stage(self, name: str):
        """Time a stage into summary.json; with progress on, show it on a status line."""
        t = time.perf_counter()
        self._stage = name.replace("_", " ")
        self._show()
        try:
            yield
        finally:
            self.timings_s[name] = self.timings_s.get(name, 0.0) + time.perf_counter() - t

    @contextlib.contextmanager
    def live(self, label: str):
        """A status line (rich) for the whole run when progress is on; nothing otherwise. While
        numba compiles (the first run after an install; the kernels are cached after it) the line
        says so, from numba's compile events."""
        if not self._progress:
            yield
            return
        from numba.core import event
        from rich.console import Console

        with Console(stderr=True).status(label) as status, event.install_listener("numba:compile", _compile_notice(self)):
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



def _compile_notice(ctx: RunContext):
    """A numba event listener that counts the compiles in progress (nested: a kernel compiles the
    kernels it calls) and refreshes `ctx`'s status line when the outermost starts and ends."""
    from numba.core import event

    class CompileNotice(event.Listener):
        def on_start(self, ev) -> None:
            ctx._compiling += 1
            if ctx._compiling == 1:
                ctx._show()

        def on_end(self, ev) -> None:
            ctx._compiling -= 1
            if ctx._compiling == 0:
                ctx._show()

    return CompileNotice()
