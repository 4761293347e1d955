"""Benchmarks: each guards a current default or a documented target, run side by side with what it replaced
and printed as a ratio (``bench/README.md`` lists them and their targets). Run as ``python -m bench.<name>``;
one-off questions and probes are in ``experiments/``. Nothing in the pipeline or the tests imports this package."""
