"""Errors raised by the ``capture`` package."""

from lenspair.core.errors import LenspairError


class CaptureError(LenspairError):
    """A problem in the capture stage (the message names the file or key)."""


class AmbiguousTopicsError(CaptureError):
    """A bag holds more than two camera topics and their names do not tell cam0 and cam1.

    Attributes:
        topics: the camera topics it holds.
    """

    def __init__(self, message: str, topics: tuple[str, ...] = ()) -> None:
        """The one-line ``message``, and the bag's camera ``topics``."""
        super().__init__(message)
        self.topics = topics
