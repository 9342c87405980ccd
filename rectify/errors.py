"""Errors raised by the ``rectify`` package."""

from lenspair.core.errors import LenspairError


class RectifyError(LenspairError):
    """A problem in the rectify stage (the message names the file or key)."""
