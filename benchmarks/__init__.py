"""Benchmarks: ratios measured in one run, medians quoted."""
