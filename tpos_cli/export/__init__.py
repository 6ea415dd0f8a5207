"""`tpos export`: deliverables other tools open (CSV, KML 2.2, GeoJSON RFC 7946, GPX 1.1).

`trajectory` (one solution at a chosen rate), `meta` (provenance, column meanings, decimals, UTC of
the session), the writers `geojson`, `kml`, `gpx`, and `build.export_run` (the entry point). The
target combination, the 95 % ellipse, UTM, the choice of the best solution and the atomic output
files live in `tpos_cli.report` (`targets`, `projection`, `solutions`, `files`), which the report
shares.
"""
