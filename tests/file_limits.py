"""Run a command as on a full disk: writes past ``limit`` bytes in one file fail.

``RLIMIT_FSIZE`` makes the kernel refuse such writes (``EFBIG``), the way a
full disk refuses them (``ENOSPC``): short writes, then errors, at any point
of a file. It needs no privileges and no mount. ``SIGXFSZ``, which would
otherwise kill the process, is ignored (the setting survives ``exec``).
"""

import os
import resource
import signal
import subprocess
import sys
from pathlib import Path


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
