"""`tpos import`: turn logs in other formats into a contract session (docs/log-format.md).

Each format is one module returning an `ImportResult` (contract tables + `session.toml` keys);
`import_into_session` writes it into the output session, which may be built by several imports
(e.g. the IMU CSV, then the RTKLIB solution). Sources are only read.
"""

from __future__ import annotations

import math
from pathlib import Path

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers.csv_table import import_csv
from tpos_cli.importers.mapping import load_mapping
from tpos_cli.importers.nmea import import_nmea
from tpos_cli.importers.result import ImportResult
from tpos_cli.importers.rtklib_pos import import_rtklib_pos
from tpos_cli.importers.session_out import merge_toml, write_session
from tpos_cli.importers.ubx import import_ubx

FORMATS = ("csv", "nmea", "rtklib-pos", "ubx")
# The geoid undulation stays within about -107 m (Indian Ocean) and +86 m (New Guinea) (EGM2008).
MAX_GEOID_SEP_M = 120.0


def read_source(fmt: str, src: Path, *, mapping: Path | None = None, clock: str = "gps_tow",
                geoid_sep_m: float | None = None, heights: str | None = None) -> ImportResult:
    """Read one source file of format `fmt` (see FORMATS); `geoid_sep_m` (nmea, rtklib-pos) and
    `heights` (rtklib-pos) say how to reach ellipsoidal heights where the source does not."""
    if geoid_sep_m is not None and not (math.isfinite(geoid_sep_m) and abs(geoid_sep_m) <= MAX_GEOID_SEP_M):
        raise InvalidInputError(f"--geoid-sep-m {geoid_sep_m:g} is not a geoid undulation (within ±{MAX_GEOID_SEP_M:g} m)")
    if heights is not None and fmt != "rtklib-pos":
        raise InvalidInputError(f"--heights is only for the rtklib-pos format, not {fmt}")
    if fmt == "csv":
        if mapping is None:
            raise InvalidInputError("tpos import csv needs --map MAPPING.toml (see docs/mappings/README.md)")
        return import_csv(src, load_mapping(mapping))
    if mapping is not None:
        raise InvalidInputError(f"--map is only for the csv format, not {fmt}")
    if fmt == "nmea":
        return import_nmea(src, clock=clock, geoid_sep_m=geoid_sep_m)
    if fmt == "rtklib-pos":
        return import_rtklib_pos(src, clock=clock, geoid_sep_m=geoid_sep_m, heights=heights)
    if fmt == "ubx":
        return import_ubx(src, clock=clock)
    raise InvalidInputError(f"unknown import format {fmt!r}; use one of {', '.join(FORMATS)}")


def import_into_session(fmt: str, srcs: list[Path], out_dir: Path, *, mapping: Path | None = None,
                        clock: str = "gps_tow", force: bool = False, geoid_sep_m: float | None = None,
                        heights: str | None = None) -> tuple[list[Path], tuple[str, ...]]:
    """Import `srcs` (all of format `fmt`) into the session at `out_dir`; returns (files written, notes).

    Several sources of one table are concatenated in time order (e.g. hourly NMEA files).
    """
    import pandas as pd

    if not srcs:
        raise InvalidInputError("no source file given")
    results = [read_source(fmt, Path(s), mapping=mapping, clock=clock, geoid_sep_m=geoid_sep_m, heights=heights)
               for s in srcs]
    tables: dict[str, pd.DataFrame] = {}
    toml: dict = {}
    notes: list[str] = []
    for r in results:
        for name, df in r.tables.items():
            tables[name] = pd.concat([tables[name], df], ignore_index=True) if name in tables else df
        toml = merge_toml(toml, r.toml)
        notes.extend(r.notes)
    for name, df in tables.items():
        tables[name] = df.sort_values("t", kind="stable").reset_index(drop=True)
    if Path(out_dir).resolve() in {Path(s).resolve().parent for s in srcs}:
        raise InvalidInputError(f"{out_dir}: the output session must not be the directory of a source file")
    return write_session(Path(out_dir), tables, toml, force=force), tuple(notes)
