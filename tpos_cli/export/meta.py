"""What every export carries besides its points: provenance, time base, grid, column meanings."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.io.bounded import read_toml
from tpos_cli.report.projection import UtmZone

# units and meaning of the exported columns (CSV header names, GeoJSON properties, KML data, GPX extensions)
COLUMN_DOC = {
    "id": "target name",
    "t": "logger clock, s",
    "time_utc": "UTC (session start_utc + t; 1970-01-01 + t for a clock in Unix seconds)",
    "lat": "WGS-84 latitude, deg",
    "lon": "WGS-84 longitude, deg",
    "h": "WGS-84 ellipsoidal height, m",
    "vn": "north velocity, m/s",
    "ve": "east velocity, m/s",
    "vd": "down velocity, m/s",
    "roll": "roll, deg",
    "pitch": "pitch, deg",
    "yaw": "yaw from true north, deg [0, 360)",
    "sigma_n": "north SD, m",
    "sigma_e": "east SD, m",
    "sigma_u": "up SD, m",
    "sigma_vn": "north velocity SD, m/s",
    "sigma_ve": "east velocity SD, m/s",
    "sigma_vd": "down velocity SD, m/s",
    "sigma_roll": "roll SD, deg",
    "sigma_pitch": "pitch SD, deg",
    "sigma_yaw": "yaw SD, deg (Euler angle: large near pitch +-90 deg however good the attitude)",
    "sigma_tilt_n": "SD of the attitude error about north, deg",
    "sigma_tilt_e": "SD of the attitude error about east, deg",
    "sigma_heading": "heading SD: SD of the attitude error about down, deg (defined at any pitch)",
    "att95_deg": "95 % bound of the total attitude error angle, deg (at least 95 %: sqrt(chi2_3(0.95) x the "
    "largest eigenvalue of the attitude-error covariance))",
    "cov_ne_m2": "north-east covariance, m^2",
    "cov_nu_m2": "north-up covariance, m^2",
    "cov_eu_m2": "east-up covariance, m^2",
    "ell95_major_m": "95 % horizontal ellipse, semi-major axis, m",
    "ell95_minor_m": "95 % horizontal ellipse, semi-minor axis, m",
    "ell95_azimuth_deg": "95 % ellipse major-axis azimuth, deg clockwise from true north [0, 180)",
    "n_shots": "shots combined (inverse-covariance weighting)",
    "shot_chi2_dof": "chi-square per degree of freedom of the shots about the combined point (NaN for one shot): "
    "the share of the shots' variance that averages out (above 1: the sigmas were scaled up by it)",
    "t_first": "start of the first shot, logger clock, s",
    "t_last": "end of the last shot, logger clock, s",
    "utm_zone": "UTM zone (WGS 84)",
    "utm_e_m": "UTM easting, m",
    "utm_n_m": "UTM northing, m",
}


# decimals written per column: 1e-9 deg ~ 0.1 mm; metres to 0.1 mm; SDs to 0.01 mm; angles to 1e-6 deg;
# logger times to 1 us (1 ms was 0.5 ms off on a 285.7 Hz log: 15 mm along track at 30 m/s)
DECIMALS = {
    "lat": 9,
    "lon": 9,
    "h": 4,
    "utm_e_m": 4,
    "utm_n_m": 4,
    "t": 6,
    "t_first": 6,
    "t_last": 6,
    "vn": 4,
    "ve": 4,
    "vd": 4,
    "roll": 6,
    "pitch": 6,
    "yaw": 6,
    "ell95_azimuth_deg": 2,
    "cov_ne_m2": 10,
    "cov_nu_m2": 10,
    "cov_eu_m2": 10,
    "shot_chi2_dof": 3,
}
DEFAULT_DECIMALS = 5


def decimals(column: str) -> int:
    """Fixed decimals of an exported column (no scientific notation in any export)."""
    return DECIMALS.get(column, DEFAULT_DECIMALS)


@dataclass(frozen=True)
class ExportMeta:
    """Provenance written into each export (document name/description, GPX metadata)."""

    session: str
    kind: str  # "targets" | "trajectory"
    solution: str
    run_dir: str
    pipeline: str
    config_sha256: str
    tpos_version: str
    zone: UtmZone
    start_utc: datetime | None

    @property
    def title(self) -> str:
        return f"{self.session}: {self.kind} ({self.solution})"

    @property
    def description(self) -> str:
        from tpos_cli.report.format import UNIX_EPOCH

        time = (
            "no UTC (the session gives no usable start_utc): times are the logger clock t" if not self.start_utc
            else "UTC as 1970-01-01 + t (t counts Unix seconds; the session's start_utc names the first epoch)"
            if self.start_utc == UNIX_EPOCH else "UTC from the session's start_utc"
        )
        return (
            f"tpos {self.tpos_version} export of run {self.run_dir} (pipeline {self.pipeline}, config sha256 "
            f"{self.config_sha256[:12]}), solution {self.solution}. WGS-84; heights are ellipsoidal, m; "
            f"sigmas are 1-SD; ellipses 95 %; grid UTM {self.zone.label} (EPSG:{self.zone.epsg}); {time}."
        )


def read_start_utc(session_dir: Path | None) -> datetime | None:
    """`[session] start_utc` of a session (UTC of t = 0), or None when absent or unreadable."""
    if session_dir is None:
        return None
    try:  # bounded: a FIFO or a huge file named session.toml must not block an export
        raw = read_toml(Path(session_dir) / "session.toml", "session.toml")
        v = raw.get("session", {}).get("start_utc")
        if v is None:
            return None
        dt = v if isinstance(v, datetime) else datetime.fromisoformat(str(v).replace("Z", "+00:00"))
    except (OSError, InvalidInputError, ValueError, AttributeError):
        return None
    return dt.replace(tzinfo=UTC) if dt.tzinfo is None else dt.astimezone(UTC)


def target_summary(r: dict) -> str:
    """One line a person reads in a GPS tool or Google Earth: position SDs, 95 % ellipse, shots."""

    def mm(v):
        return "n/a" if v is None or not np.isfinite(v) else f"{1000.0 * v:.1f} mm" if v < 1.0 else f"{v:.3f} m"

    if "n_shots" not in r:
        return "observer (instrument position)"
    txt = (
        f"h {r['h']:.4f} m (ellipsoidal); SD north {mm(r['sigma_n'])}, east {mm(r['sigma_e'])}, up {mm(r['sigma_u'])}; "
        f"95 % ellipse {mm(r['ell95_major_m'])} x {mm(r['ell95_minor_m'])}, major axis at {r['ell95_azimuth_deg']:.1f} deg; "
        f"{r['n_shots']} shot{'s' if r['n_shots'] != 1 else ''}; UTM {r['utm_zone']} E {r['utm_e_m']:.3f} N {r['utm_n_m']:.3f}"
    )
    return txt
