"""Checks of numbers that callers of the Python API pass."""

from typing import TypeGuard

import numpy as np


def is_whole_number(value: object) -> TypeGuard[int | np.integer]:
    """Whether ``value`` is an ``int`` or a NumPy integer, and not a ``bool``.

    ``12.0 == 12`` and ``True == 1``: comparisons let a float or a bool through
    where a count, a size or a bit depth is meant, and they fail later, further
    from the call that passed them (a shift by a float, a tile of ``True`` pixels).
    """
    return isinstance(value, int | np.integer) and not isinstance(value, bool)
