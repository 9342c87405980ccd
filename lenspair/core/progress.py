"""Progress bars for long work (tqdm on stderr, quiet when asked)."""

import os
from collections.abc import Iterable, Iterator
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")


def progress(
    items: Iterable[T], desc: str, total: int | None = None, unit: str = "it"
) -> Iterator[T]:
    """Wrap ``items`` in a progress bar written to stderr.

    Bars are disabled when ``LENSPAIR_QUIET=1`` (the test suite sets it) so
    that logs stay readable; the iteration itself is unchanged.
    """
    disable = os.environ.get("LENSPAIR_QUIET", "") == "1"
    if not disable:
        _SHOWN.append(desc)
    yield from tqdm(items, desc=desc, total=total, unit=unit, disable=disable, leave=False)


_SHOWN: list[str] = []
"""The bars this process has shown (their labels)."""


def bar_shown() -> bool:
    """Whether this process has shown a bar: one may have left its line open on stderr.

    In a terminal a closed bar clears its line; in a log file its last
    carriage-return-separated state stays, unterminated, and the next message would
    continue it.
    """
    return bool(_SHOWN)
