"""Errors raised by the ``rectify`` package."""

from lenspair.core.errors import LenspairError


class RectifyError(LenspairError):
    """A problem in the rectify stage (the message names the file or key)."""


class RegistrationError(RectifyError):
    """No trustworthy homography between the two views could be estimated."""


class CropError(RectifyError):
    """The valid region of the registered views is smaller than the requested crop."""
