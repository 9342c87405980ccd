"""Error types shared by every lenspair package.

Each stage package defines its own errors in its ``errors.py``, deriving from
:class:`LenspairError`, so that the CLI can turn any of them into a one-line
message and a non-zero exit code without catching unrelated bugs.
"""

import re
from collections.abc import Sequence

_ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def first_text_line(text: str, empty: str = "") -> str:
    """The first non-blank line of a library's message, without terminal escape codes.

    ``empty`` when there is none. For one-line errors that quote a library.
    """
    text = _ANSI_ESCAPE.sub("", text).strip()
    return text.splitlines()[0] if text else empty


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message, without terminal escape codes.

    For one-line errors quoting a library's exception (torch.export colours its
    messages): the exception's type name when it has no message.
    """
    return first_text_line(str(exc), type(exc).__name__)


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


class WorkerDiedError(LenspairError):
    """A pool's worker process ended while at work (killed: out of memory, or by a user)."""
