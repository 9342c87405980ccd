"""Errors raised by the ``capture`` package."""

from lenspair.core.errors import LenspairError


class CaptureError(LenspairError):
    """A problem in the capture stage (the message names the file or key)."""


class AmbiguousTopicsError(CaptureError):
    """A bag holds more than two camera topics and their names do not tell cam0 and cam1."""
