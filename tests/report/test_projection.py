"""UTM zones and grid coordinates against known points."""

from __future__ import annotations

import numpy as np
import pytest

from tpos_cli.report.projection import to_utm, utm_zone, zone_for

# Meridian arc of WGS-84 from the equator to 45 deg: 4 984 944.378 m (Bowring's series, also
# NGA's UTM tables); on the central meridian the UTM northing is k0 = 0.9996 times the arc.
ARC_45_M = 4984944.378


@pytest.mark.parametrize(
    ("lat", "lon", "label", "epsg"),
    [
        (45.49, -73.56, "18N", 32618),  # Montreal
        (-33.87, 151.21, "56S", 32756),  # Sydney
        (60.39, 5.32, "32N", 32632),  # Bergen: the Norway exception (would be 31)
        (78.22, 15.65, "33N", 32633),  # Longyearbyen: the Svalbard exception
        (0.0, 179.99, "60N", 32660),
        (10.0, -180.0, "1N", 32601),
    ],
)
def test_zones(lat, lon, label, epsg):
    z = utm_zone(lat, lon)
    assert (z.label, z.epsg) == (label, epsg)


def test_central_meridian_points():
    z = utm_zone(45.0, -75.0)
    e, n = to_utm(np.array([0.0, 45.0]), np.array([-75.0, -75.0]), z)
    np.testing.assert_allclose(e, [500000.0, 500000.0], atol=1e-6)  # false easting on the central meridian
    np.testing.assert_allclose(n, [0.0, 0.9996 * ARC_45_M], atol=0.01)  # 1 cm: the published arc's rounding
    zs = utm_zone(-10.0, -75.0)
    _, ns = to_utm(np.array([-0.0001]), np.array([-75.0]), zs)
    assert 9_999_900.0 < ns[0] < 10_000_000.0  # false northing in the south


def test_zone_of_a_set_spanning_the_antimeridian_and_nan():
    z = zone_for([10.0, 10.0], [179.9, -179.9])
    assert z.number in (1, 60)
    e, n = to_utm(np.array([np.nan]), np.array([0.0]), utm_zone(0, 0))
    assert np.isnan(e[0]) and np.isnan(n[0])
