"""The stage clock: every stage of a report is named on it (benchmarks/report.py prints them)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from tests.report import synth
from tpos_cli.report.build import make_report
from tpos_cli.report.stages import StageClock, timed


def test_stage_clock_sums_repeated_stages():
    c = StageClock()
    for _ in range(3):
        with c.stage("a"):
            pass
    with timed(c, "b"):
        pass
    with timed(None, "c"):  # no clock: nothing recorded, nothing raised
        pass
    assert list(c.cpu_s) == ["a", "b"] and all(v >= 0.0 for v in c.cpu_s.values())


def test_report_stages_are_named(tmp_path):
    s = synth.write_session(tmp_path / "s")
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)
    traj = pd.concat([synth.trajectory_rows(n, t10, [1.0, 0.0, 0.0], sigma=(1.0, 1.0, 1.0)) for n in ("forward", "backward")])
    clock = StageClock()
    res = make_report(synth.write_run(tmp_path / "r", s, traj), clock=clock)
    names = set(clock.cpu_s)
    assert {"load: run", "load: session", "load: truth", "accuracy tables", "filter health", "PDF writing"} <= names
    assert {f"figure: {p}" for page in res.pages for p in page.split("+")} <= names


def test_cyclic_gc_paused_restores_the_collector():
    import gc

    from tpos_cli.report.collector import cyclic_gc_paused

    assert gc.isenabled()
    with cyclic_gc_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    gc.disable()
    try:
        with cyclic_gc_paused():
            pass
        assert not gc.isenabled()  # it was off before: left off
    finally:
        gc.enable()
