"""Errors raised by the face of lenspair (the command line and the demo).

The base class every lenspair error derives from, and the errors shared by all
packages, are in :mod:`lenspair.core.errors`; each stage has its own
``errors.py`` (``lenspair.capture.errors``, ``lenspair.rectify.errors``, ...).
"""

from lenspair.core.errors import LenspairError


class DemoError(LenspairError):
    """A stage of the demo failed (the message names the stage)."""
