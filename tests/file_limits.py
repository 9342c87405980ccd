"""File systems that refuse: a full disk, a read-only mount, another user's folder.

``RLIMIT_FSIZE`` makes the kernel refuse writes past a size (``EFBIG``), the
way a full disk refuses them (``ENOSPC``): short writes, then errors, at any
point of a file. It needs no privileges and no mount. ``SIGXFSZ``, which
would otherwise kill the process, is ignored (the setting survives ``exec``).
Read-only folders are simulated (:func:`refuse_writes`): the tests run as
root too, whom ``chmod`` does not stop, and cannot mount.
"""

import errno
import os
import resource
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest


def run_with_file_limit(
    argv: list[str], limit: int, cwd: Path | None = None
) -> "subprocess.CompletedProcess[str]":
    """``python -m lenspair ARGV`` with files limited to ``limit`` bytes; output captured."""

    def _limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run(
        [sys.executable, "-m", "lenspair", *argv],
        env={**os.environ, "LENSPAIR_QUIET": "1"},
        capture_output=True,
        text=True,
        preexec_fn=_limit,
        cwd=cwd,
        check=False,
        timeout=600,
    )


REFUSALS = [errno.EROFS, errno.EACCES]
"""A read-only file system, and a folder of another user."""


def refuse_writes(monkeypatch: pytest.MonkeyPatch, folder: Path, code: int) -> None:
    """Make ``folder`` and what is below it refuse new files and folders, raising ``code``.

    As a read-only mount (``EROFS``) or another user's folder (``EACCES``)
    does: the tests run as root too, whom ``chmod`` does not stop, and cannot
    mount. ``os.open`` with ``O_CREAT`` (``mkstemp``) and ``os.mkdir``
    (``mkdtemp``, ``Path.mkdir``) raise as the kernel would, naming the path.
    """
    real_open, real_mkdir = os.open, os.mkdir

    def refused(path: Any) -> bool:
        return Path(os.path.abspath(os.fsdecode(path))).parent.is_relative_to(folder)

    def open_(path: Any, flags: int, mode: int = 0o777, *, dir_fd: int | None = None) -> int:
        if flags & os.O_CREAT and refused(path):
            raise OSError(code, os.strerror(code), os.fsdecode(path))
        return real_open(path, flags, mode, dir_fd=dir_fd)

    def mkdir_(path: Any, mode: int = 0o777, *, dir_fd: int | None = None) -> None:
        if refused(path):
            raise OSError(code, os.strerror(code), os.fsdecode(path))
        real_mkdir(path, mode, dir_fd=dir_fd)

    monkeypatch.setattr(os, "open", open_)
    monkeypatch.setattr(os, "mkdir", mkdir_)


@contextmanager
def file_size_limit(limit: int) -> Iterator[None]:
    """Files of this process limited to ``limit`` bytes (``EFBIG``, as a full disk refuses)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, handler)
