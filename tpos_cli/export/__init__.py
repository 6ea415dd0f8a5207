"""`tpos export`: deliverables other tools open (CSV, KML 2.2, GeoJSON RFC 7946, GPX 1.1).

`targets` (repeat shots combined by inverse-covariance weighting, 95 % ellipses), `trajectory`
(one solution at a chosen rate), `projection` (UTM through pyproj), `solutions` (the best solution
of a run), `meta` (provenance and UTC), `csv`-like formatting and the writers `geojson`, `kml`,
`gpx`, `files` (atomic, umask-respecting output files), `build.export_run` (the entry point).
"""
