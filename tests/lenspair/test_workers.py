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
