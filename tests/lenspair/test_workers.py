"""Spawned pools start their workers deaf to Ctrl-C and end them when the block fails."""

import os
import signal
import time

import pytest

from lenspair.core.workers import spawn_pool
from tests.processes import wait_gone


def _nothing() -> None:
    """An initializer that leaves the signal handlers as the worker was born with them."""


def _sigint_blocked(_: int) -> bool:
    return signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])


def _pid_then_wait(index: int) -> int:
    if index >= 2:
        time.sleep(30)  # still at work when the block fails
    return os.getpid()


def test_workers_are_born_ignoring_ctrl_c() -> None:
    """A worker still importing when Ctrl-C reached the process group printed its own
    KeyboardInterrupt traceback: the initializer that ignores it had not run yet."""
    before = signal.getsignal(signal.SIGINT)
    with spawn_pool(2, _nothing) as pool_map:
        blocked = set(pool_map(_sigint_blocked, range(4)))
    assert blocked == {True}
    # the parent still answers Ctrl-C, as before
    assert signal.getsignal(signal.SIGINT) is before
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])


def test_ctrl_c_while_workers_start_is_answered_once_they_all_are_known() -> None:
    """Acted on at once, it left a worker half started, reading a pipe its parent closed."""
    from lenspair.core.workers import _starting_workers

    reached_end = False
    with pytest.raises(KeyboardInterrupt), _starting_workers():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)  # delivered meanwhile, and held
        reached_end = True
    assert reached_end


def test_a_signal_held_while_workers_start_wins_over_the_error_it_caused() -> None:
    """A worker that took the group's SIGTERM broke the pool while its parent still
    started the next: "a worker process ended" (exit 2) instead of "terminated" (143)."""
    from lenspair.core.workers import _starting_workers

    with pytest.raises(KeyboardInterrupt), _starting_workers():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)  # held
        raise RuntimeError("the pool is broken")  # what the next worker's start met


def test_a_failing_block_ends_its_workers_before_it_leaves() -> None:
    """A parent leaving on SIGTERM while its workers read their start-up data cut the pipe
    ("pickle data was truncated" from each); now the workers are ended first."""
    pids: list[int] = []
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt), spawn_pool(2, _nothing) as pool_map:
        for pid in pool_map(_pid_then_wait, range(6)):
            pids.append(pid)
            if len(pids) == 2:
                raise KeyboardInterrupt
    assert time.monotonic() - started < 25  # not after the workers' sleep
    assert len(pids) == 2 and not wait_gone(set(pids), 0.0)


_GROUP_SIGTERM = """
import multiprocessing.util as util, os, signal, sys
from lenspair.core.errors import WorkerDiedError
from lenspair.core.workers import spawn_pool
from tests.lenspair.test_workers import _keep, _square

spawn = util.spawnv_passfds

def spawn_then_terminate(*args):  # SIGTERM reaches the worker before it reads its data
    pid = spawn(*args)
    os.kill(pid, signal.SIGTERM)
    return pid

util.spawnv_passfds = spawn_then_terminate
try:
    with spawn_pool(1, _keep, (b"x" * 8_000_000,)) as pool_map:
        print(list(pool_map(_square, range(3))))
except WorkerDiedError as exc:
    print("died:", exc)
"""


def _keep(data: bytes) -> None:
    """An initializer whose start-up data is more than a pipe holds."""
    assert len(data) == 8_000_000


def _square(value: int) -> int:
    return value * value


def test_sigterm_before_a_worker_reads_its_start_up_data_does_not_hang_its_parent() -> None:
    """timeout or systemd signal the whole group: a worker killed while its parent still
    wrote its start-up data (a few MB for capture-ingest) left the parent writing forever."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, "-c", _GROUP_SIGTERM], cwd=root, capture_output=True, text=True,
        timeout=120, env={**os.environ, "PYTHONPATH": str(root)},
    )  # fmt: skip
    # the worker read its data, then took the SIGTERM: the pool says so in one line
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("died: a worker process ended while at work"), done.stdout
    assert "Traceback" not in done.stderr


def test_a_worker_killed_at_work_is_one_error_not_a_broken_pool() -> None:
    from lenspair.core.errors import WorkerDiedError

    killed: list[int] = []
    with pytest.raises(WorkerDiedError, match="out of memory"), spawn_pool(1, _nothing) as pool_map:
        for pid in pool_map(_pid_then_wait, range(50)):
            if not killed:
                os.kill(pid, signal.SIGKILL)  # as the out-of-memory killer does
                killed.append(pid)


def test_workers_take_sigterm_once_started() -> None:
    # blocked from birth until the start-up data is read, not for good: terminate() works
    with spawn_pool(1, _nothing) as pool_map:
        blocked = list(pool_map(_blocked_signals, range(1)))
    assert blocked == [(True, False)]


def _blocked_signals(_: int) -> tuple[bool, bool]:
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    return signal.SIGINT in mask, signal.SIGTERM in mask
