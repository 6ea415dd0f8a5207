"""Importers: heights labelled by what the source says, converted only with a known geoid separation;
damaged sources (impossible values with good checksums, malformed rows) refused with exit 2; leap seconds."""

import struct

import numpy as np
import pytest
from typer.testing import CliRunner

from tests.importers.test_nmea_ubx import _nmea, _ubx_frame
from tpos_cli.cli import app
from tpos_cli.errors import InvalidInputError
from tpos_cli.importers import gpstime
from tpos_cli.importers.nmea import import_nmea
from tpos_cli.importers.rtklib_pos import import_rtklib_pos
from tpos_cli.importers.ubx import import_ubx

RMC = _nmea("GPRMC,120000.00,A,4530.0000,N,07333.0000,W,0.0,0.0,150621,,,D")


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


# ------------------------------------------------------------------------------------------ heights

def test_gga_without_geoid_separation_is_not_called_ellipsoidal(tmp_path):
    p = _write(tmp_path, "a.nmea", RMC + _nmea("GPGGA,120000.00,4530.0000,N,07333.0000,W,1,09,0.8,30.0,M,,M,,"))
    with pytest.raises(InvalidInputError, match="above mean sea level without the geoid separation.*--geoid-sep-m"):
        import_nmea(p)
    r = import_nmea(p, geoid_sep_m=-32.5)
    assert r.tables["gps"]["h"].iloc[0] == pytest.approx(-2.5)  # 30.0 above the geoid - 32.5
    assert any("--geoid-sep-m -32.5 m = ellipsoidal" in n for n in r.notes)


def test_gga_separation_in_the_log_is_used_and_said(tmp_path):
    p = _write(tmp_path, "a.nmea", RMC + _nmea("GPGGA,120000.00,4530.0000,N,07333.0000,W,1,09,0.8,30.0,M,-32.5,M,,"))
    r = import_nmea(p, geoid_sep_m=10.0)  # the log's own separation wins over the fallback
    assert r.tables["gps"]["h"].iloc[0] == pytest.approx(-2.5)
    assert any("GGA geoid separation (median -32.500 m) = ellipsoidal" in n for n in r.notes)


POS_HEAD = "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)\n"
POS_ROW = "2021/06/15 12:00:00.000   45.500000000  -73.550000000    30.0000   5   9   1.0000   1.0000   2.0000\n"


@pytest.mark.parametrize("option_line, kwargs, h, note", [
    ("% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)\n", {}, 30.0,
     "heights ellipsoidal, as the header says"),
    ("% (lat/lon/height=WGS84/geodetic,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)\n",
     {"geoid_sep_m": -32.5}, -2.5, "heights geodetic (above the geoid), as the header says; + --geoid-sep-m -32.5 m"),
    ("", {"heights": "ellipsoidal"}, 30.0, "as --heights says (the file does not say)"),
    ("", {"heights": "geodetic", "geoid_sep_m": -32.5}, -2.5, "as --heights says"),
])
def test_rtklib_heights_follow_the_header(tmp_path, option_line, kwargs, h, note):
    p = _write(tmp_path, "a.pos", option_line + POS_HEAD + POS_ROW)
    r = import_rtklib_pos(p, **kwargs)
    assert r.tables["gps"]["h"].iloc[0] == pytest.approx(h)
    assert any(note in n for n in r.notes)


@pytest.mark.parametrize("option_line, kwargs, message", [
    ("% (lat/lon/height=WGS84/geodetic,Q=1:fix)\n", {}, "the header says the heights are geodetic"),
    ("", {}, "does not say whether its heights are ellipsoidal or geodetic"),
    ("% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix)\n", {"heights": "geodetic", "geoid_sep_m": 1.0}, "contradicts the file's header"),
    ("% (lat/lon/height=Tokyo/ellipsoidal,Q=1:fix)\n", {}, "on the Tokyo datum"),
])
def test_rtklib_heights_never_guessed(tmp_path, option_line, kwargs, message):
    p = _write(tmp_path, "a.pos", option_line + POS_HEAD + POS_ROW)
    with pytest.raises(InvalidInputError, match=message):
        import_rtklib_pos(p, **kwargs)


def test_cli_refuses_an_implausible_geoid_separation(tmp_path):
    p = _write(tmp_path, "a.pos", POS_HEAD + POS_ROW)
    res = CliRunner().invoke(app, ["import", "rtklib-pos", str(p), "-o", str(tmp_path / "s"), "--heights", "geodetic",
                                   "--geoid-sep-m", "1e308"])
    assert res.exit_code == 2 and "is not a geoid undulation" in res.output and not (tmp_path / "s").exists()


# ------------------------------------------------------------------------------------------ damage

@pytest.mark.parametrize("row, message", [
    (POS_ROW.replace("2021/06/15", "2021/13/15"), "line 3: month 13 is not a month"),
    (POS_ROW.replace("12:00:00.000", "99:00:00.000"), "line 3: hour 99 is not an hour"),
    (POS_ROW.replace("2021/06/15", "2021/02/30"), "line 3: day 30 is not a day of its month"),
    (POS_ROW.replace("45.500000000", "95.500000000"), "line 3: latitude 95.5 is not a latitude"),
    (POS_ROW.replace("   2.0000\n", "\n"), "line 3: 9 fields where the header has 10"),
    (POS_ROW.replace("30.0000", "abc"), r"line 3: height\(m\) 'abc' is not a number"),
    (POS_ROW.replace("30.0000", "1e9"), r"line 3: height 1e\+09 is not a height on Earth"),
])
def test_damaged_pos_row_refused_at_the_door(tmp_path, row, message):
    p = _write(tmp_path, "a.pos", POS_HEAD + POS_ROW + row + POS_ROW.replace("00.000", "01.000"))
    with pytest.raises(InvalidInputError, match=message):
        import_rtklib_pos(p, heights="ellipsoidal")
    res = CliRunner().invoke(app, ["import", "rtklib-pos", str(p), "-o", str(tmp_path / "s"), "--heights", "ellipsoidal"])
    assert res.exit_code == 2 and "Traceback" not in res.output and not (tmp_path / "s").exists()


@pytest.mark.parametrize("sentence, message", [
    (_nmea("GPGGA,120000.00,9530.0000,N,07333.0000,W,1,09,0.8,30.0,M,-32.5,M,,"), "latitude 95.5 deg is outside ±90"),
    (_nmea("GPGGA,990000.00,4530.0000,N,07333.0000,W,1,09,0.8,30.0,M,-32.5,M,,"), "time '990000.00' is not hhmmss.ss"),
    (_nmea("GPRMC,120000.00,A,4530.0000,N,07333.0000,W,0.0,0.0,151321,,,D"), "date '151321' is not ddmmyy"),
    (_nmea("GPGGA,120000.00,4575.0000,N,07333.0000,W,1,09,0.8,30.0,M,-32.5,M,,"), "latitude '4575.0000' 'N' is not"),
    (_nmea("GPGGA,120000.00,4530.0000,N,07333.0000,W,1,09,0.8,1e9,M,-32.5,M,,"), r"altitude 1e\+09 m is not a height on Earth"),
])
def test_damaged_nmea_sentence_refused_at_the_door(tmp_path, sentence, message):
    good = _nmea("GPGGA,120000.00,4530.0000,N,07333.0000,W,1,09,0.8,30.0,M,-32.5,M,,")
    p = _write(tmp_path, "a.nmea", RMC + good + sentence)
    with pytest.raises(InvalidInputError, match=f"line 3: .*{message}"):
        import_nmea(p)


def _pvt(lat_e7=400966916, month=8, hour=17, height_mm=1580048):
    p = struct.pack("<IHBBBBBBIiBBBBiiiiIIiiiiiIIHBBi", 408639750, 2025, month, 28, hour, 30, 21, 0x07, 20, 750_000_000,
                    3, 0x03, 0, 25, -1051471665, lat_e7, height_mm, 1601435, 14, 10, 1, -2, -27,
                    0, 0, 50, 0, 100, 0, 0, 0) + bytes(8)
    return _ubx_frame(0x01, 0x07, p)


@pytest.mark.parametrize("frame, message", [
    (_pvt(lat_e7=955000000), "lat 95.5 is not a latitude"),
    (_pvt(month=13), "month 13 is not a month"),
    (_pvt(hour=99), "hour 99 is not an hour"),
    (_pvt(height_mm=2_000_000_000), "height 2000000000 is not a height on Earth"),
])
def test_damaged_ubx_message_refused_at_the_door(tmp_path, frame, message):
    (tmp_path / "a.ubx").write_bytes(_pvt() + frame)
    with pytest.raises(InvalidInputError, match=f"NAV-PVT message 2 .*{message}"):
        import_ubx(tmp_path / "a.ubx")


# ------------------------------------------------------------------------------------------ leap seconds

@pytest.mark.parametrize("utc, gps_minus_utc", [
    ("1981-06-30T23:59:59", 0), ("1981-07-01T00:00:00", 1), ("2005-12-31T12:00:00", 13), ("2006-01-01T00:00:00", 14),
    ("2016-12-31T23:59:59", 17), ("2017-01-01T00:00:00", 18), ("2025-08-28T17:30:21", 18),
])
def test_leap_seconds_from_erfa_match_iers_bulletin_c(utc, gps_minus_utc):
    unix = np.datetime64(utc, "s").astype("int64").astype(float)
    assert gpstime.leap_seconds_at_unix(unix) == gps_minus_utc


def test_a_date_past_the_leap_table_is_said():
    assert gpstime.leap_table_note([np.datetime64("2025-08-28", "s").astype("int64")]) is None
    assert "may be out of date" in gpstime.leap_table_note([np.datetime64("2060-01-01", "s").astype("int64")])
