"""Errors raised by the ``dataset`` package."""

from lenspair.core.errors import LenspairError


class DatasetError(LenspairError):
    """A problem in the dataset stage (the message names the file or key)."""
