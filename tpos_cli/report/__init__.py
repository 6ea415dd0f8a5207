"""`tpos report`: accuracy of a run's solutions against GPS-referenced truth, filter health, PDF.

`metrics` (pure statistics), `truth` (choosing and interpolating the truth), `rundir` (reading a run
directory), `accuracy` and `health` (tables), `figures` (matplotlib builders), `pdf` (the document),
`build.make_report` (the entry point the CLI calls).
"""
