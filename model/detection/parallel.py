"""A process pool for making detector samples: spawned workers, one thread each.

Rendering, reading and ingesting recordings are CPU work in numpy and OpenCV;
``workers`` processes of one thread each use ``workers`` cores (OpenCV and
torch would otherwise start a thread per core in every worker).
"""

from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import TypeVar

import cv2
import torch

T = TypeVar("T")
R = TypeVar("R")


def _one_thread() -> None:
    cv2.setNumThreads(1)
    torch.set_num_threads(1)


def process_map(function: Callable[[T], R], items: Sequence[T], workers: int) -> list[R]:
    """``function`` over ``items``, results in order; in this process when ``workers <= 1``.

    ``function`` and the items must be picklable (module-level functions,
    ``functools.partial`` of them).
    """
    if workers <= 1 or len(items) <= 1:
        return [function(item) for item in items]
    with ProcessPoolExecutor(
        min(workers, len(items)), mp_context=get_context("spawn"), initializer=_one_thread
    ) as pool:
        return list(pool.map(function, items))
