"""Fleet calibration: a manifest of recorded runs through the offline pipeline, on local processes or a Dask cluster.

``manifest.read_manifest`` parses the CSV; ``row.process_run`` is one run, bag to row (the worker's job, the same
core as ``replay``: ``pipeline.run_bag`` with the default configuration); ``runner.run_fleet`` schedules the runs
and streams the rows to ``runs.parquet``; ``units.summarize_units`` pools them per unit and flags the units that
stand out; ``plot.fleet_plot`` draws ``fleet.png``; ``simulate.simulate_fleet`` writes a fleet with known truth.
See docs/fleet.md.
"""
