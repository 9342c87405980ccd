"""``lenspair detect`` output: per-frame CSV/JSON and a contact sheet with the maps.

For each frame of the input (:mod:`lenspair.capture.frame_source`) one row:
``name, camera, t_ns, probability, kind, obstructed, obstructed_share, blank,
p_clean, p_rain, p_dust, p_dirt, error`` (``blank``: a nearly uniform frame,
see :mod:`lenspair.model.detection.judge`). A frame that cannot be read gets its
``error`` filled and empty figures: it is recorded, not fatal. The contact
sheet shows up to ``sheet_frames`` frames spread over the input, each
labelled with kind and probability; on frames called obstructed, the tiles
called covered (map > 0.5, those counted in ``obstructed_share``) are tinted
red. All files are written atomically.
"""

import csv
import io
import logging
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from lenspair.capture.frame_source import InputFrame
from lenspair.core.contact_sheet import make_contact_sheet, to_display
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import atomic_write_json, atomic_write_text
from lenspair.core.imageio import write_image
from lenspair.core.progress import progress
from lenspair.model.detection.judge import Judgement, judge
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


def detect_frames(
    network: AnomalyDetector,
    frames: Iterable[InputFrame],
    out: Path,
    batch_size: int = 8,
    sheet_frames: int = 12,
    threshold: float = 0.5,
) -> list[FrameVerdict]:
    """Judge every frame; write ``out/detections.csv``, ``.json`` and ``contact_sheet.png``.

    Returns:
        One :class:`FrameVerdict` per frame, in input order.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    verdicts: list[FrameVerdict] = []
    shown: list[tuple[np.ndarray, np.ndarray, str]] = []
    listed = list(frames)
    picks = np.linspace(0, max(0, len(listed) - 1), min(sheet_frames, len(listed)))
    sheet_picks = set(picks.round().astype(int).tolist())
    batch: list[tuple[int, InputFrame, np.ndarray]] = []

    def flush() -> None:
        if not batch:
            return
        result = judge(network, [image for _, _, image in batch], batch_size, threshold)
        rows = _verdicts([frame for _, frame, _ in batch], result)
        for position, ((index, frame, image), row) in enumerate(zip(batch, rows, strict=True)):
            verdicts.append(row)
            if index in sheet_picks:
                label = f"{frame.name}: {row.kind} p={row.probability:.2f}"
                tile_map = result.maps[position] if row.obstructed else 0.0 * result.maps[position]
                shown.append((image, tile_map, label))
        batch.clear()

    for index, frame in enumerate(progress(listed, desc="detect", total=len(listed), unit="frame")):
        try:
            image = frame.load()
        except LenspairError as exc:
            flush()
            log.warning("%s: %s", frame.name, exc)
            failed = FrameVerdict(
                frame.name, frame.camera, frame.t_ns, None, None, None, None, None, None, str(exc)
            )
            verdicts.append(failed)
            continue
        batch.append((index, frame, image))
        if len(batch) == batch_size:
            flush()
    flush()
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=FIELDS)
    writer.writeheader()
    writer.writerows(v.row() for v in verdicts)
    atomic_write_text(out / "detections.csv", buffer.getvalue())
    atomic_write_json(out / "detections.json", [asdict(v) for v in verdicts])
    if shown:
        columns = 4
        cells = [overlay(image, tile_map) for image, tile_map, _ in shown]
        labels = [label for _, _, label in shown]
        rows = [cells[i : i + columns] for i in range(0, len(cells), columns)]
        label_rows = [labels[i : i + columns] for i in range(0, len(labels), columns)]
        sheet = make_contact_sheet(rows, label_rows, title="detector: red = covered tiles")
        write_image(out / "contact_sheet.png", sheet)  # atomic, as every write_image
    return verdicts
