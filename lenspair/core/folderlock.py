"""One writer per output folder: a non-blocking ``flock`` on a file in it.

``capture-ingest`` locks its output, ``train`` its run folder: two processes
writing one folder at once removed or overwrote each other's files. The
kernel releases an ``flock`` when its holder dies, however it dies (``kill
-9`` too), so a killed run never blocks its rerun and there is no stale lock
to remove; the file stays (removing it while another process waits to open
it would let two processes hold two files).
"""

import errno
import fcntl
import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from lenspair.core.fsutil import naming_errors

log = logging.getLogger(__name__)

_NO_LOCKS = (errno.ENOLCK, errno.EOPNOTSUPP, errno.EINVAL)
"""``flock``'s errors on a file system without locks (some NFS and FUSE mounts)."""


def lock_file(path: Path, writer: str) -> int | None:
    """Open ``path`` and lock it, not waiting: its descriptor, or None when another holds it.

    Closing the descriptor releases the lock. On a file system without locks
    the descriptor is returned all the same, with a warning that nothing
    stops a second ``writer`` (``capture-ingest``, ``train``) from writing
    the folder at the same time.

    Raises:
        OSError: the lock file cannot be created (a read-only folder), naming it.
    """
    with naming_errors(path):
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(descriptor)
        return None
    except OSError as exc:
        if exc.errno not in _NO_LOCKS:
            os.close(descriptor)
            raise
        log.warning(
            "%s: cannot be locked (%s): nothing stops a second %s from writing it at the same "
            "time; run one at a time",
            path.parent,
            exc.strerror or exc,
            writer,
        )
    return descriptor


@contextmanager
def holding(path: Path, writer: str, taken: Exception) -> Iterator[None]:
    """Hold :func:`lock_file`'s lock of ``path`` meanwhile; raise ``taken`` when another holds it.

    Raises:
        Exception: ``taken`` (the writer's one-line refusal), when the lock is held.
        OSError: the lock file cannot be created (a read-only folder), naming it.
    """
    descriptor = lock_file(path, writer)
    if descriptor is None:
        raise taken
    try:
        yield
    finally:
        os.close(descriptor)  # releases the lock


def lock_shared(path: Path, create: bool = False) -> int | None:
    """Take a shared lock on a lock file, not waiting, for a reader of the folder.

    Readers share it; a writer's exclusive :func:`lock_file` is refused while
    one holds it, and it is refused while a writer holds the exclusive one.
    With ``create``, a missing lock file is made (a writer that comes later
    must find the readers' lock); one that cannot be made (a read-only
    folder, which nothing rewrites) gives None.

    Returns:
        The descriptor (closing it releases the lock); None when there is no
        lock file (no writer has ever locked the folder) and ``create`` is off
        or it cannot be made, or the file system has no locks.

    Raises:
        BlockingIOError: a writer holds the lock.
        OSError: the lock file exists but cannot be opened, naming it.
    """
    flags = os.O_RDONLY | os.O_CLOEXEC | (os.O_CREAT if create else 0)
    try:
        with naming_errors(path):
            descriptor = os.open(path, flags, 0o666)
    except FileNotFoundError:
        return None
    except OSError as exc:
        if create and exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            return None  # nothing rewrites a folder this process may not even add a file to
        raise
    try:
        fcntl.flock(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(descriptor)
        if isinstance(exc, BlockingIOError) or exc.errno not in _NO_LOCKS:
            raise
        return None
    return descriptor
