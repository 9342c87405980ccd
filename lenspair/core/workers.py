"""Spawned process pools that start quietly and stop with the command that started them.

``capture-ingest --workers`` and the detector's sample making run numpy and
OpenCV work in ``spawn`` pools. Stopping such a run used to print a worker's
traceback per process beside lenspair's one line:

* Ctrl-C reaches the whole process group, and a worker still importing
  (``import cv2``) had not yet reached the initializer that ignores it: a
  ``KeyboardInterrupt`` traceback from each one. :func:`spawn_pool` starts
  every worker with ``SIGINT`` blocked from birth (a signal mask survives
  ``exec``); the parent alone answers Ctrl-C and stops the pool.
* A parent that left on ``SIGTERM`` while a worker was still reading its
  start-up data cut that pipe short (``UnpicklingError: pickle data was
  truncated``, or its semaphore gone). :func:`spawn_pool` holds a signal
  that arrives while workers start until every one is known, and ends the
  workers, waiting for them, before the error leaves it.
* ``SIGTERM`` sent to the process group (``timeout``, systemd, a batch
  scheduler) also reached a worker before it had read its start-up data (a
  few MB for ``capture-ingest``: more than a pipe holds). It died there, and
  its parent waited forever to write the rest. Workers are born with
  ``SIGTERM`` blocked too and unblock it once their data is read (in the
  initializer's wrapper): a ``SIGTERM`` that came meanwhile ends them then.
* A worker killed at work (the out-of-memory killer) broke the pool: a
  traceback and exit 1. It is :class:`~lenspair.core.errors.WorkerDiedError`, one line.

A ``kill -9`` of the parent is :mod:`lenspair.core.orphans`' business.
"""

import os
import signal
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing import get_context
from typing import Any

from lenspair.core.errors import WorkerDiedError

STOP_SECONDS = 5.0
"""How long a worker asked to end (``SIGTERM``) may take before it is killed."""


@contextmanager
def _starting_workers() -> Iterator[None]:
    """Meanwhile: Ctrl-C and SIGTERM wait, and processes started now are born deaf to both.

    ``SIGINT`` and ``SIGTERM`` are blocked in this thread, whose mask the
    processes it starts inherit (across ``exec`` too): a worker never sees
    Ctrl-C, which its parent answers, and sees ``SIGTERM`` only once it has
    read its start-up data (:func:`_started`). A signal arriving while
    workers start is held and acted on once they all are known, so that the
    pool can end every one of them: one still starting when its parent left
    read its start-up data from a closed pipe (a traceback). Main thread only
    (signal handlers live there).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[signal.Signals] = []

    def hold(signum: int, _: object) -> None:
        held.append(signal.Signals(signum))

    previous = {number: signal.signal(number, hold) for number in _HELD}
    signal.pthread_sigmask(signal.SIG_BLOCK, set(_HELD))
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, set(_HELD))
        # as it would have been answered (KeyboardInterrupt, Terminated, or the default),
        # also over an error the start met: a worker that took the same SIGTERM ended
        # at once, and the pool, broken, refused the next one
        if held:
            handler = previous[held[0]]
            if callable(handler):
                handler(held[0], None)
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), held[0])


_HELD = (signal.SIGINT, signal.SIGTERM)
"""The signals held while workers start (:func:`_starting_workers`)."""


def _started(initializer: Callable[..., None], *initargs: Any) -> None:
    """In a worker: its start-up data is read; let SIGTERM end it from now on, then initialise."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM})
    initializer(*initargs)


def _end_workers(pool: ProcessPoolExecutor) -> None:
    """Stop handing out work and end the pool's processes now, waiting for them."""
    # the pool's processes are not public (and shutdown forgets them); without them
    # (another Python) the workers still end, through lenspair.core.orphans, less quietly
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(STOP_SECONDS)
        if process.is_alive():
            process.kill()
            process.join()


@contextmanager
def spawn_pool(
    workers: int, initializer: Callable[..., None], initargs: tuple[Any, ...] = ()
) -> Iterator[Callable[..., Iterator[Any]]]:
    """A ``spawn`` pool of ``workers`` processes; yields its ``map``, which starts them.

    The workers start with ``SIGINT`` blocked (the parent stops them on
    Ctrl-C); an error or interrupt leaving the block ends them first. A
    worker that dies at work is :class:`~lenspair.core.errors.WorkerDiedError`.

    Yields:
        ``map(function, items, chunksize=1)``: results in order, as
        :meth:`concurrent.futures.Executor.map` gives them.
    """
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=get_context("spawn"),
        initializer=_started,
        initargs=(initializer, *initargs),
    )

    def quiet_map(function: Callable[..., Any], items: Any, chunksize: int = 1) -> Iterator[Any]:
        with _starting_workers():  # the workers are started as the items are handed out
            return pool.map(function, items, chunksize=chunksize)

    try:
        yield quiet_map
    except BrokenProcessPool:
        _end_workers(pool)
        raise WorkerDiedError(
            "a worker process ended while at work (killed: out of memory? fewer --workers "
            "use less memory)"
        ) from None
    except BaseException:
        _end_workers(pool)
        raise
    pool.shutdown(wait=True)
