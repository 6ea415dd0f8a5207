"""RTK float epochs: the class from the receiver's own stated SDs, and the rows that see the float offset state."""

import numpy as np

from tpos_cli.fusion.layout import float_offset_block
from tpos_cli.fusion.measurements import Kind
from tpos_cli.fusion.rtk_float import float_fixes, float_intervals, float_rows
from tpos_cli.timebase import in_intervals


def _floor_sds(n=400, seed=0):
    """An RTK receiver's stated horizontal SDs at its 1 cm floor, moving +-10 % with the geometry."""
    t = np.arange(n) * 0.25
    return t, 0.01 * (1.0 + 0.1 * np.sin(2.0 * np.pi * t / 60.0)) * (1.0 + 0.01 * np.random.default_rng(seed).random(n))


def test_a_raised_stretch_is_float_and_geometry_is_not():
    t, sig = _floor_sds()
    assert not float_fixes(sig).any()  # the geometry's +-10 % never reaches 1.5 x the median
    sig[100:115] *= np.r_[1.3, 2.0, 2.5, 1.25, 2.2, 1.3, np.full(9, 1.8)]  # part 1's shape: dips to 1.2-1.3 x inside
    fl = float_fixes(sig)
    assert np.flatnonzero(fl).tolist() == list(range(100, 115))  # the dips stay in (hysteresis), nothing else
    assert float_intervals(t, fl).tolist() == [[t[100], t[114]]]


def test_no_class_without_an_rtk_floor_or_with_the_factor_off():
    t, sig = _floor_sds()
    sig[100:110] *= 2.5
    assert not float_fixes(sig, 0.0).any()  # 0: off
    assert not float_fixes(sig * 50.0).any()  # a 0.5 m code receiver: a raise is its honest figure
    half = sig.copy()
    half[::2] = np.nan  # not stated: at most half the fixes state an SD -> no floor
    half[1] = np.nan
    assert not float_fixes(half).any()


def test_only_the_position_rows_inside_a_stretch_see_the_offset():
    iv = np.array([[10.0, 12.0], [50.0, 50.0]])
    t = np.array([9.9, 10.0, 11.0, 12.0, 12.1, 50.0, 11.0])
    kind = np.array([Kind.GPS_POSITION] * 6 + [Kind.GPS_VELOCITY])
    assert in_intervals(t, iv, closed=True).tolist() == [False, True, True, True, False, True, True]
    assert in_intervals(t, iv).tolist() == [False, True, True, False, False, False, True]  # half-open: ends out
    assert float_rows(t, kind, iv).tolist() == [False, True, True, True, False, True, False]
    assert not float_rows(t, kind, None).any()


def test_float_offset_block_is_stationary_gauss_markov():
    b = float_offset_block(0.15, 0.25, 5.0)
    assert np.allclose(np.diag(b.P0), [0.0225, 0.0225, 0.0625])
    # the driving PSD keeps the prior's variance stationary: d/dt P = -2 P / tau + q = 0
    assert np.allclose(-2.0 * np.diag(b.P0) / b.tau_s + b.q, 0.0)


def test_float_epochs_velocity_rows_carry_the_offsets_drift():
    """A float solution's velocity follows its position's offset: the velocity rows of float fixes carry the
    offset's drift over 1 s (q x 1 s, 2 sigma^2 / tau: 9.5 cm/s per horizontal axis at 0.15 m, 5 s) on top of
    their own SD; the position rows and the fixed epochs' rows keep theirs (`insgps.gps_measurements`)."""
    from tpos_cli.fusion.insgps import GpsFixes, gps_measurements
    from tpos_cli.fusion.layout import StateLayout
    from tpos_cli.fusion.rtk_float import float_velocity_var

    lay = StateLayout((float_offset_block(0.15, 0.25, 5.0),))
    var = float_velocity_var(lay)
    assert np.allclose(var, 2.0 * np.array([0.15, 0.15, 0.25]) ** 2 / 5.0)
    assert not float_velocity_var(StateLayout()).any()
    t = np.arange(6.0)
    fixes = GpsFixes(t, np.column_stack([np.full(6, 48.0), np.full(6, 11.0), np.full(6, 500.0)]), np.zeros((6, 3)),
                     np.full((6, 3), 0.01), np.full((6, 3), 0.02))
    m = gps_measurements(fixes, np.linspace(-1.0, 7.0, 801), backward=False, gap_s=0.0,
                         float_intervals_s=np.array([[2.0, 3.0]]), float_vel_var=var)
    vel = m.kind == Kind.GPS_VELOCITY
    fl = (m.t_s >= 2.0) & (m.t_s <= 3.0)
    assert np.allclose(np.diagonal(m.R[vel & fl], axis1=1, axis2=2), 0.02**2 + var)
    assert np.allclose(np.diagonal(m.R[vel & ~fl], axis1=1, axis2=2), 0.02**2)
    assert np.allclose(np.diagonal(m.R[~vel], axis1=1, axis2=2), 0.01**2)
