"""Worker processes that end when their parent dies, whatever the signal.

A ``kill -9`` of a command gives it no chance to stop its worker processes;
without help they live on as orphans, finish their queued work (writing
files no journal will list) and then wait forever. :func:`end_with_parent`,
called first thing in a worker (a pool initializer), prevents that twice
over: on Linux the kernel sends the worker ``SIGKILL`` the moment its parent
exits (``prctl(PR_SET_PDEATHSIG)``), and on every system a daemon thread
checks each ``poll_seconds`` whether the parent is still the one that
started it and ends the worker at once (``os._exit``) when it is not.

Ending with ``SIGKILL``/``os._exit`` can leave a half-written temporary
file; lenspair's temporaries are named by their creator's process id (see
:mod:`lenspair.core.leftovers`) and the next run removes them.
"""

import ctypes
import ctypes.util
import os
import signal
import sys
import threading
import time

_PR_SET_PDEATHSIG = 1


def _kernel_death_signal() -> None:
    """Ask Linux to SIGKILL this process when its parent exits (no-op elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):  # no prctl: the watchdog thread still works
        pass


def _watch(parent_pid: int, poll_seconds: float) -> None:
    while True:
        if os.getppid() != parent_pid:
            os._exit(1)  # the parent is gone: stop now, without finishing queued work
        time.sleep(poll_seconds)


def end_with_parent(parent_pid: int, poll_seconds: float = 0.2) -> None:
    """Make this process end as soon as process ``parent_pid`` (its parent) does.

    Args:
        parent_pid: the parent's pid, as the parent saw it (``os.getpid()``
            passed to the child), so that a parent that died before this
            call is noticed too.
        poll_seconds: watchdog period (portable fallback to the kernel signal).

    """
    _kernel_death_signal()
    if os.getppid() != parent_pid:  # died while this worker was starting
        os._exit(1)
    threading.Thread(
        target=_watch, args=(parent_pid, poll_seconds), name="end-with-parent", daemon=True
    ).start()
