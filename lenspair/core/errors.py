"""Error types shared by every lenspair package.

Each stage package defines its own errors in its ``errors.py``, deriving from
:class:`LenspairError`, so that the CLI can turn any of them into a one-line
message and a non-zero exit code without catching unrelated bugs.
"""


class LenspairError(Exception):
    """Base class of every error lenspair raises on purpose."""


class ConfigError(LenspairError):
    """A configuration or spec file is malformed (message names the dotted key)."""


class ImageIOError(LenspairError):
    """An image file could not be read or written (message names the file)."""
