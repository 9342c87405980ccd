"""A warm process that forks one ``lenspair`` command per request, for the fault tests.

Each ``python -m lenspair`` spends seconds importing (torch, OpenCV) before it
does any work, and the fault tests start dozens of runs to kill. This server
imports once and forks a child per request; the child is a process of its own
that runs ``lenspair.cli.main(argv)`` as ``python -m lenspair ARGV`` would
(stdout to ``/dev/null``, stderr to a file), then exits with its code. The
tests kill the child with ``SIGKILL`` like any other process.

    python -P tests/fork_server.py    # start_server(env), from the fault tests

Protocol, one line each: a request is JSON ``{"argv": [...], "stderr": path}``;
the server answers the child's pid at once, then its exit code (negative: the
signal that ended it) once it has ended. The server itself never runs a torch
operation and is started with ``OMP_NUM_THREADS=1``, so no thread pool exists
to be forked half-way. :class:`ForkedRun` is the tests' side of it.
"""

import atexit
import contextlib
import importlib
import json
import os
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

# What the tested commands import inside their ``run``: loaded once, here.
WARM = (
    "lenspair.cli",
    "lenspair.commands.capture_ingest",
    "lenspair.commands.dataset_build",
    "lenspair.commands.train",
    "lenspair.commands.restore",
    "lenspair.capture.ingest",
    "lenspair.core.device",
    "lenspair.model.training.config",
    "lenspair.model.training.config_loading",
    "lenspair.model.training.datasets",
    "lenspair.model.training.distributed",
    "lenspair.model.training.loop",
    "lenspair.model.training.pretrained",
    "lenspair.model.inference.backends",
    "lenspair.model.inference.judge",
    "lenspair.model.inference.pipeline",
)


def serve() -> None:
    """Answer requests from stdin until it closes."""
    for name in WARM:
        importlib.import_module(name)
    for line in sys.stdin:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            _child(request["argv"], request["stderr"])
        print(pid, flush=True)
        _, status = os.waitpid(pid, 0)
        print(os.waitstatus_to_exitcode(status), flush=True)


def _child(argv: list[str], stderr: str) -> None:
    """Run one command in the forked child; never returns."""
    code = 1
    try:
        sys.stdin.close()
        os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
        os.dup2(os.open(stderr, os.O_WRONLY | os.O_CREAT | os.O_TRUNC), 2)
        code = sys.modules["lenspair.cli"].main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:  # reported like an uncaught error of python -m lenspair
        traceback.print_exc()
    finally:
        atexit._run_exitfuncs()  # what interpreter exit would run
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


class ForkedRun:
    """A command running in a child of the fork server (the test side of the protocol)."""

    def __init__(self, server: subprocess.Popen[str], argv: list[str], stderr: Path) -> None:
        assert server.stdin is not None and server.stdout is not None
        server.stdin.write(json.dumps({"argv": argv, "stderr": str(stderr)}) + "\n")
        server.stdin.flush()
        self.server = server
        self.pid = int(server.stdout.readline())
        self.stderr = stderr
        self.returncode: int | None = None

    def poll(self) -> int | None:
        """The exit code once the child has ended (a zombie counts as ended), else None."""
        if self.returncode is None and not running(self.pid):
            assert self.server.stdout is not None
            self.returncode = int(self.server.stdout.readline())
        return self.returncode

    def kill(self) -> None:
        """``SIGKILL`` the child (unless it has ended) and wait for the server to reap it."""
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):  # it ended meanwhile
                os.kill(self.pid, signal.SIGKILL)
        while self.poll() is None:
            time.sleep(0.001)


def running(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie has ended)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def start_server(env: dict[str, str]) -> "subprocess.Popen[str]":
    """Start the server (text pipes on stdin and stdout) with ``env``."""
    return subprocess.Popen(
        # -P: this file's folder (tests/, holding tests/lenspair/) stays off sys.path
        [sys.executable, "-P", str(Path(__file__))],
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )


if __name__ == "__main__":
    serve()
