"""Errors raised by the ``simulate`` package."""

from lenspair.core.errors import LenspairError


class SimulateError(LenspairError):
    """A problem in the simulate stage (the message names the file or key)."""
