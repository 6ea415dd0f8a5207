"""Ellipsoid fit recovers simulated hard and soft iron; the correction formula is the loader's."""

import numpy as np
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from tpos_cli.magcal import apply_mag_calibration, fit_ellipsoid


def test_ellipsoid_fit_recovers_iron():
    rng = np.random.default_rng(0)
    F = 50.0
    h_n = np.array([20.0, 1.0, 45.8])
    h_n *= F / np.linalg.norm(h_n)
    R = Rotation.random(2000, random_state=1).as_matrix()
    h_s = np.einsum("nji,j->ni", R, h_n)  # field in the sensor axes for each attitude
    A = np.array([[1.1, 0.05, -0.02], [0.05, 0.92, 0.03], [-0.02, 0.03, 1.04]])  # symmetric soft iron
    b = np.array([12.0, -7.0, 30.0])
    m = h_s @ A.T + b + rng.standard_normal((2000, 3)) * 0.3
    cal = fit_ellipsoid(m, F)
    assert_allclose(cal.hard_iron_ut, b, atol=0.1)  # 0.3 µT noise over 2000 samples: ~0.02 µT SD
    assert_allclose(cal.soft_iron @ A, np.eye(3), atol=5e-3)
    assert abs(cal.residual_sd_ut - 0.3) < 0.05  # only the white noise is left
    out = apply_mag_calibration(m, cal.hard_iron_ut, cal.soft_iron)
    assert_allclose(out, (m - cal.hard_iron_ut) @ cal.soft_iron.T)  # m_cal = S (m - b)


def test_calibrated_copy_keeps_the_session_toml_as_written(tmp_path):
    """Issue 18: a quoted key and a TOML datetime survive the copy (they were rewritten unquoted or
    crashed after the copy); the source is untouched and the new keys are there."""
    import tomllib

    from tpos_cli.magcal import MagCalibration, write_calibrated_copy

    src = tmp_path / "s"
    src.mkdir()
    text = ('[session]\nname = "s"\nkind = "target"\nstart_utc = 2015-06-11T14:02:00Z\n"operator name" = "Zoë"\n\n'
            '[imu]\naxes = "FRD"\nrate_hz = 100.0\n')
    (src / "session.toml").write_text(text, encoding="utf-8")
    (src / "imu.csv").write_text("t,gyro_x\n0,0\n")
    cal = MagCalibration(np.array([1.0, 2.0, 3.0]), np.eye(3), 50.0, 0.3, 2.0, 0.5)
    write_calibrated_copy(src, tmp_path / "out", cal)
    assert (src / "session.toml").read_text(encoding="utf-8") == text
    out = (tmp_path / "out" / "session.toml").read_text(encoding="utf-8")
    doc = tomllib.loads(out)
    assert doc["session"]["operator name"] == "Zoë"
    assert doc["session"]["start_utc"].year == 2015
    assert doc["magnetic"]["hard_iron_ut"] == [1.0, 2.0, 3.0]
    assert (tmp_path / "out" / "imu.csv").exists()


def test_calibrated_copy_with_force_replaces_only_another_session(tmp_path):
    """write_calibrated_copy(force=True) rmtree'd any dst: a directory of other files, or one holding the
    input session (deleted before the copy read it). Now the CLI's guard (io.run_dir.check_session_out):
    only another session is replaced."""
    import pytest

    from tpos_cli.errors import InvalidInputError
    from tpos_cli.magcal import MagCalibration, write_calibrated_copy

    cal = MagCalibration(np.array([1.0, 2.0, 3.0]), np.eye(3), 50.0, 0.3, 2.0, 0.5)
    parent = tmp_path / "p"
    src = parent / "s"
    src.mkdir(parents=True)
    text = '[session]\nname = "s"\nkind = "target"\n\n[imu]\naxes = "FRD"\nrate_hz = 100.0\n'
    (parent / "session.toml").write_text(text, encoding="utf-8")  # the parent looks like a session too
    (src / "session.toml").write_text(text, encoding="utf-8")
    (src / "imu.csv").write_text("t,gyro_x\n0,0\n")
    with pytest.raises(InvalidInputError, match="holds the input session"):
        write_calibrated_copy(src, parent, cal, force=True)
    assert (src / "imu.csv").exists()
    other = tmp_path / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(InvalidInputError, match="is not a tpos session"):
        write_calibrated_copy(src, other, cal, force=True)
    assert (other / "keep.txt").read_text() == "mine"
    with pytest.raises(InvalidInputError, match="already exists"):
        write_calibrated_copy(src, other, cal)
    write_calibrated_copy(src, tmp_path / "out", cal)
    write_calibrated_copy(src, tmp_path / "out", cal, force=True)  # a session: replaced
    assert "hard_iron_ut" in (tmp_path / "out" / "session.toml").read_text()


def test_field_profile_shows_a_magnet_attached_for_part_of_the_log():
    """One field keeps its magnitude range in every stretch of the log; a magnet carried for the middle
    third (BROAD trial 33: |m| 18-63 µT then, 43-46 µT before and after) widens that stretch alone."""
    from tpos_cli.magcal import field_profile

    F = 50.0
    R = Rotation.random(3000, random_state=2).as_matrix()
    m = np.einsum("nji,j->ni", R, np.array([20.0, 0.0, np.sqrt(F**2 - 400.0)]))
    m[1000:2000] += [25.0, 0.0, 0.0]  # a magnet fixed in the body
    prof = field_profile(np.arange(3000) / 10.0, m)
    ranges = [tuple(int(v) for v in part.split(" s ")[1].replace(" µT", "").split("-")) for part in prof.split(", ")]
    assert ranges[0] == ranges[2] == (50, 50) and ranges[1][1] - ranges[1][0] > 30, prof


def test_a_failed_fit_says_how_the_field_changed_along_the_log(tmp_path):
    """When the samples do not outline an ellipsoid, the error gives the field's magnitude per stretch
    and the --window remedy (a log holding two fields cannot be fitted whole)."""
    import pandas as pd
    import pytest

    from tests.helpers.sessions import write_minimal_session
    from tpos_cli.errors import ProcessingError
    from tpos_cli.magcal import calibrate_session

    s = write_minimal_session(tmp_path / "s", seconds=30.0, with_gps=False)
    imu = pd.read_csv(s / "imu.csv")
    # samples along one line (no ellipsoid can be fitted): |m| 67 -> 45 -> 67 µT along the log
    imu["mag_x"], imu["mag_y"], imu["mag_z"] = np.linspace(-50.0, 50.0, len(imu)), 0.0, 45.0
    imu.to_csv(s / "imu.csv", index=False)
    with pytest.raises(ProcessingError, match=r"do not outline an ellipsoid.*field's magnitude along the log \(5-95 %\): "
                                              r"1000-1010 s 4\d-6\d µT, 1010-1020 s 45-4\d µT, 1020-1030 s 4\d-6\d µT: .*--window T0:T1"):
        calibrate_session(s)


def test_samples_that_do_not_surround_the_centre_are_refused():
    """A magnetometer swept along a line (or an arc) can admit an ellipsoid far from every sample
    (centre 111 µT away, |m| <= 67 µT, "field" 1e7 µT): the fit is refused, not written with a warning."""
    import pytest

    from tpos_cli.errors import ProcessingError

    m = np.column_stack([np.linspace(0.0, 50.0, 3000), np.zeros(3000), np.full(3000, 45.0)])
    with pytest.raises(ProcessingError, match="do not surround the fitted centre"):
        fit_ellipsoid(m)


def test_a_window_off_the_log_is_invalid_input_naming_the_log_span(tmp_path):
    """`--window` beyond the log selects no sample: a usage mistake (exit 2 with the log's span, like `tpos noise
    --static`), not a failed fit (exit 1 with an empty field profile)."""
    import pandas as pd
    import pytest

    from tests.helpers.sessions import write_minimal_session
    from tpos_cli.errors import InvalidInputError
    from tpos_cli.magcal import calibrate_session

    s = write_minimal_session(tmp_path / "s", seconds=30.0, with_gps=False)
    imu = pd.read_csv(s / "imu.csv")
    imu["mag_x"], imu["mag_y"], imu["mag_z"] = 20.0, 0.0, 45.0
    imu.to_csv(s / "imu.csv", index=False)
    with pytest.raises(InvalidInputError, match=r"--window 500:600: no magnetometer samples in that window \(log spans "
                                                r"1000\.00-1029\.99\)"):
        calibrate_session(s, (500.0, 600.0))
