"""RunContext's status line: stage, elapsed time, and a notice while numba compiles."""

import numpy as np
from numba import njit
from numba.core import event

from tpos_cli.chains.context import RunContext, _compile_notice


class _Status:
    """Stands in for rich's status: records what the line was set to."""

    def __init__(self):
        self.lines = []

    def update(self, text):
        self.lines.append(text)


def test_status_line_says_when_numba_compiles():
    ctx = RunContext()
    ctx._status = _Status()
    with ctx.stage("alignment"):
        pass

    @njit  # a new function (no cache): compiles on its first call
    def twice(x):
        return 2.0 * x

    with event.install_listener("numba:compile", _compile_notice(ctx)):
        assert twice(np.float64(1.5)) == 3.0
        assert twice(np.float64(2.5)) == 5.0  # compiled: no notice
    lines = ctx._status.lines
    assert lines[0].startswith("[bold]alignment[/bold] (") and "compiling" not in lines[0]
    assert lines[1].endswith(" - compiling kernels (first run only)")
    assert "compiling" not in lines[2]
    assert len(lines) == 3


def test_warm_numba_runs_only_with_a_spare_cpu(monkeypatch):
    """One CPU: no helper thread; more: numba's set-up in a thread that finishes (under its compiler lock)."""
    from tpos_cli.chains import context

    monkeypatch.setattr(context, "spare_cpu", lambda: False)
    assert context.warm_numba() is None
    monkeypatch.setattr(context, "spare_cpu", lambda: True)
    th = context.warm_numba()
    th.join(timeout=120)
    assert not th.is_alive()


def test_tpos_threads_1_keeps_one_thread(monkeypatch):
    from tpos_cli.chains.context import spare_cpu

    monkeypatch.setenv("TPOS_THREADS", "1")
    assert not spare_cpu()
    monkeypatch.setenv("TPOS_THREADS", "2")
    assert spare_cpu()


def test_a_busy_machine_has_no_spare_cpu(monkeypatch):
    """Without TPOS_THREADS: a helper thread only while the load average leaves a CPU free."""
    import os

    from tpos_cli.chains.context import spare_cpu

    monkeypatch.delenv("TPOS_THREADS", raising=False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.9, 0.5, 0.5))
    assert spare_cpu()
    monkeypatch.setattr(os, "getloadavg", lambda: (1.6, 0.5, 0.5))
    assert not spare_cpu()
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    assert not spare_cpu()
