"""``lenspair detect`` output: per-frame CSV/JSON and a contact sheet with the maps.

For each frame of the input (:func:`lenspair.capture.frames.iter_frames`) one row:
``name, camera, t_ns, probability, kind, obstructed, obstructed_share, blank,
p_clean, p_rain, p_dust, p_dirt, error`` (``blank``: a nearly uniform frame,
see :mod:`lenspair.model.detection.judge`). A frame that cannot be read gets its
``error`` filled and empty figures: it is recorded, not fatal. The contact
sheet shows up to ``sheet_frames`` frames spread over the input, each
labelled with kind and probability; on frames called obstructed, the tiles
called covered (map > 0.5, those counted in ``obstructed_share``) are tinted
red. Frames stream through in batches: memory holds one batch and the few
sheet candidates (:class:`SpreadSample`), never the whole input. All files
are written atomically.
"""

import csv
import io
import logging
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Generic, TypeVar

import cv2
import numpy as np

from lenspair.capture.frame_types import InputFrame
from lenspair.capture.frames import DETECT_OUTPUT
from lenspair.capture.recording_types import FrameProblem
from lenspair.capture.rosbag import never_stamped
from lenspair.core.bitdepth import RunningDepth, widen
from lenspair.core.contact_sheet import make_contact_sheet, to_display
from lenspair.core.fsutil import atomic_write_texts, json_text
from lenspair.core.imagewrite import write_image
from lenspair.core.progress import progress
from lenspair.model.detection.judge import Judgement, judge, size_problem
from lenspair.model.networks.detector import KINDS, AnomalyDetector

log = logging.getLogger(__name__)

FIELDS = (
    "name",
    "camera",
    "t_ns",
    "probability",
    "kind",
    "obstructed",
    "obstructed_share",
    "blank",
    *(f"p_{kind}" for kind in KINDS),
    "error",
)


@dataclass(frozen=True)
class FrameVerdict:
    """One frame's row (figures None when the frame could not be read)."""

    name: str
    camera: str | None
    t_ns: int | None
    probability: float | None
    kind: str | None
    obstructed: bool | None
    obstructed_share: float | None
    kind_probabilities: tuple[float, ...] | None
    blank: bool | None = None
    error: str | None = None

    def row(self) -> dict[str, object]:
        """The CSV row (``FIELDS``)."""
        probabilities = self.kind_probabilities or (None,) * len(KINDS)
        values: dict[str, object] = {
            key: value for key, value in asdict(self).items() if key in FIELDS
        }
        values.update({f"p_{k}": p for k, p in zip(KINDS, probabilities, strict=True)})
        return {key: "" if values.get(key) is None else values[key] for key in FIELDS}


def overlay(image: np.ndarray, tile_map: np.ndarray) -> np.ndarray:
    """``uint8`` RGB display of ``image`` with the tiles of ``tile_map`` above 0.5 tinted red."""
    shown = to_display(image).astype(np.float32)
    height, width = shown.shape[:2]
    alpha = cv2.resize(
        tile_map.astype(np.float32), (width, height), interpolation=cv2.INTER_NEAREST
    )
    alpha = 0.5 * (alpha > 0.5).astype(np.float32)[:, :, None]
    red = np.array([255.0, 0.0, 0.0], np.float32)
    blended: np.ndarray = np.rint(shown * (1.0 - alpha) + red * alpha).astype(np.uint8)
    return blended


T = TypeVar("T")


class SpreadSample(Generic[T]):
    """Up to ``size`` items spread evenly over a stream whose length is unknown.

    Keeps every ``stride``-th item (by index); when more than ``2 * size`` are
    kept the stride doubles and every other one is dropped, so memory stays
    at ``2 * size`` items and the kept ones still span the stream.
    """

    def __init__(self, size: int) -> None:
        """``size``: how many items :meth:`picks` returns at most (>= 0)."""
        self.size = size
        self.stride = 1
        self.kept: list[tuple[int, T]] = []

    def wants(self, index: int) -> bool:
        """Whether the item at ``index`` would be kept (to skip building it)."""
        return self.size > 0 and index % self.stride == 0

    def add(self, index: int, item: T) -> None:
        """Offer the item at ``index`` (indices increasing); kept when :meth:`wants` it."""
        if not self.wants(index):
            return
        self.kept.append((index, item))
        if len(self.kept) > 2 * self.size:
            self.stride *= 2
            self.kept = [(i, kept) for i, kept in self.kept if i % self.stride == 0]

    def picks(self) -> list[T]:
        """At most ``size`` of the kept items, evenly spread, first one included."""
        count = min(self.size, len(self.kept))
        spread = np.linspace(0, len(self.kept) - 1, count).round().astype(int).tolist()
        return [self.kept[i][1] for i in sorted(set(spread))]


def sheet_cell(image: np.ndarray, tile_map: np.ndarray, width: int = 480) -> np.ndarray:
    """The overlay of ``image`` shrunk to at most ``width`` pixels wide (the sheet shows less).

    The frame is shrunk first and the overlay drawn on that: drawn at full
    size, its float copies took about 35 bytes a pixel, and one 30000x30000
    frame in a folder ended ``detect`` killed for memory, no verdict written.
    """
    if image.shape[1] > width:
        height = max(1, round(image.shape[0] * width / image.shape[1]))
        image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    return overlay(image, tile_map)


def _verdicts(frames: Sequence[InputFrame], verdict: Judgement) -> list[FrameVerdict]:
    rows = []
    for index, frame in enumerate(frames):
        rows.append(
            FrameVerdict(
                frame.name,
                frame.camera,
                frame.t_ns,
                round(float(verdict.probability[index]), 4),
                verdict.kinds[index],
                bool(verdict.obstructed[index]),
                round(float(verdict.obstructed_share[index]), 4),
                tuple(round(float(p), 4) for p in verdict.kind_probabilities[index]),
                bool(verdict.blank[index]),
            )
        )
    return rows


def _timed_by_log(
    verdicts: list[FrameVerdict], log_times: Sequence[int | None]
) -> list[FrameVerdict]:
    """Bag frames timed by the log time where a camera's header stamps are all one value.

    As ``capture-ingest`` does (:func:`lenspair.capture.rosbag.read_bag`): a
    driver that never sets ``header.stamp`` gave every row one ``t_ns``. Both
    cameras then take the log time, and the log says so.
    """
    stamps: dict[str | None, list[int]] = {}
    for verdict, log_time in zip(verdicts, log_times, strict=True):
        if log_time is not None and verdict.t_ns is not None:
            stamps.setdefault(verdict.camera, []).append(verdict.t_ns)
    unset = never_stamped(stamps)
    if not unset:
        return verdicts
    log.warning(
        "every header.stamp of %s is one value: never set by the driver? t_ns is the bag's "
        "log time instead",
        ", ".join(f"{camera} ({stamps[camera][0]} ns)" for camera in unset),
    )
    return [
        replace(verdict, t_ns=log_time) if log_time is not None else verdict
        for verdict, log_time in zip(verdicts, log_times, strict=True)
    ]


def _relative(source: str, root: Path | None) -> str:
    """``source`` (a file, or ``data.csv:LINE``) relative to ``root`` when it lies in it."""
    if root is None:
        return source
    prefix = f"{Path(root)}/"
    return source[len(prefix) :] if source.startswith(prefix) else source


def detect_frames(
    network: AnomalyDetector,
    frames: Iterable[InputFrame],
    out: Path,
    batch_size: int = 8,
    sheet_frames: int = 12,
    threshold: float = 0.5,
    total: int | None = None,
    dropped: Sequence[FrameProblem] = (),
    root: Path | None = None,
) -> list[FrameVerdict]:
    """Judge every frame; write ``out/detections.csv``, ``.json`` and ``contact_sheet.png``.

    Args:
        network: the detector.
        frames: decoded frames in input order
            (:func:`lenspair.capture.frames.iter_frames`); read once, lazily.
        out: output folder (created).
        batch_size: frames per network call.
        sheet_frames: frames on the contact sheet (0: no sheet).
        threshold: obstructed above this probability.
        total: the number of frames when known, for the progress bar only.
        dropped: a recording's images its listing left out or could not find
            (:func:`lenspair.capture.frames.iter_frames`): a row each, not
            judged, with the reason, after the others (read once ``frames`` is
            exhausted: the listing fills it).
        root: the input they were listed from: their rows are named relative
            to it, as the judged frames' are.

    Returns:
        One :class:`FrameVerdict` per frame, in input order, then the dropped ones.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    verdicts: list[FrameVerdict] = []
    candidates: SpreadSample[tuple[np.ndarray, str]] = SpreadSample(sheet_frames)
    batch: list[InputFrame] = []
    depth = RunningDepth(str(root) if root is not None else "the input")

    def flush(bits: int | None = None) -> None:
        """Judge the batch at ``bits`` (default: the depth now)."""
        if not batch:
            return
        # 16-bit frames of 10- or 12-bit values are judged (and shown) on the full scale
        bits = depth.bits if bits is None else bits
        images = [widen(frame.image, bits) for frame in batch if frame.image is not None]
        result = judge(network, images, batch_size, threshold, bits=16)  # widened above
        rows = _verdicts(batch, result)
        for position, (frame, row) in enumerate(zip(batch, rows, strict=True)):
            verdicts.append(row)
            if candidates.wants(frame.index):
                label = f"{frame.name}: {row.kind} p={row.probability:.2f}"
                tile_map = result.maps[position] if row.obstructed else 0.0 * result.maps[position]
                candidates.add(frame.index, (sheet_cell(images[position], tile_map), label))
        batch.clear()

    log_times: list[int | None] = []  # per verdict, in order
    for frame in progress(frames, desc="detect", total=total, unit="frame"):
        log_times.append(frame.log_time_ns)
        image = frame.image
        error = (frame.error or "unreadable") if image is None else size_problem(image)
        if image is None or error is not None:
            flush()
            log.warning("%s: %s", frame.name, error)
            failed = FrameVerdict(
                frame.name, frame.camera, frame.t_ns, None, None, None, None, None, error=error
            )
            verdicts.append(failed)
            continue
        if (before := depth.rise(image)) is not None and batch:
            flush(before)  # the frames batched so far, at the depth they were seen at
        batch.append(frame)
        if len(batch) == batch_size:
            flush()
    flush()
    verdicts = _timed_by_log(verdicts, log_times)
    for problem in dropped:
        verdicts.append(
            FrameVerdict(
                _relative(problem.source, root), problem.camera, problem.t_ns, None, None, None,
                None, None, error=problem.reason,
            )
        )  # fmt: skip
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=FIELDS)
    writer.writeheader()
    writer.writerows(v.row() for v in verdicts)
    # an earlier run's sheet must not pass for this run's; the tables are written together
    (out / "contact_sheet.png").unlink(missing_ok=True)
    atomic_write_texts(
        {
            out / DETECT_OUTPUT: buffer.getvalue(),
            out / "detections.json": json_text([asdict(v) for v in verdicts]),
        }
    )
    shown = candidates.picks()
    if shown:
        columns = 4
        cells = [cell for cell, _ in shown]
        labels = [label for _, label in shown]
        rows = [cells[i : i + columns] for i in range(0, len(cells), columns)]
        label_rows = [labels[i : i + columns] for i in range(0, len(labels), columns)]
        sheet = make_contact_sheet(rows, label_rows, title="detector: red = covered tiles")
        write_image(out / "contact_sheet.png", sheet)  # atomic, as every write_image
    return verdicts
