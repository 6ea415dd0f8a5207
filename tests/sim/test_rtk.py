"""RTK-like simulated fixes (issue 11 item 7): stated SDs and error statistics per regime, default path unchanged."""

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from scipy.stats import chi2
from typer.testing import CliRunner

from tpos_cli.cli import app
from tpos_cli.errors import InvalidInputError
from tpos_cli.frames import earth
from tpos_cli.sim import simulate_drive
from tpos_cli.sim.rtk import FIXED, FLOAT, MULTIPATH, RtkModel

FLOOR = np.array(RtkModel().floor_sigma_neu_m)
P = 1e-4  # two-sided level of every statistical check: one false failure in 10^4 runs per check


def _chi2_ok(z) -> bool:
    """Sum of squares of unit-normal z consistent with its chi-square at two-sided level P."""
    z = np.ravel(z)
    return chi2.ppf(P / 2, z.size) < np.sum(z**2) < chi2.ppf(1 - P / 2, z.size)


def _error_neu_m(g) -> np.ndarray:
    lat = np.radians(g.lla_true[:, 0])
    h = g.lla_true[:, 2]
    dn = np.radians(g.lla[:, 0] - g.lla_true[:, 0]) * (earth.meridian_radius_m(lat) + h)
    de = np.radians(g.lla[:, 1] - g.lla_true[:, 1]) * (earth.transverse_radius_m(lat) + h) * np.cos(lat)
    return np.column_stack([dn, de, g.lla[:, 2] - g.lla_true[:, 2]])


@pytest.fixture(scope="module")
def busy():
    """A 4 Hz RTK drive with many float stretches and multipath steps, so that each regime has hundreds of epochs."""
    return simulate_drive(900.0, seed=21, outages=(), gps_rate_hz=4.0, gps_rtk=True, gps_rtk_float_per_min=12.0,
                          gps_rtk_multipath_per_min=8.0)


def test_stated_sd_is_the_floor_except_in_float_stretches_where_it_is_raised_by_the_drawn_factor(busy):
    g, r = busy.gps, busy.gps.rtk
    assert np.all(g.fix == 2) and r.regime.size == g.t_s.size
    assert set(np.unique(r.regime)) == {FIXED, FLOAT, MULTIPATH}
    at_floor = r.regime != FLOAT
    assert np.array_equal(g.sigma_neu_m[at_floor], np.tile(FLOOR, (at_floor.sum(), 1)))
    k = np.searchsorted(r.float_s[:, 0], g.t_s, side="right") - 1  # the stretch that started last
    fl = r.regime == FLOAT
    assert np.all((g.t_s[fl] >= r.float_s[k[fl], 0]) & (g.t_s[fl] < r.float_s[k[fl], 1]))
    assert_allclose(g.sigma_neu_m[fl], FLOOR * r.float_sd_factor[k[fl], None], rtol=1e-15)
    assert np.all((r.float_sd_factor >= 1.2) & (r.float_sd_factor <= 2.6))


def test_white_noise_is_at_the_floor_in_every_regime(busy):
    e = _error_neu_m(busy.gps) - busy.gps.rtk.offset_neu_m
    for regime in (FIXED, FLOAT, MULTIPATH):
        assert _chi2_ok(e[busy.gps.rtk.regime == regime] / FLOOR), regime
    assert np.all(busy.gps.rtk.offset_neu_m[busy.gps.rtk.regime == FIXED] == 0.0)


def test_float_offset_is_gauss_markov_with_the_drawn_sd_and_time_constant(busy):
    """Whitened by the stretch's own SD and a = exp(-dt / tau), the offsets are unit white noise."""
    g, r = busy.gps, busy.gps.rtk
    a = np.exp(-0.25 / RtkModel().float_tau_s)
    z = []
    for (start, end), sd in zip(r.float_s, r.float_offset_sd_neu_m, strict=True):
        b = r.offset_neu_m[(g.t_s >= start) & (g.t_s < end)] / sd
        if len(b):
            z.append(b[:1])  # stationary start
            z.append((b[1:] - a * b[:-1]) / np.sqrt(1.0 - a * a))
    z = np.concatenate(z)
    assert len(z) > 300
    assert _chi2_ok(z)
    assert np.all(np.abs(z.mean(axis=0)) < 3.9 / np.sqrt(len(z)))  # 3.9 SD: two-sided 1e-4
    h_rms = np.sqrt(2.0) * r.float_offset_sd_neu_m[:, 0]
    assert np.all((h_rms >= 0.05) & (h_rms <= 0.25))
    assert_allclose(r.float_offset_sd_neu_m[:, 2] / r.float_offset_sd_neu_m[:, 0], FLOOR[2] / FLOOR[0])


def test_multipath_step_is_a_constant_offset_the_stated_sd_does_not_show(busy):
    g, r = busy.gps, busy.gps.rtk
    mp = r.regime == MULTIPATH
    j = np.searchsorted(r.multipath_s[:, 0], g.t_s[mp], side="right") - 1
    assert np.all(g.t_s[mp] < r.multipath_s[j, 1])
    assert np.array_equal(r.offset_neu_m[mp], r.multipath_offset_neu_m[j])
    size = np.hypot(r.multipath_offset_neu_m[:, 0], r.multipath_offset_neu_m[:, 1])
    assert np.all((size >= 0.03) & (size <= 0.10))


@pytest.mark.parametrize("which", ["float", "multipath"])
def test_stretch_count_and_lengths_match_the_rate_and_length_range(busy, which):
    """Renewal process: cycle = exponential gap (mean m = 60 / rate) + uniform length in (lo, hi); the count in
    T is about T / E[cycle] with variance T var(cycle) / E[cycle]^3."""
    rate, (lo, hi), s = ((12.0, RtkModel().float_duration_s, busy.gps.rtk.float_s) if which == "float"
                         else (8.0, RtkModel().multipath_duration_s, busy.gps.rtk.multipath_s))
    m = 60.0 / rate
    mean_c, var_c = m + 0.5 * (lo + hi), m * m + (hi - lo) ** 2 / 12.0
    T = 900.0 + 0.25
    assert abs(len(s) - T / mean_c) < 3.9 * np.sqrt(T * var_c / mean_c**3)
    length = s[:, 1] - s[:, 0]
    assert np.all((length >= lo) & (length <= hi))
    assert abs(length.mean() - 0.5 * (lo + hi)) < 3.9 * (hi - lo) / np.sqrt(12.0 * len(s))
    gaps = s[1:, 0] - s[:-1, 1]
    assert np.all(gaps > 0)  # stretches of one kind never overlap


def test_default_path_draws_as_before_and_rtk_draws_after_every_other():
    """Without --gps-rtk the fixes are the seed's first draws (white N/E/U at 1.5/1.5/2.5 m, then velocity, then
    nsat), as before the RTK mode; with it the IMU, velocities and nsat are the same arrays and the position's
    white part is the same draws scaled to the floor."""
    off = simulate_drive(120.0, seed=4)
    on = simulate_drive(120.0, seed=4, gps_rtk=True)
    gps_rng = np.random.default_rng(np.random.SeedSequence(4).spawn(2)[1])
    n = 121  # all 1 Hz epochs, before the outage rows go
    w_pos, w_vel = gps_rng.standard_normal((n, 3)), gps_rng.standard_normal((n, 3))
    keep = (np.arange(n) < 40) | (np.arange(n) >= 70)
    assert np.array_equal(off.gps.vel_ned_mps, off.gps.vel_true_ned_mps + w_vel[keep] * 0.05)
    assert np.array_equal(off.gps.nsat, gps_rng.integers(7, 13, size=n)[keep])
    assert_allclose(_error_neu_m(off.gps), w_pos[keep] * [1.5, 1.5, 2.5], atol=1e-8)  # lat/lon rounding
    assert np.array_equal(off.gps.sigma_neu_m, np.tile([1.5, 1.5, 2.5], (keep.sum(), 1))) and off.gps.rtk is None
    assert "gps_rtk" not in off.params and off.params["gps_sigma_h_m"] == 1.5
    assert np.array_equal(on.imu.gyro_b_rps, off.imu.gyro_b_rps) and np.array_equal(on.truth.lla, off.truth.lla)
    assert np.array_equal(on.gps.vel_ned_mps, off.gps.vel_ned_mps) and np.array_equal(on.gps.nsat, off.gps.nsat)
    assert_allclose(_error_neu_m(on.gps) - on.gps.rtk.offset_neu_m, w_pos[keep] * FLOOR, atol=1e-8)


def test_rtk_model_refuses_figures_that_are_no_receiver():
    for bad in ({"floor_sigma_neu_m": (0.0, 0.01, 0.01)}, {"float_per_min": -1.0}, {"float_sd_factor": (0.5, 2.0)},
                {"float_offset_m": (0.3, 0.1)}, {"float_tau_s": 0.0}, {"multipath_duration_s": (0.0, 0.0)}):
        with pytest.raises(InvalidInputError):
            RtkModel(**bad)


def test_cli_gps_rtk_writes_the_stated_sds_and_keeps_fix_2(tmp_path):
    out = tmp_path / "rtk"
    res = CliRunner().invoke(app, ["simulate", "drive", str(out), "--gps-rtk", "--duration", "300", "--seed", "3",
                                   "--format", "csv", "-q"])
    assert res.exit_code == 0, res.output
    gps = pd.read_csv(out / "gps.csv")
    sim = simulate_drive(300.0, seed=3, gps_rtk=True)
    assert_allclose(gps[["sigma_n", "sigma_e", "sigma_u"]].to_numpy(), sim.gps.sigma_neu_m, rtol=1e-15)
    assert (gps["fix"] == 2).all() and gps["sigma_n"].min() == FLOOR[0]
    assert "# gps_rtk = " in (out / "session.toml").read_text()
    truth = pd.read_csv(out / "truth.csv")
    assert_allclose(truth[["lat", "lon", "h"]].to_numpy(), sim.truth.lla, rtol=0, atol=0)  # the truth is unchanged
    for args in (["drive", str(tmp_path / "a"), "--gps-rtk", "--gps-sigma-h", "1"], ["target", str(tmp_path / "b"), "--gps-rtk"]):
        assert CliRunner().invoke(app, ["simulate", *args, "-q"]).exit_code == 2
