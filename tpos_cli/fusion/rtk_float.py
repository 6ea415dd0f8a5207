"""RTK float epochs: the fixes whose receiver raised its stated SD, and their error model (issue 11).

An RTK receiver states an SD at its floor while its carrier-phase ambiguities are fixed, and its
error is then white at that floor. In float (or otherwise degraded) epochs it raises its stated SD,
but by far less than its error grows: rtklibexplorer part 1 raises sigma_n to 1.2-2.6x its 0.99 cm
floor while those fixes sit 5-25 cm off, an offset that varies slowly over the stretch, not white
noise. Left out, the filter coasts across each stretch (session 19: worse forward solutions on 2 of 6
RTK sims); taken as white at their stated SD, they pull the run decimetres off and the covariance
matching reads them as white scatter of every fix. Here they stay in, with the error they have:

    fix = truth + b_float + white (stated SD),   b_float a first-order Gauss-Markov offset (NED),

b_float a block of three filter states (`layout.float_offset_block`) that enters H only on the
position rows of float epochs (`measurements.measure`, `FilterConfig.float_intervals_s`). Between
stretches the state decays to its prior (mean 0, the stationary SD), so each stretch starts from the
float class's own uncertainty; the backward run and the smoothers see it as part of the state.
"""

from __future__ import annotations

import numpy as np

from tpos_cli.fusion.layout import N_NAV, Block, StateLayout
from tpos_cli.fusion.measurements import Kind
from tpos_cli.timebase import in_intervals, true_runs

# A fixed RTK solution's horizontal SD moves with the satellite geometry (HDOP) around the receiver's
# floor; a float or degraded epoch raises it. 1.5: beyond that geometry's range (the walk's 536 stated
# SDs stay within 1.14 x their median), a round factor set after seeing the stated-SD lists of the two
# RTK logs (session 19, disclosed; not their errors, not a run's figures).
FLOAT_SD_FACTOR = 1.5
FLOAT_SD_Z = 3.0  # a stretch goes on while its SD stays above median + 3 robust SDs (the textbook outlier fence)
# Only a receiver whose fixes sit at a centimetre floor has fixed and float epochs: code or SBAS fixes state
# decimetres to metres, and a raise there (HDOP in a street canyon) is an honest figure, kept as stated.
RTK_FLOOR_MAX_M = 0.1
# The float offset's stationary SD: the decimetre class of an RTK float solution (centimetres once
# the ambiguities are fixed, decimetres while they float), 0.15 m per horizontal axis (0.21 m
# horizontal RMS) and 0.25 m up (a GNSS solution's vertical is the weaker axis); round figures of the
# class, chosen before any run (not fitted to a log; part 1's float fixes were 5-25 cm off, the sim's
# `sim.rtk` draws 5-25 cm horizontal RMS).
FLOAT_SIGMA_H_M = 0.15
FLOAT_SIGMA_V_M = 0.25
# Its correlation time: a moving receiver's float errors follow multipath and the float ambiguities'
# convergence, which change over seconds; 5 s, the figure `sim.rtk` assumes (`RtkModel.float_tau_s`:
# not measurable on the real log, whose truth is its own fixes). Part 1's and the sim's stretches last
# 0.25-3.75 s: over one stretch the state is close to a constant offset for any tau of seconds or more.
FLOAT_TAU_S = 5.0


def rtk_floor(sigma_h_m) -> bool | None:
    """Whether fixes stating horizontal SDs `sigma_h_m` (m) come from an RTK receiver: the median of the
    stated ones (finite, positive) is a centimetre floor, at most `RTK_FLOOR_MAX_M`; None when none states one."""
    sig = np.asarray(sigma_h_m, dtype=float)
    stated = sig[np.isfinite(sig) & (sig > 0)]
    return bool(np.median(stated) <= RTK_FLOOR_MAX_M) if stated.size else None


def float_fixes(sigma_h_m, factor: float = FLOAT_SD_FACTOR) -> np.ndarray:
    """(M,) bool, the fixes in time order: stretches of fixes whose receiver raised its stated
    horizontal SD (RTK float or degraded epochs). A stretch is a run of consecutive fixes stating
    more than the log's median + `FLOAT_SD_Z` robust SDs (1.4826 MAD; the median itself when most
    fixes sit at the receiver's floor) that holds at least one fix above `factor` x the median
    (hysteresis: the receiver's SD dips within a float stretch, part 1's to 1.2 x its floor between
    2.5 x peaks; geometry alone stays under `factor`). Non-finite or non-positive SDs (not stated)
    end a stretch and are never float; `factor` 0 turns the class off; half the fixes at least must
    state an SD (else there is no floor to be raised from), and their median must be a centimetre
    floor (`rtk_floor`: an RTK receiver's)."""
    sig = np.asarray(sigma_h_m, dtype=float)
    stated = np.isfinite(sig) & (sig > 0)
    out = np.zeros(sig.size, dtype=bool)
    if factor <= 0 or stated.sum() < max(1, 0.5 * sig.size) or not rtk_floor(sig):
        return out
    med = np.median(sig[stated])
    above = stated & (sig > med + FLOAT_SD_Z * 1.4826 * np.median(np.abs(sig[stated] - med)))
    seed = stated & (sig > factor * med)
    for a, b in zip(*true_runs(above)):  # runs [a, b) of fixes above the fence
        if seed[a:b].any():
            out[a:b] = True
    return out


def float_intervals(t_s, is_float) -> np.ndarray:
    """(K, 2) [first, last] time (s) of each run of consecutive float fixes (`is_float` (M,), the
    fixes in time order): times survive the fixes' decimation and windowing, which indices do not."""
    t = np.asarray(t_s, dtype=float)
    start, end = true_runs(is_float)
    return np.column_stack([t[start], t[end - 1]]) if start.size else np.zeros((0, 2))


def float_rows(t_s, kind, intervals_s) -> np.ndarray:
    """(E,) bool: the GPS position rows (t_s session seconds, kind `Kind`) of float epochs, whose
    error holds the float offset state (`measurements.measure`)."""
    return in_intervals(t_s, intervals_s, closed=True) & (np.asarray(kind) == Kind.GPS_POSITION)


def float_velocity_var(layout: StateLayout) -> np.ndarray:
    """(3,) variance (m/s)^2 added to the velocity rows of float epochs (`fusion.insgps.gps_measurements`):
    the float offset's drift over one second (its driving PSD q times 1 s, the fixes' interval in the
    filter), as a float solution's velocity follows its position's offset (RTKLIB's velocity is a state
    of the same float filter; part 1's float epochs' rows sit 10-20 cm/s off, 5-10x its fixed epochs':
    white at the fixed rows' SD they pulled the forward run 30 cm off). Zeros without the block."""
    o = layout.offset(Block.FLOAT)
    if o < 0:
        return np.zeros(3)
    return layout.extra_q()[o - N_NAV:o - N_NAV + 3] * 1.0
