"""Numbers for people (`tpos_cli.report.format`): UTC stamps only where start_utc can date the log."""

from __future__ import annotations

from datetime import UTC, datetime

from tpos_cli.report.format import checked_start_utc, utc_strings

NOW = datetime(2026, 11, 25, tzinfo=UTC)


def test_start_utc_dates_a_log_stamped_from_zero():
    s = datetime(2015, 6, 11, 14, 2, tzinfo=UTC)
    assert checked_start_utc(s, [0.0, 90.0], NOW) == (s, "")
    assert list(utc_strings([12.0], s, 0)) == ["2015-06-11T14:02:12Z"]
    assert checked_start_utc(None, [0.0], NOW) == (None, "")


def test_start_utc_of_the_first_sample_of_a_unix_time_log_is_refused():
    # navego_canada_enav: t in Unix seconds, start_utc the first sample's UTC: start_utc + t is 2067
    s = datetime(2018, 9, 4, 21, 43, 26, tzinfo=UTC)
    got, why = checked_start_utc(s, [1536097411.1, 1536097773.0], NOW)
    assert got is None and "2067-05-09T19:32:59Z, after today" in why and "no UTC times written" in why
    # a GPS-seconds-of-week log with start_utc at the start of its week is fine
    week = datetime(2020, 7, 5, tzinfo=UTC)
    assert checked_start_utc(week, [243258.5, 243551.7], NOW) == (week, "")
