"""The reader and writer threads of ``restore``: decode ahead, write behind, in order.

The network runs in the calling thread; decoding (PNG, bag messages) and
encoding/writing overlap with it. Queues are bounded so memory stays flat.
A per-frame encoding error (:class:`~lenspair.capture.errors.CaptureError`,
:class:`~lenspair.core.errors.ImageIOError`: a format that cannot hold the
frame, ``ValueError``) turns that frame into a failed one (copied unchanged); an
original that cannot even be read to copy it is recorded and left out; any
other writer error (disk full, permissions on OUT) ends the run.
"""

import queue
import threading
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from lenspair.capture.errors import CaptureError
from lenspair.capture.frame_types import InputFrame
from lenspair.core.errors import ImageIOError

if TYPE_CHECKING:
    from lenspair.model.inference.bag_sink import BagSink
    from lenspair.model.inference.file_sink import FileSink
    from lenspair.model.inference.report import RestoreReport

_END = object()


def threaded(items: Iterator[Any], size: int) -> Iterator[Any]:
    """Iterate ``items`` in a reader thread, at most ``size`` ahead (errors re-raised here).

    When the consumer stops early (an error, ``close()``), the reader is told
    to stop and joined, so the input's files and bag readers are closed.
    """
    buffer: queue.Queue[Any] = queue.Queue(maxsize=size)
    failure: list[BaseException] = []
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                while not stop.is_set():
                    try:
                        buffer.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    break
        except BaseException as exc:  # handed to the consumer, raised there
            failure.append(exc)
        finally:
            close = getattr(items, "close", None)
            if close is not None:
                close()  # runs the generator's cleanup (closes bag readers) in this thread
            while not stop.is_set():
                try:
                    buffer.put(_END, timeout=0.1)
                    break
                except queue.Full:
                    continue

    thread = threading.Thread(target=produce, name="restore-reader", daemon=True)
    thread.start()
    try:
        while (item := buffer.get()) is not _END:
            yield item
    finally:
        stop.set()
        thread.join()
    if failure:
        raise failure[0]


class Writer:
    """The writer thread: writes ``(item, pixels | None)`` in order, records failures.

    A restored frame that cannot be written (its original is copied instead)
    is counted into the report by :meth:`close`, in the caller's thread: the
    report's counters are the caller's alone, never updated from two threads.
    """

    def __init__(self, sink: "FileSink | BagSink", report: "RestoreReport", size: int) -> None:
        self.sink, self.report = sink, report
        self.queue: queue.Queue[Any] = queue.Queue(maxsize=size)
        self.failure: list[BaseException] = []
        self.problems: list[dict[str, str]] = []  # found in the writer thread
        self.unwritten = 0  # restored frames whose original was written instead
        self.thread = threading.Thread(target=self._run, name="restore-writer", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            self._drain()
        finally:
            try:
                self.sink.close()  # in this thread: bag storage handles are thread-bound
            except BaseException as exc:  # raised by close()
                self.failure.append(exc)

    def _drain(self) -> None:
        while (entry := self.queue.get()) is not _END:
            if self.failure:
                continue  # drain after an error; the caller raises it
            item, frame, pixels = entry
            try:
                try:
                    self.sink.write(item, pixels)
                except (CaptureError, ImageIOError, ValueError) as exc:  # this frame only
                    if frame is None:
                        raise
                    self.problems.append({"frame": frame.name, "reason": str(exc)})
                    if pixels is None:  # not even the original could be copied: said above
                        continue
                    self.unwritten += 1
                    self.sink.write(item, None)
            except BaseException as exc:  # disk full, permissions: fatal, raised by close()
                self.failure.append(exc)

    def put(self, item: Any, frame: InputFrame | None, pixels: np.ndarray | None) -> None:
        """Queue one item for writing (raises the writer's error, if any)."""
        if self.failure:
            raise self.failure[0]
        self.queue.put((item, frame, pixels))

    def close(self) -> None:
        """Finish writing, close the sink, count unwritten frames; raises the writer's error."""
        self.queue.put(_END)
        self.thread.join()
        earlier = {p["frame"]: p for p in self.report.problems}
        for problem in self.problems:
            said = earlier.get(problem["frame"])
            if said is None:
                self.report.problems.append(problem)
            else:  # a frame that could not be read could not be copied either: one entry
                copied = "not copied to OUT"
                said["reason"] += (
                    f"; {copied}"
                    if problem["reason"].endswith(copied)
                    else (f"; {problem['reason']}")
                )
        self.report.restored -= self.unwritten
        self.report.failed += self.unwritten
        if self.failure:
            raise self.failure[0]
