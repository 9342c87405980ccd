"""How the README's generated sections write a figure, a missing input, and a picture's place.

Shared by the parts of the "Measured results" section
(:mod:`benchmarks.readme_demo`, :mod:`benchmarks.readme_speed`) and by
:mod:`benchmarks.readme_results`, which assembles them and writes the README.
"""

import math
from pathlib import Path
from typing import Any

from lenspair.core.report import Block, Paragraph

FIGURES = Path("docs") / "results"
"""Where the pictures the section shows are copied, relative to the README."""

Copies = list[tuple[Path, Path]]
"""(source, destination) of the pictures the section shows, copied by
:func:`benchmarks.readme_results.main`."""


def number(value: Any, digits: int) -> str:
    """``value`` with ``digits`` decimals; ``n/a`` for None, ``inf`` for an infinite one."""
    if value is None:
        return "n/a"
    value = float(value)
    if math.isinf(value):
        return "inf"
    return f"{value:.{digits}f}"


def not_measured(what: str, command: str) -> list[Block]:
    """The paragraph standing for a part whose input is missing: the command that writes it."""
    return [Paragraph(f"Not measured yet: {what} comes from `{command}`.")]
