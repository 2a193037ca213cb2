"""Benchmarks: speed against the limit, tracking against peer controllers (``bench/run.py``)."""
