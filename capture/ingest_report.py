"""The figures of an ingest's ``report.json``: counts, rejection reasons, output homography.

Helpers of :func:`lenspair.capture.ingest.ingest_recording` that summarise a finished
run for :class:`lenspair.capture.ingested.IngestReport`, and write the report so that
a rerun which changed nothing but the timings leaves the file untouched.
"""

import json
import re
from collections import Counter
from pathlib import Path

import numpy as np

from lenspair.capture.ingested import IngestReport, PairRecord
from lenspair.capture.pairing import PairingResult
from lenspair.capture.recording import CAMERAS, Recording
from lenspair.capture.rigfile import RigFile
from lenspair.core.config import to_plain
from lenspair.core.fsutil import atomic_write_json


def _category(reason: str) -> str:
    """The stable part of a reason, for counting: text before the first ':' or ' ('."""
    return re.split(r":| \(", reason, maxsplit=1)[0].strip()


def rejection_reasons(recording: Recording, records: list[PairRecord]) -> Counter[str]:
    """How many frames were rejected or dropped, by the stable part of the reason.

    Args:
        recording: the recording (its dropped problems are counted as
            ``"<camera or 'recording'> not listed: <category>"``).
        records: the run's records, kept and rejected.

    Returns:
        Count per reason category (the text before the first ``:`` or ``" ("``).

    """
    reasons = Counter(_category(r.reason) for r in records if r.status == "rejected" and r.reason)
    for problem in recording.problems:
        if problem.dropped:
            reasons[f"{problem.camera or 'recording'} not listed: {_category(problem.reason)}"] += 1
    return reasons


def in_output_pixels(matrix: np.ndarray, x0: int, y0: int) -> np.ndarray:
    """The rectified-pixel homography in cropped output pixels (both views cropped alike).

    Args:
        matrix: 3x3 clean -> obstructed homography in rectified pixels.
        x0: left edge of the crop, rectified pixels.
        y0: top edge of the crop, rectified pixels.

    Returns:
        3x3 float64 homography in output pixels, normalised so ``[2, 2] == 1``.

    """
    shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    out = shift @ matrix @ np.linalg.inv(shift)
    return np.asarray(out / out[2, 2])


def frame_counts(
    recording: Recording, pairing: PairingResult, rig_file: RigFile, records: list[PairRecord]
) -> dict[str, int]:
    """Frame bookkeeping; every frame of both cameras is in exactly one bucket.

    Args:
        recording: the recording (listed frames and problems).
        pairing: the timestamp pairing of the two cameras.
        rig_file: the rig description (which camera is obstructed).
        records: one record per obstructed frame, kept or rejected.

    Returns:
        Counts keyed ``frames_<camera>``, ``listed_<camera>``,
        ``dropped_<camera>``, ``unpaired_<camera>``, ``pairs``, ``kept``,
        ``rejected``, ``rejected_paired``, ``masked``, ``recording_problems``.

    """
    counts: dict[str, int] = {}
    for camera in CAMERAS:
        listed = len(recording.frames[camera])
        dropped = sum(1 for p in recording.problems if p.dropped and p.camera == camera)
        counts[f"frames_{camera}"] = listed + dropped
        counts[f"listed_{camera}"] = listed
        counts[f"dropped_{camera}"] = dropped
        counts[f"unpaired_{camera}"] = len(pairing.unpaired_of(camera))
    counts["pairs"] = len(pairing.pairs)
    counts["kept"] = sum(1 for r in records if r.status == "kept")
    counts["rejected"] = sum(1 for r in records if r.status == "rejected")
    counts["rejected_paired"] = counts["rejected"] - counts[f"unpaired_{rig_file.obstructed}"]
    counts["masked"] = sum(1 for r in records if r.status == "kept" and "mask" in r.files)
    counts["recording_problems"] = sum(1 for p in recording.problems if p.camera is None)
    return counts


def write_report_if_changed(path: Path, report: IngestReport) -> None:
    """Write ``report.json`` unless the existing one differs only in its timings."""
    plain = to_plain(report)
    if path.is_file():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
            if {**old, "timings_s": None} == {**json.loads(json.dumps(plain)), "timings_s": None}:
                return
        except ValueError:
            pass
    atomic_write_json(path, plain)
