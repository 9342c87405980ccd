"""The detector's sample pool: results in order, workers tied to their parent."""

import threading

from lenspair.model.detection.parallel import process_map


def _threads(_: int) -> list[str]:
    return sorted(thread.name for thread in threading.enumerate())


def _square(value: int) -> int:
    return value * value


def test_results_come_in_order_whatever_the_worker_count() -> None:
    items = list(range(7))
    expected = [i * i for i in items]
    assert process_map(_square, items, 1) == process_map(_square, items, 2) == expected


def test_pool_workers_end_with_their_parent() -> None:
    # the watchdog thread of lenspair.core.orphans.end_with_parent runs in every worker
    for names in process_map(_threads, [0, 1], 2):
        assert "end-with-parent" in names
