"""Errors of the benchmark scripts."""


class ResultsError(Exception):
    """The section cannot be written: README markers, or benchmark files of several runs.

    The README's markers are missing or out of order, or the benchmark files
    come from different runs (:func:`benchmarks.readme_speed.benchmark_run`).
    """
