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


def test_a_unix_time_log_whose_start_utc_names_its_first_sample_is_dated_from_1970():
    # navego_canada_enav: t in Unix seconds, start_utc the first sample's UTC: start_utc + t is 2067, a false
    # "after today" (audit, session 25); the contract's t may have any origin, and 1970 + t is the log's UTC
    from tpos_cli.report.format import UNIX_EPOCH

    s = datetime(2018, 9, 4, 21, 43, 26, tzinfo=UTC)
    got, why = checked_start_utc(s, [1536097411.1, 1536097773.0], NOW)
    assert got == UNIX_EPOCH and "t counts Unix seconds" in why and "after today" not in why
    assert list(utc_strings([1536097405.9], got, 3)) == ["2018-09-04T21:43:25.900Z"]
    # the same clock with a start_utc a day off its Unix date: no reading dates it, still refused
    got, why = checked_start_utc(s + (s - s.replace(day=3)), [1536097411.1, 1536097773.0], NOW)
    assert got is None and "after today" in why and "no UTC times written" in why
    # a GPS-seconds-of-week log with start_utc at the start of its week is fine
    week = datetime(2020, 7, 5, tzinfo=UTC)
    assert checked_start_utc(week, [243258.5, 243551.7], NOW) == (week, "")
