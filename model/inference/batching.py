"""The middle stage of restore: frames batched, run through the network, handed on in order.

:func:`run_batches` takes the reader thread's items, refuses a network whose
channels the first frames do not have, records failed and skipped frames,
and batches the others (:class:`_Batches`): frames ``k*B .. k*B+B-1`` of the
same size and dtype form a batch, so a frame is always computed in the same
batch and ``--resume`` writes the same bytes as an uninterrupted run. Every
item goes to the writer thread (:class:`~lenspair.model.inference.threads.Writer`)
in input order, with restored pixels or None (copied unchanged).
"""

import itertools
import logging
import os
from collections.abc import Iterator
from typing import Any

import numpy as np
from tqdm import tqdm

from lenspair.capture.frame_types import InputFrame
from lenspair.core.bitdepth import RunningDepth, widen
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import Backend
from lenspair.model.inference.input_checks import frame_problem, image_channels
from lenspair.model.inference.judge import FrameJudge
from lenspair.model.inference.restore_options import RestoreOptions
from lenspair.model.inference.resume import FrameDepths
from lenspair.model.inference.threads import Writer
from lenspair.model.inference.tiling import restore_images

log = logging.getLogger(__name__)


class _Batches:
    """The batch being filled and the items waiting on it, handed to ``writer`` on a flush.

    Args:
        backend: the network.
        options: batch size and tiling.
        writer: takes every item, in input order; its report is counted here.
    """

    def __init__(self, backend: Backend, options: RestoreOptions, writer: Writer) -> None:
        self.backend = backend
        self.options = options
        self.writer = writer
        self.report = writer.report
        self.pending: list[tuple[Any, InputFrame | None, int | None]] = []  # item, frame, slot
        self.batch: list[InputFrame] = []
        self.depth = RunningDepth(writer.report.input)
        self.depths = FrameDepths(writer.sink.state_dir)

    def pass_on(self, item: Any, frame: InputFrame | None) -> None:
        """Queue ``item`` to be copied unchanged, after the frames batched before it."""
        self.pending.append((item, frame, None))

    def add(self, item: Any, frame: InputFrame) -> None:
        """Batch ``frame``; a batch is run when full or when ``frame`` cannot join it."""
        if self.batch and _batch_key(self.batch[0], self.options) != _batch_key(
            frame, self.options
        ):
            self.flush()
        self.batch.append(frame)
        self.pending.append((item, frame, len(self.batch) - 1))
        if len(self.batch) == self.options.batch_size:
            self.flush()

    def flush(self, bits: int | None = None) -> None:
        """Restore the batch at ``bits`` (default: the depth now) and hand on the pending items."""
        outputs: list[np.ndarray | None] = [None] * len(self.batch)
        # 16-bit frames of 10- or 12-bit values are restored on the full scale, then
        # written back in the camera's words (lenspair.core.bitdepth)
        bits = self.depth.bits if bits is None else bits
        done = [
            self.writer.sink.done(frame) and self.depths.same(frame, bits) for frame in self.batch
        ]
        failure = None
        if self.batch and not all(done):  # the whole batch: same batches as an uninterrupted run
            images = [frame.image for frame in self.batch if frame.image is not None]
            self.depths.record(self.batch, bits)
            try:
                outputs[:] = restore_images(
                    self.backend, images, bits, self.options.tile, self.options.overlap
                )
            except ModelError as exc:  # a frame too large for memory: its batch fails, not the run
                failure = str(exc)
        self._hand_on(done, outputs, failure)
        self.pending.clear()
        self.batch.clear()

    def _hand_on(
        self, done: list[bool], outputs: list[np.ndarray | None], failure: str | None
    ) -> None:
        """Give the pending items to the writer, counting each frame in the report."""
        report, writer = self.report, self.writer
        for item, frame, slot in self.pending:
            if slot is None:
                writer.put(item, frame, None)
            elif done[slot]:  # written by an earlier run; a bag takes it from the cache
                report.resumed += 1
                cached = writer.sink.cached(self.batch[slot])
                if cached is not None:
                    writer.put(item, frame, cached)
            elif failure is not None:  # copied unchanged and listed; --resume tries it again
                assert frame is not None
                report.failed += 1
                report.problems.append({"frame": frame.name, "reason": failure})
                writer.put(item, frame, None)
            else:
                report.restored += 1
                writer.put(item, frame, outputs[slot])


def run_batches(
    items: Iterator[Any],
    backend: Backend,
    options: RestoreOptions,
    judge: FrameJudge | None,
    writer: Writer,
    total: int | None,
) -> str | None:
    """Batch frames and run the network; hands everything to ``writer`` in order.

    Args:
        items: the input's frames (:class:`~lenspair.capture.frame_types.InputFrame`)
            or bag messages, in order.
        backend: the network.
        options: batch size and tiling.
        judge: when given, frames it calls clean are copied unchanged.
        writer: takes every item; its report is counted here.
        total: frames expected, for the progress bar (None: unknown).

    Returns:
        None; or, when none of the first :data:`REFUSE_AFTER` readable frames
        has the network's channels, why (the first's reason), with nothing
        handed to ``writer``: the run is refused (:func:`_settle_channels`).
        A frame that does not match is otherwise a failed frame. A refusal is
        returned, not raised, so that no other error (a judge's) is taken for one.
    """
    items, refused = _settle_channels(items, backend.channels)
    if refused is not None:
        return refused
    report = writer.report
    bar = tqdm(total=total, desc="restoring", unit="frame", leave=False, disable=_quiet())
    batches = _Batches(backend, options, writer)
    for item in items:
        frame: InputFrame | None = item if isinstance(item, InputFrame) else item.frame
        if frame is None:
            batches.pass_on(item, None)
            continue
        report.frames_read += 1
        bar.update(1)
        image = frame.image
        reason = frame.error
        if image is not None:
            reason = frame_problem(str(frame.source), image, backend.channels) or reason
        if image is None or reason is not None:
            report.failed += 1
            report.problems.append({"frame": frame.name, "reason": reason or "unreadable"})
            batches.pass_on(item, frame)
            continue
        # every readable frame, finished ones too: a resume decides alike; the frames
        # batched so far are restored at the depth they were seen at, as one by one
        if (before := batches.depth.rise(image)) is not None and batches.batch:
            batches.flush(before)
        if judge is not None and not judge(frame, widen(image, batches.depth.bits)):
            report.skipped += 1
            report.skipped_frames.append(frame.name)
            batches.pass_on(item, frame)
            continue
        batches.add(item, frame)
    batches.flush()
    bar.close()
    if batches.depths.redone:
        log.warning(
            "%d finished 16-bit frame(s) restored again: frames added or removed before them "
            "changed the bit depth they are taken at (lenspair.core.bitdepth.RunningDepth)",
            batches.depths.redone,
        )
    return None


REFUSE_AFTER = 3
"""Readable frames in a row, from the first, whose channels are not the network's that refuse
the run: the wrong network for the input, most likely. Fewer are failed frames once a frame
that matches comes (a stray thumbnail named first in a folder stopped the whole run)."""


def _settle_channels(items: Iterator[Any], channels: int) -> tuple[Iterator[Any], str | None]:
    """Read ahead until a frame has ``channels`` or :data:`REFUSE_AFTER` frames in a row do not.

    Returns:
        The items, those read ahead first, in order; and None, or why the run
        is refused (the first frame's reason) when no readable frame matched.
    """
    ahead: list[Any] = []
    refusal: str | None = None
    mismatched = 0
    for item in items:
        ahead.append(item)
        frame = item if isinstance(item, InputFrame) else item.frame
        if frame is None or frame.image is None:
            continue
        if image_channels(frame.image) == channels:
            return itertools.chain(ahead, items), None
        refusal = refusal or frame_problem(str(frame.source), frame.image, channels)
        mismatched += 1
        if mismatched == REFUSE_AFTER:
            break
    return iter(ahead), refusal


def _batch_key(frame: InputFrame, options: RestoreOptions) -> tuple[Any, ...]:
    """What frames of one batch share: batch number (aligned to frame index), shape, dtype."""
    assert frame.image is not None
    return (frame.index // options.batch_size, frame.image.shape, frame.image.dtype)


def _quiet() -> bool:
    """Whether ``LENSPAIR_QUIET=1`` asks for no progress bar."""
    return os.environ.get("LENSPAIR_QUIET", "") == "1"
