"""Argparse value types shared by the subcommands (one-line errors naming the option)."""

import argparse
from pathlib import Path

from lenspair.core.samples import file_or_sample


def positive_int(text: str) -> int:
    """Argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def detector_file(text: str) -> Path:
    """Argparse type: a detector checkpoint; ``detector.pt`` alone is the bundled one."""
    return file_or_sample(text, ".pt")
