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
from pathlib import Path

from lenspair.core.fsutil import naming_errors

log = logging.getLogger(__name__)


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
        if exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.EINVAL):
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
