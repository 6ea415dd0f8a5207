"""`tpos report`: a report someone hands in, with or without truth.

`rundir` (reading a run directory), `truth` (choosing and interpolating the truth), `metrics` (pure
statistics), `accuracy` (errors against truth), `health` (innovations, forward/backward
agreement), `qc` (what a run shows without truth: estimated accuracy, GPS quality, disturbances),
`context` (everything the pages draw, computed once), `layout` (pages, tables for people, time
axes, map furniture), `sections` (packing sections onto pages), `summary` (page 1), `planview`,
`timeplots`, `tables`, `appendix` (`--full`), `figures` (the Allan plot), `pdf` (the document),
`targets` (repeat shots combined, 95 % ellipses), `projection` (UTM), `solutions` (the best one),
`files` (whole, umask-respecting outputs),
`build.make_report` (the entry point the CLI calls).
"""
