"""Errors raised by the ``capture`` package."""

from lenspair.core.errors import LenspairError


class CaptureError(LenspairError):
    """A problem in the capture stage (the message names the file or key)."""
