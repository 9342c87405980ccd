"""The figures of an ingest's ``report.json``: counts, rejection reasons, output homography.

Helpers of :func:`lenspair.capture.ingest.ingest_recording` that summarise a finished
run for :class:`lenspair.capture.ingested.IngestReport`, and write the report so that
a rerun which changed nothing but the timings leaves the file untouched.
"""

import json
import os
import re
from collections import Counter
from pathlib import Path

import numpy as np

from lenspair.capture.ingested import PAIRS_FILE, REPORT_FILE, IngestReport, PairRecord
from lenspair.capture.pairing import PairingResult
from lenspair.capture.recording import CAMERAS, FrameProblem, Recording
from lenspair.capture.rigfile import CameraName, RigFile
from lenspair.core.config import to_plain
from lenspair.core.fsutil import atomic_write_json


def _category(reason: str) -> str:
    """The stable part of a reason, for counting: text before the first ':' or ' ('."""
    return re.split(r":| \(", reason, maxsplit=1)[0].strip()


def _has_record(problem: FrameProblem, obstructed: CameraName | None) -> bool:
    """Whether a dropped frame gets its own rejected line in ``pairs.jsonl``.

    Every dropped obstructed frame with a timestamp does (a row that lists the
    very file and timestamp of an earlier row is not dropped but one frame:
    :func:`lenspair.capture.recording_types.order_frames`); one without a
    timestamp is named in ``report.json`` instead (:func:`untimed_frames`).
    """
    if obstructed is None or not problem.dropped or problem.camera != obstructed:
        return False
    return problem.t_ns is not None


def _untimed(problem: FrameProblem, obstructed: CameraName) -> bool:
    """Whether a dropped obstructed frame has no timestamp, so no line in ``pairs.jsonl``."""
    return problem.dropped and problem.camera == obstructed and problem.t_ns is None


def untimed_frames(recording: Recording, obstructed: CameraName) -> list[str]:
    """What ``report.json`` says of each obstructed frame that could not be timed.

    ``pairs.jsonl`` names a frame by its timestamp: a frame without one (a
    ``data.csv`` row whose time does not parse, a ``left/``/``right/`` file
    without a time in its name) can have no line there. It is named in the
    report's ``recording_problems`` instead, with its file and reason, and
    counted as rejected (:func:`frame_counts`), so that every obstructed frame
    is accounted for.
    """
    return [
        f"{obstructed} frame without a timestamp, in no line of {PAIRS_FILE}: {problem}"
        for problem in recording.problems
        if _untimed(problem, obstructed)
    ]


def camera_problems(recording: Recording, obstructed: CameraName) -> list[str]:
    """Each camera's problems for ``report.json``, but the obstructed camera's dropped frames.

    The log says the first few of a recording's problems; the report keeps
    them all. The obstructed camera's dropped frames have their own lines
    (:func:`unlisted_records`) or are named as untimed (:func:`untimed_frames`);
    the rest are listed here: the clean camera's frames its listing left
    out, and problems that leave no frame out (a timestamp that goes back).
    """
    return [
        str(problem)
        for problem in recording.problems
        if problem.camera is not None
        and not _has_record(problem, obstructed)
        and not _untimed(problem, obstructed)
    ]


def unlisted_records(recording: Recording, obstructed: CameraName) -> list[PairRecord]:
    """Rejected records of the obstructed frames the recording could not list.

    ``pairs.jsonl`` holds one line per obstructed frame: a frame whose
    timestamp repeats an earlier frame's (a different file), or whose file is
    missing, gets a rejected line whose reason names its source.
    """
    return [
        PairRecord(t_ns=p.t_ns, status="rejected", reason=f"{p.reason} ({p.source})")
        for p in recording.problems
        if _has_record(p, obstructed) and p.t_ns is not None  # (said for the type checker)
    ]


def rejection_reasons(
    recording: Recording, records: list[PairRecord], obstructed: CameraName | None = None
) -> Counter[str]:
    """How many frames were rejected or dropped, by the stable part of the reason.

    Args:
        recording: the recording (its dropped frames are counted as
            ``"<camera> not listed: <category>"``, except those of the
            ``obstructed`` camera that have a record, counted once by it).
        records: the run's records, kept and rejected.
        obstructed: the obstructed camera.

    Returns:
        Count per reason category (the text before the first ``:`` or ``" ("``).

    A problem of the whole recording (a bag cut short: "reading stopped
    early") is no frame: it is said on its own, in the log and the report's
    ``recording_problems``, not counted here, so that the printed
    rejections add up to the frames rejected.
    """
    reasons = Counter(_category(r.reason) for r in records if r.status == "rejected" and r.reason)
    for problem in recording.problems:
        if problem.camera is None:
            continue
        if problem.dropped and not _has_record(problem, obstructed):
            reasons[f"{problem.camera} not listed: {_category(problem.reason)}"] += 1
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
        ``rejected``, ``rejected_paired``, ``rejected_unlisted`` (dropped
        obstructed frames with their own line), ``rejected_untimed`` (dropped
        obstructed frames without a timestamp, so without a line:
        :func:`untimed_frames`), ``masked``, ``recording_problems``.
        ``kept + rejected`` is ``frames_<obstructed>``: every obstructed frame.

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
    untimed = sum(1 for p in recording.problems if _untimed(p, rig_file.obstructed))
    counts["rejected"] = sum(1 for r in records if r.status == "rejected") + untimed
    unlisted = sum(1 for p in recording.problems if _has_record(p, rig_file.obstructed))
    counts["rejected_unlisted"] = unlisted
    counts["rejected_untimed"] = untimed
    counts["rejected_paired"] = (
        counts["rejected"] - counts[f"unpaired_{rig_file.obstructed}"] - unlisted - untimed
    )
    counts["masked"] = sum(1 for r in records if r.status == "kept" and "mask" in r.files)
    counts["recording_problems"] = sum(1 for p in recording.problems if p.camera is None)
    return counts


STALE_REPORT = ".report.json.stale"
"""``report.json`` while a run rewrites ``pairs.jsonl`` (:func:`set_report_aside`)."""


def set_report_aside(out_dir: Path) -> None:
    """Move ``report.json`` aside before a run rewrites the recording's pairs.

    ``pairs.jsonl`` is written before ``report.json``: a run killed between
    the two (say, re-ingesting with the other side declared) left the new
    pairs beside the old report, and dataset-build paired the frames the
    wrong way round. Aside, the old report is not there to be misread; the
    run's end puts it back when nothing but timings changed
    (:func:`write_report_if_changed`), so an unchanged rerun keeps its bytes.
    """
    path = out_dir / REPORT_FILE
    if path.is_file():
        os.replace(path, out_dir / STALE_REPORT)


def write_report_if_changed(path: Path, report: IngestReport) -> None:
    """Write ``report.json`` unless the one before (or set aside) differs only in timings."""
    plain = to_plain(report)
    stale = path.with_name(STALE_REPORT)
    before = path if path.is_file() else stale
    if before.is_file():
        try:
            old = json.loads(before.read_text(encoding="utf-8"))
            if {**old, "timings_s": None} == {**json.loads(json.dumps(plain)), "timings_s": None}:
                if before == stale:
                    os.replace(stale, path)
                return
        except (ValueError, UnicodeDecodeError):
            pass
    atomic_write_json(path, plain)
    stale.unlink(missing_ok=True)
