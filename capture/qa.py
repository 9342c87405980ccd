"""``qa.png``: a contact sheet for people to check an ingested recording at a glance.

One row per sampled kept frame (spread over the recording): the obstructed
input, the registered clean target, their absolute difference (grey,
amplified 4x: edges that show up in it everywhere mean misregistration,
blobs are the anomalies) and the trust mask (white = not trustworthy).
"""

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lenspair.capture.ingested import PairRecord
from lenspair.core.contact_sheet import make_contact_sheet
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.core.pixels import to_float

QA_FILE = "qa.png"
DIFFERENCE_GAIN = 4.0


def _grey(image: np.ndarray) -> np.ndarray:
    values = to_float(image)
    return values.mean(axis=2) if values.ndim == 3 else values


def qa_rows(out_dir: Path, records: Sequence[PairRecord], max_rows: int = 4) -> list[PairRecord]:
    """Up to ``max_rows`` kept records spread evenly over ``records``."""
    kept = [r for r in records if r.status == "kept"]
    if len(kept) <= max_rows:
        return kept
    picks = sorted({round(i * (len(kept) - 1) / (max_rows - 1)) for i in range(max_rows)})
    return [kept[i] for i in picks]


def make_qa_sheet(out_dir: Path, records: Sequence[PairRecord], max_rows: int = 4) -> np.ndarray:
    """Build the sheet from the files an ingest wrote.

    Args:
        out_dir: ``OUT/<recording_id>``.
        records: the recording's records (kept ones are sampled).
        max_rows: frames shown.

    Returns:
        ``uint8`` RGB ``(H, W, 3)`` image.

    Raises:
        ValueError: no kept record.

    """
    rows, labels = [], []
    for record in qa_rows(out_dir, records, max_rows):
        image_in = read_image(out_dir / record.files["input"])
        image_target = read_image(out_dir / record.files["target"])
        difference = np.clip(
            np.abs(_grey(image_in) - _grey(image_target)) * DIFFERENCE_GAIN, 0.0, 1.0
        ).astype(np.float32)
        mask = (
            read_image(out_dir / record.files["mask"])
            if "mask" in record.files
            else np.zeros(image_in.shape[:2], np.uint8)
        )
        rows.append([image_in, image_target, difference, mask > 0])
        residual = "n/a" if record.residual_px is None else f"{record.residual_px:.2f} px"
        masked = 100 * (record.mask_fraction or 0.0)
        labels.append(
            [
                f"input {record.t_ns}",
                "target (clean, registered)",
                f"|input - target| x{DIFFERENCE_GAIN:g}, residual {residual}",
                f"mask {masked:.1f}%",
            ]
        )
    if not rows:
        raise ValueError("qa sheet: no kept pair to show")
    title = f"{out_dir.name}: {sum(r.status == 'kept' for r in records)} kept of {len(records)}"
    return make_contact_sheet(rows, labels, title=title, cell_width=270)


def write_qa_sheet(path: Path, out_dir: Path, records: Sequence[PairRecord]) -> None:
    """Write :func:`make_qa_sheet` to ``path`` (atomically, deterministic bytes)."""
    write_image(path, make_qa_sheet(out_dir, records))
