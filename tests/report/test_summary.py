"""Page 1 (`report.summary`) and the verdict's checks (`report.tables.verdict_checks_section`) say
what the run's verdict says: the same figures, every reason in full somewhere in the PDF."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from tests.report import synth
from tpos_cli.report.build import build_context, headline
from tpos_cli.report.summary import _verdict_box, headline_rows
from tpos_cli.report.tables import reason_lines, verdict_checks_section


def _with_quality(run, quality: dict, results: dict | None = None):
    s = json.loads((run / "summary.json").read_text())
    s["quality"] = quality
    if results is not None:
        s["results"] = results
    (run / "summary.json").write_text(json.dumps(s))
    return run


def _drive_run(tmp_path, quality: dict, results: dict | None = None):
    s = synth.write_session(tmp_path / "s", movement=True)
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)
    traj = synth.trajectory_rows("smoothed", t10, [0.3, 0.4, 0.0], sigma=(0.5, 0.5, 0.5))
    return _with_quality(synth.write_run(tmp_path / "r", s, traj), quality, results)


FLAGS = {"epochs": 2901, "flagged": 353, "fraction": 0.1217, "expected": 0.001, "level": "suspect"}


def test_forward_backward_row_quotes_the_verdicts_flag_fraction(tmp_path):
    # rtklibexplorer part 1 (session 7 audit): page 1 said "0.1 % of epochs apart by more than their
    # 99 % bound" (horizontal only) beside a reason "disagree beyond their covariances at 12 % of
    # epochs" (the whole state): page 1 now gives the verdict's own figure from summary.json
    r = _drive_run(tmp_path, {"verdict": "suspect", "reasons": ["flags"], "checks": {"flags": FLAGS}})
    rows = dict(headline_rows(build_context(r)))
    assert rows["Forward/backward agreement"].startswith("12.2 % of epochs flagged")
    assert "0.1 % expected)" in rows["Forward/backward agreement"]


def test_without_the_flags_check_there_is_no_flag_row(tmp_path):
    r = _drive_run(tmp_path, {"verdict": "ok", "reasons": [], "checks": {}})
    assert not any("flagged" in v for _, v in headline_rows(build_context(r)))


def _box_lines(fig):
    """The verdict box's lines, top to bottom (the texts right of the verdict badge)."""
    texts = sorted((t for t in fig.texts if abs(t.get_position()[0] - 0.285) < 1e-9), key=lambda t: -t.get_position()[1])
    return [t.get_text() for t in texts]


def test_verdict_reasons_sit_on_a_fixed_line_pitch(tmp_path):
    # session 26: on the rtklibexplorer drive's page 1 the third line of a reason (after "[time]" and "±" in the
    # line above) sat on the next reason: one multi-line text spaced the lines by their glyphs
    reasons = ["gps/imu: the GPS positions are time-stamped 0.115 ± 0.006 s early against the IMU (estimated by the filter, "
               "whose output is on the GPS clock), their velocities 0.013 ± 0.006 s late: one [time] gps_offset_s cannot "
               "put both right", "forward and backward runs disagree"]
    fig = Figure()
    _verdict_box(fig, build_context(_drive_run(tmp_path, {"verdict": "suspect", "reasons": reasons, "checks": {}})), 0.95)
    ys = sorted((t.get_position()[1] for t in fig.texts if abs(t.get_position()[0] - 0.285) < 1e-9), reverse=True)
    assert len(ys) == 4 and all(t.get_va() == "baseline" for t in fig.texts if abs(t.get_position()[0] - 0.285) < 1e-9)
    np.testing.assert_allclose(-np.diff(ys), -np.diff(ys)[0], rtol=1e-12)  # every line one pitch below the last


def test_every_reason_is_in_full_in_the_verdict_checks_when_page_1_cuts_them(tmp_path):
    words = "the filter's sigmas are too small for this log so positions may be off by more than their sigmas"
    reasons = [f"reason {i}: {words}; {words}" for i in range(4)]  # ~200 characters each, 2 lines each on page 1
    q = {"verdict": "suspect", "reasons": reasons, "checks": {"flags": FLAGS}}
    ctx = build_context(_drive_run(tmp_path, q))
    fig = Figure()
    _verdict_box(fig, ctx, 0.95)
    box = "\n".join(_box_lines(fig))
    assert box.startswith("- reason 0")
    assert "reason 3" not in box  # page 1 has room for six lines: reasons 3 and 4 do not fit
    assert box.splitlines()[-1].strip().startswith("... (2 more reasons and every reason in full")
    sec = verdict_checks_section(ctx, only_failed=True)
    assert sec is not None
    text = " ".join(ln.strip() for ln in reason_lines(reasons))
    for r in reasons:
        assert f"- {r}" in text  # each reason whole, in order, no word lost to wrapping


def test_reasons_without_a_failed_check_still_get_the_section(tmp_path):
    q = {"verdict": "suspect", "reasons": ["a reason from a check that recorded no level"], "checks": {"x": {"n": 3}}}
    sec = verdict_checks_section(build_context(_drive_run(tmp_path, q)), only_failed=True)
    assert sec is not None and "reasons in full" in sec.subtitle


def test_magnetometer_row_quotes_the_filters_rejections(tmp_path):
    # BROAD trial 28 (session 7 audit): page 1 said "disturbed for 8 s" (its own |B| band) beside a
    # verdict "rejected 59 % of its samples": page 1 now gives the filter's figure too
    s = synth.write_session(tmp_path / "s", kind="target", truth=False)
    traj = synth.trajectory_rows("fkf", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.0, 0.0, 0.0], sigma=(0.5, 0.5, 0.5))
    rej = {"rejected": 30790, "samples": 52628, "fraction": 0.585, "level": "suspect"}
    r = _with_quality(synth.write_run(tmp_path / "r", s, traj), {"verdict": "suspect", "reasons": ["m"],
                                                                 "checks": {"magnetometer.rejected": rej}})
    rows = dict(headline_rows(build_context(r)))
    assert rows["Magnetometer in the filter"].startswith("58.5 % of its samples rejected")


def test_output_on_the_gps_clock_is_said_when_scored_against_truth(tmp_path):
    # comma2k19 (session 7 audit): the default run moves its output to the GPS clock (d = -0.109 s),
    # truth.* is on the logger's: horizontal RMS 1.48 m against 0.55 m with the output left on the
    # logger's clock, and nothing on the report said why. The synthetic run moves at 1 m/s north.
    clk = {"estimate_s": -0.2, "sigma_s": 0.01, "velocity_estimate_s": -0.2, "velocity_sigma_s": 0.01, "output_clock": "gps"}
    ctx = build_context(_drive_run(tmp_path, {"verdict": "ok", "reasons": [], "checks": {}}, {"gps_clock_offset": clk}))
    (note,) = [n for n in ctx.notes if "GPS receiver's clock" in n]
    assert "-0.200 s" in note and "1.0 m/s, 0.20 m along the track" in note and "clock_apply_sd=1e9" in note
    assert dict(headline_rows(ctx))["Clocks"].startswith("output on the GPS clock (-0.200 s)")


def test_output_on_the_logger_clock_gets_no_clock_note(tmp_path):
    clk = {"estimate_s": -0.002, "sigma_s": 0.01, "velocity_estimate_s": 0.0, "velocity_sigma_s": 0.01, "output_clock": "imu"}
    ctx = build_context(_drive_run(tmp_path, {"verdict": "ok", "reasons": [], "checks": {}}, {"gps_clock_offset": clk}))
    assert not any("clock" in n for n in ctx.notes) and "Clocks" not in dict(headline_rows(ctx))


def test_gps_row_says_which_outages_the_user_withheld(tmp_path):
    # part 1 with two --mask-gps windows (session 7 audit): page 1 said "2 outages, longest 30 s", as if the
    # receiver had lost them
    s = synth.write_session(tmp_path / "s", movement=True, gps=True)
    traj = synth.trajectory_rows("smoothed", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.3, 0.4, 0.0], sigma=(0.5, 0.5, 0.5))
    r = synth.write_run(tmp_path / "r", s, traj, gps_outages=[[1002.0, 1004.0], [1010.0, 1013.0]], mask_gps=[[1010.0, 1013.0]])
    rows = dict(headline_rows(build_context(r)))
    assert "2 outages, longest 3 s" in rows["GPS"] and rows["Withheld with --mask-gps"] == "1 of the 2 outages above"
    r2 = synth.write_run(tmp_path / "r2", s, traj, gps_outages=[[1002.0, 1004.0]])
    assert "Withheld with --mask-gps" not in dict(headline_rows(build_context(r2)))


def test_page_1_rows_keep_the_tables_font(tmp_path):
    # the table shrinks its font to fit its longest value (layout.draw_table): the rows added in
    # session 7 (flags, clocks, masks, magnetometer) must not make page 1 smaller to read
    from tpos_cli.report import layout as L

    clk = {"estimate_s": -0.1087, "sigma_s": 0.01, "velocity_estimate_s": -0.2, "velocity_sigma_s": 0.01, "output_clock": "gps"}
    q = {"verdict": "suspect", "reasons": ["r"], "checks": {"flags": FLAGS, "magnetometer.rejected": {"fraction": 0.585}}}
    s = synth.write_session(tmp_path / "s", movement=True, gps=True, gps_error_ned_m=(0.4, -0.3, 0.5))  # truth independent
    traj = synth.trajectory_rows("smoothed", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.3, 0.4, 0.0], sigma=(0.5, 0.5, 0.5))
    r = _with_quality(synth.write_run(tmp_path / "r", s, traj, gps_outages=[[1010.0, 1013.0]], mask_gps=[[1010.0, 1013.0]]),
                      q, {"gps_clock_offset": clk, "gps_fixes": 5})
    qc = synth.write_session(tmp_path / "qc", movement=True, gps=True, truth=False)  # no truth: agreement with the fixes
    tgt = synth.write_session(tmp_path / "tgt", kind="target", truth=False)
    runs = {
        "drive": r,
        "qc": synth.write_run(tmp_path / "r_qc", qc, traj),
        "target": _with_quality(synth.write_run(tmp_path / "r_tgt", tgt, traj.assign(solution="fkf")), q),
    }
    for name, run in runs.items():
        rows = headline_rows(build_context(run))
        fig = Figure(figsize=L.A4_IN)
        cols = [L.Column("", [k for k, _ in rows], align="left"), L.Column("", [v for _, v in rows], align="left")]
        L.draw_table(fig, 0.9, cols, fontsize=7.8, header=False)
        assert {t.get_fontsize() for t in fig.texts} == {7.8}, (name, [v for _, v in rows if len(v) > 60])
    keys = {k for k, _ in headline_rows(build_context(r))}
    assert {"Forward/backward agreement", "Withheld with --mask-gps", "Clocks"} <= keys


def test_page_1_says_when_the_fixes_had_no_sds(tmp_path):
    # session 8: fixes without SDs carry the stated accuracy (1.5 m h, 2.5 m v) into the estimates; comma2k19's
    # page 1 showed "Estimated 95 %, horizontal: median 3.82 m" beside a 1.48 m RMS error and a smooth track,
    # and only page 5's warnings said why
    from tpos_cli.report import layout as L

    considered = {"sigma_h_m": 1.4951, "sigma_v_m": 2.4893, "white_h_m": 0.122, "white_v_m": 0.231}
    q = {"verdict": "suspect", "reasons": ["r"], "checks": {"flags": FLAGS}}
    s = synth.write_session(tmp_path / "s", movement=True, gps=True)
    traj = synth.trajectory_rows("smoothed", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.3, 0.4, 0.0], sigma=(0.5, 0.5, 0.5))
    r = _with_quality(synth.write_run(tmp_path / "r", s, traj), q, {"alignment": {"gps_considered_error": considered}})
    rows = headline_rows(build_context(r))
    assert dict(rows)["GPS SDs"] == "none in the log: stated 1.50 m h, 2.50 m v used (fix scatter 0.12 m)"
    fig = Figure(figsize=L.A4_IN)
    L.draw_table(fig, 0.9, [L.Column("", [k for k, _ in rows], align="left"), L.Column("", [v for _, v in rows], align="left")],
                 fontsize=7.8, header=False)
    assert {t.get_fontsize() for t in fig.texts} == {7.8}
    r2 = _with_quality(synth.write_run(tmp_path / "r2", s, traj), q, {"alignment": {}})
    assert "GPS SDs" not in dict(headline_rows(build_context(r2)))


def test_page_1_states_the_accuracy_the_chain_used_with_gauss_markov_states(tmp_path):
    # review (session 8): page 1 rebuilt the stated accuracy as hypot(considered, white), while the drive chain took
    # considered^2 = max(stated^2 - white^2 - gm^2, 0): with gps_error_model = "gauss_markov" on a log without SDs
    # it said 1.30 m where 1.50 m was used
    q = {"verdict": "ok", "reasons": [], "checks": {"flags": FLAGS}}
    s = synth.write_session(tmp_path / "s", movement=True, gps=True)
    traj = synth.trajectory_rows("smoothed", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.3, 0.4, 0.0], sigma=(0.5, 0.5, 0.5))
    white, gm = (0.12, 0.23), (0.75, 1.2)
    considered = {"sigma_h_m": float(np.sqrt(1.5 ** 2 - white[0] ** 2 - gm[0] ** 2)), "white_h_m": white[0],
                  "sigma_v_m": float(np.sqrt(2.5 ** 2 - white[1] ** 2 - gm[1] ** 2)), "white_v_m": white[1]}
    states = {"method": "set by the pipeline", "tau_s": 300.0, "sigma_h_m": gm[0], "sigma_v_m": gm[1]}
    r = _with_quality(synth.write_run(tmp_path / "r", s, traj), q,
                      {"alignment": {"gps_considered_error": considered, "gps_error_states": states}})
    rows = headline_rows(build_context(r))
    assert dict(rows)["GPS SDs"] == "none in the log: stated 1.50 m h, 2.50 m v used (scatter 0.12 m, GM 0.75 m)"
    from tpos_cli.report import layout as L

    fig = Figure(figsize=L.A4_IN)  # the longer row still fits page 1's table at its font
    L.draw_table(fig, 0.9, [L.Column("", [k for k, _ in rows], align="left"), L.Column("", [v for _, v in rows], align="left")],
                 fontsize=7.8, header=False)
    assert {t.get_fontsize() for t in fig.texts} == {7.8}
    # the chain's own stated figures win (an axis whose considered part was clipped to 0 cannot be rebuilt)
    clipped = dict(considered, sigma_h_m=0.0, stated_h_m=0.5, stated_v_m=2.5)
    r2 = _with_quality(synth.write_run(tmp_path / "r2", s, traj), q,
                       {"alignment": {"gps_considered_error": clipped, "gps_error_states": states}})
    assert dict(headline_rows(build_context(r2)))["GPS SDs"] == (
        "none in the log: stated 0.50 m h, 2.50 m v used (scatter 0.12 m, GM 0.75 m)")


def test_a_truth_that_is_the_fixes_the_run_used_is_no_truth_there(tmp_path):
    # rtklibexplorer's drives and walk publish the receiver's own RTK solution as truth.csv: the same rows
    # as gps.csv. Page 1 said "Inside the stated 95 % bound: horizontal 13 %" on the walk: the run's
    # residual to a fix it used (variance R - P), read as its error (variance P)
    s = synth.write_session(tmp_path / "s", movement=True, gps=True)  # truth rows = the fixes
    traj = synth.trajectory_rows("smoothed", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.3, 0.4, 0.0], sigma=(0.05, 0.05, 0.05))
    ctx = build_context(synth.write_run(tmp_path / "r", s, traj))
    rows = dict(headline_rows(ctx))
    assert not ctx.has_truth and "Against the GPS fixes used" in rows and "Inside the stated 95 % bound" not in rows
    assert "are the GPS fixes the run used" in ctx.truth.trajectory.description
    # audit (session 25): with every row a fix the run used, it said "only the 0 others are independent truth"
    assert "none is independent truth; withhold fixes with `tpos process --mask-gps" in ctx.truth.trajectory.description
    # ... and the headline (accuracy.json, the console, `tpos batch`'s "pos m") gave the residuals to those fixes
    # as errors against truth (the RTK walk: 0.0537 m); page 1 gives none
    assert headline(ctx.acc) == []
    # fixes withheld with --mask-gps: the truth rows there are independent, the others not
    fixes = pd.read_csv(s / "gps.csv")
    withheld = fixes[(fixes["t"] >= 1010.0) & (fixes["t"] <= 1013.0)]
    ctx = build_context(synth.write_run(tmp_path / "r2", s, traj, mask_gps=[[1010.0, 1013.0]], withheld=withheld))
    tt = ctx.truth.trajectory
    np.testing.assert_array_equal(tt.independent, (tt.t >= 1010.0) & (tt.t <= 1013.0))
    se = ctx.errors("smoothed")
    assert np.isfinite(se.err_ned_m[:, 0]).sum() == ((se.t > 1010.0) & (se.t < 1013.0)).sum() + 2  # both ends: truth rows
    assert "Error against truth the run did not use" in dict(headline_rows(ctx))
    # the headline over the withheld epochs only, as page 1 (the RTK drive masked: 0.095 m over all, 0.20 m withheld)
    (h,) = headline(ctx.acc)
    assert h["n"] == np.isfinite(se.err_ned_m[:, 0]).sum()
    np.testing.assert_allclose(h["rms_pos_h_m"], np.sqrt(np.nanmean(se.err_ned_m[:, 0] ** 2 + se.err_ned_m[:, 1] ** 2)), rtol=1e-9)
    # a receiver's fixes a few decimetres off the truth: the truth is independent everywhere
    s3 = synth.write_session(tmp_path / "s3", movement=True, gps=True, gps_error_ned_m=(0.4, -0.3, 0.5))
    ctx = build_context(synth.write_run(tmp_path / "r3", s3, traj))
    assert ctx.has_truth and ctx.truth.trajectory.independent.all()


def test_page_1_attitude_error_leads_with_the_total_angle(tmp_path):
    # near pitch +-90 deg the Euler roll and yaw errors are large and cancel (BROAD 02: roll 1.14, yaw 1.19, total
    # angle 0.52 deg): the row gives the total angle page 1 plots first, the Euler angles after it
    s = synth.write_session(tmp_path / "s", movement=True)
    traj = synth.trajectory_rows("smoothed", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.3, 0.4, 0.0], rpy_err_deg=(0.5, -0.3, 2.0),
                                 sigma=(0.5, 0.5, 0.5))
    rows = dict(headline_rows(build_context(synth.write_run(tmp_path / "r", s, traj))))
    value = rows["Attitude error (smoothed)"]
    # the three Euler errors compose to about their root sum of squares at the synthetic track's small angles
    total = float(value.split("RMS total angle ")[1].split(" deg")[0])
    assert abs(total - np.sqrt(0.5**2 + 0.3**2 + 2.0**2)) < 0.02, value
    assert value.endswith("(roll 0.500, pitch 0.300, yaw 2.000)"), value


def test_attitude_page_1_draws_the_total_angle_bound_not_the_euler_yaw_sd(tmp_path):
    # audit (session 25): BROAD 02's page 1 drew "stated 95 % heading bound" from sigma_yaw, an Euler SD of 204 deg
    # near pitch -90 deg beside a total attitude error of ~0.5 deg; the run's att95_deg bounds the angle page 1 plots
    from tpos_cli.report.summary import _attitude_strip

    s = synth.write_session(tmp_path / "s", kind="target", truth=False)
    traj = synth.trajectory_rows("fkf", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.0, 0.0, 0.0], sigma=(0.5, 0.5, 0.5))
    traj["sigma_yaw"] = np.where(np.arange(len(traj)) == 100, 204.0, 0.7)
    traj["att95_deg"] = 1.9
    ctx = build_context(synth.write_run(tmp_path / "r", s, traj))
    fig = Figure()
    _attitude_strip(fig, ctx, 0.9, 0.5)
    (line,) = [ln for ln in fig.axes[0].get_lines() if ln.get_linestyle() == "--"]
    assert "total angle" in line.get_label() and "heading" not in line.get_label()
    np.testing.assert_allclose(line.get_ydata(), 1.9)


def test_the_total_angle_panel_gets_the_total_angle_bound(tmp_path):
    # session 26: the attitude page's total-angle panel had no band (the Euler SDs bound no total angle); its band
    # is the run's att95_deg, from 0 (an angle is not negative)
    from matplotlib.collections import PolyCollection

    from tpos_cli.report.timeplots import attitude_section

    s = synth.write_session(tmp_path / "s", movement=True)
    traj = synth.trajectory_rows("smoothed", np.arange(0.0, 20.0 + 1e-9, 0.1), [0.3, 0.4, 0.0], rpy_err_deg=(0.5, -0.3, 2.0),
                                 sigma=(0.5, 0.5, 0.5))
    traj["sigma_roll"], traj["sigma_pitch"], traj["sigma_yaw"], traj["att95_deg"] = 0.4, 0.4, 0.9, 2.5
    sec = attitude_section(build_context(synth.write_run(tmp_path / "r", s, traj)))
    fig = Figure()
    sec.draw(fig, 0.9, 0.1)
    (band,) = [c for c in fig.axes[3].collections if isinstance(c, PolyCollection)]
    y = np.concatenate([p.vertices[:, 1] for p in band.get_paths()])
    assert y.min() == 0.0 and y.max() == pytest.approx(2.5)
