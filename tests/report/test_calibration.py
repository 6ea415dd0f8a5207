"""The drive report's "Estimated from the log" table (`report.tables._calibration_rows`)."""

from tpos_cli.report.tables import _calibration_rows


def test_rows_from_a_drive_summary():
    """Every calibration a drive run holds gets a row with its 1-sigma; what the run lacks is left out;
    no "-0.00"."""
    results = {
        "constraints": {
            "mounting": {"mounting_rpy_deg": [-0.001, 1.96, -3.97], "sigma_py_deg": [0.02, 0.03], "source": "travel direction"},
            "forward": {"residual_misalignment_deg": {"pitch_yaw": [0.01, -0.02], "sigma": [0.05, 0.06]},
                        "odometer_scale_error": {"estimate": 0.0198, "sigma": 0.0005}},
        },
        "lever_arm": {"estimated": True, "stated_m": [0.0, 0.0, 0.0], "estimate_m": [0.83, 0.5, 0.0],
                      "sigma_forward_right_m": [0.03, 0.02], "decided_by": "auto"},
        "gps_clock_offset": {"estimate_s": 0.0802, "sigma_s": 0.006, "velocity_estimate_s": 0.079, "velocity_sigma_s": 0.004,
                             "output_clock": "gps"},
    }
    rows = {r[0]: r for r in _calibration_rows(results)}
    assert rows["IMU on the vehicle, roll/pitch/yaw (deg)"][1] == "0.00 / 1.96 / -3.97"
    assert rows["GPS lever arm, IMU axes (m)"][1:3] == ("0.830 / 0.500 / 0.000", "0.030 / 0.020 (fwd/right)")
    assert rows["IMU-GPS clock offset, positions (s)"][1:3] == ("+0.0802", "0.0060")
    assert rows["odometer scale error"][1:3] == ("+0.01980", "0.00050")
    assert len(rows) == 6
    assert _calibration_rows({}) == []
    stated = _calibration_rows({"lever_arm": {"estimated": False, "stated_m": [0.0, -0.05, 0.0], "decided_by": "auto: no"}})
    assert stated[0][1] == "0 / -0.05 / 0" and "not estimated" in stated[0][3]
