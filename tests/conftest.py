"""Shared test settings: quiet progress bars, headless plotting, fast hypothesis."""

import os

os.environ.setdefault("LENSPAIR_QUIET", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

from hypothesis import settings

settings.register_profile("ci", max_examples=40, deadline=None, derandomize=True)
settings.load_profile("ci")
