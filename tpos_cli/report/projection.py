"""UTM grid coordinates of WGS-84 points, through pyproj (PROJ's transverse Mercator).

One zone serves a whole export (the zone of the points' centre), as a surveyor delivers a job in
one grid; points a little outside it stay valid in the extended zone. The zone follows the UTM/MGRS
rules, including the Norway (32V) and Svalbard (31X-37X) exceptions; the hemisphere is that of the
centre (EPSG:326zz north, 327zz south, false northing 10 000 km).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass(frozen=True)
class UtmZone:
    number: int
    north: bool

    @property
    def epsg(self) -> int:
        return (32600 if self.north else 32700) + self.number

    @property
    def label(self) -> str:
        """E.g. "18N" (hemisphere letter, not the MGRS latitude band)."""
        return f"{self.number}{'N' if self.north else 'S'}"


def utm_zone(lat_deg: float, lon_deg: float) -> UtmZone:
    """The UTM zone holding (lat, lon), with the Norway and Svalbard exceptions."""
    lon = (float(lon_deg) + 180.0) % 360.0 - 180.0
    lat = float(lat_deg)
    number = int((lon + 180.0) // 6.0) % 60 + 1
    if 56.0 <= lat < 64.0 and 3.0 <= lon < 12.0:
        number = 32
    elif 72.0 <= lat <= 84.0 and 0.0 <= lon < 42.0:
        number = 31 if lon < 9.0 else 33 if lon < 21.0 else 35 if lon < 33.0 else 37
    return UtmZone(number, lat >= 0.0)


def zone_for(lat_deg, lon_deg) -> UtmZone:
    """The zone of the centre of a set of points (mean latitude; longitude averaged on the circle)."""
    lat = np.asarray(lat_deg, dtype=float)
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    ok = np.isfinite(lat) & np.isfinite(lon)
    if not ok.any():
        raise ValueError("`lat_deg`, `lon_deg` hold no finite point")
    lon_c = np.degrees(np.arctan2(np.sin(lon[ok]).mean(), np.cos(lon[ok]).mean()))
    return utm_zone(float(lat[ok].mean()), float(lon_c))


@lru_cache(maxsize=8)
def _transformer(epsg: int):
    from pyproj import Transformer

    return Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)


def to_utm(lat_deg, lon_deg, zone: UtmZone) -> tuple[np.ndarray, np.ndarray]:
    """Easting and northing, m, of the points in `zone` (NaN in, NaN out)."""
    e, n = _transformer(zone.epsg).transform(np.asarray(lon_deg, dtype=float), np.asarray(lat_deg, dtype=float))
    e, n = np.asarray(e, dtype=float), np.asarray(n, dtype=float)
    bad = ~(np.isfinite(e) & np.isfinite(n))
    if bad.any():
        e, n = np.where(bad, np.nan, e), np.where(bad, np.nan, n)
    return e, n
