"""Robustness sweeps (``offboard sweep SPEC.toml``): many flights of one scenario with parameters
drawn or gridded per flight, run on Dask, one Parquet row per flight, and a report.

- ``spec``: the sweep file, validated (one line naming the field), expanded to per-flight
  parameter sets with per-flight seeds;
- ``flight``: one flight on the one-vehicle path (``offboard.inprocess.simulate``, the reference)
  and the row of metrics it gives;
- ``batch``: the batched engine, N flights stepped together, equal per flight to ``flight``;
- ``runner``: flights chunked into Dask tasks, rows streamed to Parquet, progress;
- ``report``: success rate, percentiles, sensitivity ranking, plots.
"""
