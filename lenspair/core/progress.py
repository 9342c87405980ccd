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
    yield from tqdm(items, desc=desc, total=total, unit=unit, disable=disable, leave=False)
