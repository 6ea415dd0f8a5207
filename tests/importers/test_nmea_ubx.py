"""NMEA and u-blox NAV-PVT import against sentences/frames built from known values."""

import struct

import numpy as np
import pytest

from tpos_cli.importers.nmea import import_nmea
from tpos_cli.importers.ubx import import_ubx


def _nmea(body: str) -> str:
    ck = 0
    for c in body.encode():
        ck ^= c
    return f"${body}*{ck:02X}\r\n"


def test_nmea_gga_rmc(tmp_path):
    # 45°30.000' N, 73°33.000' W, 30.0 m above the geoid, separation -32.5 m; 10 knots at course 90°
    lines = [
        _nmea("GPRMC,120000.00,A,4530.0000,N,07333.0000,W,10.0,90.0,150621,,,D"),
        _nmea("GPGGA,120000.00,4530.0000,N,07333.0000,W,2,09,0.8,30.0,M,-32.5,M,,"),
        _nmea("GPGGA,120001.00,4530.0000,N,07333.0000,W,2,09,0.8,30.0,M,-32.5,M,,").replace("*", "*0"),  # bad checksum
        _nmea("GPRMC,120001.00,A,4530.0000,N,07333.0000,W,0.0,,150621,,,D"),
        _nmea("GPGGA,120001.00,4530.0000,N,07333.0000,W,0,00,,,,,,,"),
    ]
    p = tmp_path / "log.nmea"
    p.write_text("".join(lines))
    r = import_nmea(p, clock="unix")
    g = r.tables["gps"]
    assert len(g) == 2  # the sentence with a broken checksum is skipped
    assert g["t"].iloc[0] == pytest.approx(1623758400.0)  # 2021-06-15T12:00:00Z
    assert g["lat"].iloc[0] == pytest.approx(45.5, abs=1e-12) and g["lon"].iloc[0] == pytest.approx(-73.55, abs=1e-12)
    assert g["h"].iloc[0] == pytest.approx(-2.5)  # 30.0 + (-32.5): ellipsoidal
    assert g["fix"].tolist() == [2, 0] and np.isnan(g["lat"].iloc[1])
    assert g["vn"].iloc[0] == pytest.approx(0.0, abs=1e-9) and g["ve"].iloc[0] == pytest.approx(10 * 1852 / 3600)
    tow = import_nmea(p).tables["gps"]["t"].iloc[0]
    assert tow == pytest.approx(2 * 86400 + 12 * 3600 + 18)  # Tuesday; GPS = UTC + 18 s


def _ubx_frame(cls, mid, payload):
    body = bytes([cls, mid]) + struct.pack("<H", len(payload)) + payload
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


def test_ubx_nav_pvt(tmp_path):
    itow = 408639750
    p = struct.pack("<IHBBBBBBIiBBBBiiiiIIiiiiiIIHBBi", itow, 2025, 8, 28, 17, 30, 21, 0x07, 20, 750_000_000,
                    3, 0x03 | (2 << 6), 0, 25, -1051471665, 400966916, 1580048, 1601435, 14, 10, 1, -2, -27,
                    0, 0, 50, 0, 100, 0, 0, 0) + bytes(8)
    assert len(p) == 92
    data = b"junk" + _ubx_frame(0x01, 0x07, p) + _ubx_frame(0x02, 0x15, b"\x00" * 16)
    bad = bytearray(_ubx_frame(0x01, 0x07, p))
    bad[-1] ^= 0xFF  # corrupt checksum: skipped
    (tmp_path / "a.ubx").write_bytes(data + bytes(bad))
    g = import_ubx(tmp_path / "a.ubx").tables["gps"]
    assert len(g) == 1
    row = g.iloc[0]
    assert row.t == pytest.approx(408639.75)  # iTOW
    assert (row.lat, row.lon, row.h) == (pytest.approx(40.0966916), pytest.approx(-105.1471665), pytest.approx(1580.048))
    assert row.fix == 2 and (row.vn, row.ve, row.vd) == (pytest.approx(0.001), pytest.approx(-0.002), pytest.approx(-0.027))
