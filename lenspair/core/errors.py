"""Error types shared by every lenspair package.

Each stage package defines its own errors in its ``errors.py``, deriving from
:class:`LenspairError`, so that the CLI can turn any of them into a one-line
message and a non-zero exit code without catching unrelated bugs.
"""

from collections.abc import Sequence


def listed(items: Sequence[str], most: int = 3, sep: str = "; ") -> str:
    """The first ``most`` of ``items`` joined by ``sep``, then ``...`` when there are more.

    For one-line errors that name a few of many problems (the count goes
    beside it, in the caller's words).
    """
    return sep.join(items[:most]) + (f"{sep}..." if len(items) > most else "")


class LenspairError(Exception):
    """Base class of every error lenspair raises on purpose."""


class ConfigError(LenspairError):
    """A configuration or spec file is malformed (message names the dotted key)."""


class ImageIOError(LenspairError):
    """An image file could not be read or written (message names the file)."""
