"""A process pool for making detector samples: spawned workers, one thread each.

Rendering, reading and ingesting recordings are CPU work in numpy and OpenCV;
``workers`` processes of one thread each use ``workers`` cores (OpenCV and
torch would otherwise start a thread per core in every worker). Like
ingest's workers, they end when the command that started them dies
(:func:`lenspair.core.orphans.end_with_parent`).
"""

import os
from collections.abc import Callable, Sequence
from typing import TypeVar

import cv2
import torch

from lenspair.core.orphans import end_with_parent
from lenspair.core.workers import spawn_pool

T = TypeVar("T")
R = TypeVar("R")


def _init_worker(parent_pid: int) -> None:
    end_with_parent(parent_pid)
    cv2.setNumThreads(1)
    torch.set_num_threads(1)


def process_map(function: Callable[[T], R], items: Sequence[T], workers: int) -> list[R]:
    """``function`` over ``items``, results in order; in this process when ``workers <= 1``.

    ``function`` and the items must be picklable (module-level functions,
    ``functools.partial`` of them).
    """
    if workers <= 1 or len(items) <= 1:
        return [function(item) for item in items]
    with spawn_pool(min(workers, len(items)), _init_worker, (os.getpid(),)) as pool_map:
        return list(pool_map(function, items))
