"""Benchmarks: ratios measured in one run, medians quoted."""

RUN_KEY = "benchmark_run"
"""The entry ``python -m benchmarks`` adds to every JSON file it produces: the run's id
and the machine (CPU, cores, torch threads, oneDNN's ISA cap), so that files of
different runs are told apart (:mod:`benchmarks.readme_results` refuses to mix them)."""
