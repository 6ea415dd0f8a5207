"""Importers: velocities that are differences of the receiver's own fixes are named at import time
(the raw walk's .pos and .ubx: RMS 0.036 m/s against the central differences 0.15 s earlier, 0.097 at
their stamps). The test is the filter's own, `fusion.velocity_lag.velocity_latency_s`."""

from __future__ import annotations

import numpy as np
import pandas as pd

from tpos_cli.frames.geodetic import ned_to_lla
from tpos_cli.importers.velocity_timing import velocity_timing_note

ORIGIN = np.array([40.0967, -105.1472, 1580.0])


def _track(v_of: str, rate_hz: float = 4.0, duration_s: float = 60.0, speed: float = 6.0) -> pd.DataFrame:
    """A car turning and braking (heading 0.3 rad/s sway, speed +-30 %) with fixes at `rate_hz`:
    velocities instantaneous ("now"), or the position difference with the fix before/after."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    tt = np.arange(0.0, duration_s, 1e-3)  # dense integration of the motion
    s = speed * (1.0 + 0.3 * np.sin(2 * np.pi * tt / 20.0))
    yaw = 1.5 * np.sin(0.2 * tt)
    vn_d, ve_d = s * np.cos(yaw), s * np.sin(yaw)
    n_d, e_d = np.cumsum(vn_d) * 1e-3, np.cumsum(ve_d) * 1e-3
    n, e = np.interp(t, tt, n_d), np.interp(t, tt, e_d)
    ned = np.column_stack([n, e, np.zeros_like(t)])
    lla = ned_to_lla(ned, ORIGIN)
    if v_of == "now":
        vn, ve = np.interp(t, tt, vn_d), np.interp(t, tt, ve_d)
    elif v_of == "before":
        vn, ve = np.r_[np.nan, np.diff(n) * rate_hz], np.r_[np.nan, np.diff(e) * rate_hz]
    else:
        vn, ve = np.r_[np.diff(n) * rate_hz, np.nan], np.r_[np.diff(e) * rate_hz, np.nan]
    return pd.DataFrame({"t": 408000.0 + t, "lat": lla[:, 0], "lon": lla[:, 1], "h": lla[:, 2], "vn": vn, "ve": ve, "vd": 0.0})


def test_velocities_of_the_fix_before_are_named_with_their_half_interval():
    note = velocity_timing_note(_track("before"), "x.pos")
    assert note is not None and "differences with the fix before" in note and "centred 0.125 s earlier" in note


def test_velocities_of_the_fix_after_are_named():
    note = velocity_timing_note(_track("after"), "x.pos")
    assert note is not None and "differences with the fix after" in note and "0.125 s later" in note


def test_instantaneous_velocities_and_a_standing_receiver_get_no_note():
    assert velocity_timing_note(_track("now"), "x.pos") is None
    still = _track("now", speed=0.0)
    assert velocity_timing_note(still, "x.pos") is None  # not moving: the differences hold only noise
    assert velocity_timing_note(_track("before").drop(columns=["vn"]), "x.pos") is None  # no velocities


def test_the_note_is_the_filters_own_lag_at_every_fix_rate():
    # review (session 8): the importer kept its own test beside fusion.insgps.velocity_latency_s (what process
    # applies when the clock states are off); now one test serves both, so the two cannot disagree
    from tpos_cli.fusion.insgps import GpsFixes, velocity_latency_s

    for rate_hz in (1.0, 2.0, 5.0, 10.0):
        g = _track("before", rate_hz=rate_hz, duration_s=120.0)
        note = velocity_timing_note(g, "x.pos")
        g = g.dropna()
        vel = np.column_stack([g["vn"], g["ve"], np.zeros(len(g))])
        lag, _ = velocity_latency_s(GpsFixes(g["t"].to_numpy(), g[["lat", "lon", "h"]].to_numpy(), vel,
                                             np.ones((len(g), 3)), np.ones((len(g), 3))))
        assert abs(lag - 0.5 / rate_hz) < 1e-9 and note is not None and f"central differences {lag:g} s earlier" in note
        assert velocity_timing_note(_track("now", rate_hz=rate_hz, duration_s=120.0), "x.pos") is None


def test_the_velocity_timing_note_does_not_import_numba():
    """`tpos import` runs the filter's lag test without the filter: `fusion.velocity_lag` needs numpy only
    (importing numba through `fusion.insgps` cost 0.2 s of every import; session 9 review)."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys\nimport tpos_cli.importers.velocity_timing\n"
            "assert 'numba' not in sys.modules, 'numba imported'\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         cwd=Path(__file__).resolve().parents[2])
    assert res.returncode == 0, res.stderr[-2000:]
