"""The ingested-recording format: the contract between ``capture-ingest`` and ``dataset-build``.

Layout of ``OUT/<recording_id>/``::

    input/<t_ns>.png    obstructed view, rectified and cropped (540x360), model input
    target/<t_ns>.png   clean view registered onto the input (same size, dtype)
    mask/<t_ns>.png     optional; 255 where the pair is NOT trustworthy (parallax,
                        failed alignment), 0 elsewhere; uint8
    pairs.jsonl         one PairRecord per input frame of the obstructed camera,
                        kept or rejected, in timestamp order
    report.json         IngestReport: counts, calibration, homography, timings
    qa.png              contact sheet for people

``<t_ns>`` is the obstructed frame's timestamp in nanoseconds.
"""

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from lenspair.core.config import load_dataclass, read_json, text_lines, to_plain
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import atomic_write_json, atomic_write_lines

PAIRS_FILE = "pairs.jsonl"
REPORT_FILE = "report.json"
Status = Literal["kept", "rejected"]


@dataclass(frozen=True)
class PairRecord:
    """One line of ``pairs.jsonl``: the fate of one obstructed frame.

    Attributes:
        t_ns: obstructed frame timestamp (ns); the output file stem.
        t_clean_ns: timestamp of the clean frame it was paired with, if any.
        status: ``kept`` or ``rejected``.
        reason: why it was rejected (or a warning for a kept pair), else None.
        residual_px: geometric registration residual (px), when measured.
        photometric_residual: mean absolute difference of input and target
            outside anomaly regions, in [0, 1] units of full scale.
        inliers: feature matches supporting the homography in this frame.
        sharpness: variance of the Laplacian of the clean view (motion blur).
        saturated: fraction of clean-view pixels at full scale.
        black: fraction of clean-view pixels at zero.
        mask_fraction: fraction of pixels marked untrustworthy in ``mask/``.
        exposure_ratio: median ratio of the target's grey levels to the
            input's over trusted, unclipped pixels
            (:func:`lenspair.core.quality.exposure_ratio`): 1 when the cameras
            expose alike; a veil or brightened drops move it too.
        files: relative paths of ``input``, ``target`` and ``mask`` outputs.
        sha256: checksums of those files, same keys.
    """

    t_ns: int
    status: Status
    t_clean_ns: int | None = None
    reason: str | None = None
    residual_px: float | None = None
    photometric_residual: float | None = None
    inliers: int | None = None
    sharpness: float | None = None
    saturated: float | None = None
    black: float | None = None
    mask_fraction: float | None = None
    exposure_ratio: float | None = None
    files: dict[str, str] = field(default_factory=dict)
    sha256: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class ExposureSummary:
    """How alike the two cameras exposed: the kept pairs' ``exposure_ratio``.

    Attributes:
        median: the median ratio of target to input grey levels.
        low: its 10th percentile over the pairs.
        high: its 90th percentile.
        pairs: how many kept pairs had a ratio.
    """

    median: float
    low: float
    high: float
    pairs: int


@dataclass(frozen=True)
class IngestReport:
    """``report.json``: what an ingest run did.

    Attributes:
        recording_id: folder name under ``OUT``.
        source: path of the recording that was read.
        obstructed: camera behind the anomaly (``cam0``/``cam1``).
        anomaly: anomaly labels from ``rig.yaml``.
        calibration_source: file the calibration came from.
        calibration: the calibration used (Kalibr camchain mapping).
        homography: 3x3 clean->obstructed homography in cropped output pixels.
        crop: ``(x, y, width, height)`` of the crop in rectified pixels.
        counts: frame counts (``frames_cam0``, ``kept``, ``rejected``, ...).
        rejection_reasons: reason -> count.
        timings_s: stage -> seconds.
        side_check: result of checking the declared obstructed side, as the
            check's record (``capture.side_check.SideCheck`` or
            ``capture.side_detector.DetectorSideCheck``) plus
            ``blank_pairs_left_out``. dataset-build reads ``mismatch`` (bool),
            ``message`` (one line), ``method`` (``detail`` or ``detector``) and
            ``confidence`` (``[0, 1]``): a record without the first two, or with
            another method, is refused on reading (:func:`side_check_problem`),
            so that a misspelt key never reads as "no mismatch". Empty: not
            checked (reports of before the check).
        lenspair_version: version that wrote it.
        significant_bits: 10 or 12 when both cameras' 16-bit frames held
            values of that depth (scaled to 16 bits in the outputs), else None
            (cameras of different depths too: see the next field).
        significant_bits_per_camera: ``cam0``/``cam1`` -> the bits that
            camera's 16-bit frames held (10 or 12: scaled to 16 bits in the
            outputs; 16: taken as they are, as are 8-bit frames); each
            camera's frames are scaled by their own. Empty in reports of
            before it was written.
        topics: bags only: ``cam0``/``cam1`` -> the topic read as that camera
            (the calibration's ``rostopic`` order where it states one); empty
            for folders, and in reports of before it was written.
        recording_problems: what was said of the recording as a whole (a bag
            cut short, header stamps never set, clocks that seem to disagree),
            and each obstructed frame without a timestamp, which no line of
            ``pairs.jsonl`` can name (``counts["rejected_untimed"]``):
            ``counts`` has their number.
        camera_problems: each camera's problems but the obstructed camera's
            frames left out (those have their own ``pairs.jsonl`` lines, or
            are in ``recording_problems`` when untimed): the clean camera's
            frames its listing left out (also counted by category in
            ``rejection_reasons``) and problems that leave no frame out (a
            timestamp that goes back; an obstructed frame's is on its
            ``pairs.jsonl`` line too); ``counts`` has their number. Empty in
            reports of before it was written.
        time_offset_ns: cam1's clock ahead of cam0's, taken off cam1's stamps
            for pairing (``--time-offset``; 0: none).
        exposure: the kept pairs' ``exposure_ratio`` over the recording
            (:mod:`lenspair.capture.exposure`); None without one (reports of
            before it was written, or no pair with enough unclipped pixels).
    """

    recording_id: str
    source: str
    obstructed: str
    anomaly: tuple[str, ...]
    calibration_source: str
    calibration: dict[str, Any]
    homography: list[list[float]]
    crop: tuple[int, int, int, int]
    counts: dict[str, int]
    rejection_reasons: dict[str, int] = field(default_factory=dict)
    timings_s: dict[str, float] = field(default_factory=dict)
    side_check: dict[str, Any] = field(default_factory=dict)
    lenspair_version: str = ""
    significant_bits: int | None = None
    significant_bits_per_camera: dict[str, int] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)
    recording_problems: list[str] = field(default_factory=list)
    camera_problems: list[str] = field(default_factory=list)
    time_offset_ns: int = 0
    exposure: ExposureSummary | None = None

    def __post_init__(self) -> None:
        """Refuse a ``side_check`` dataset-build could misread (see the attribute)."""
        problem = side_check_problem(self.side_check)
        if problem:
            raise ValueError(f"side_check: {problem}")


SIDE_CHECK_METHODS = ("detail", "detector")
"""The side checks capture-ingest runs: the fine-detail ratio and the trained detector."""


def side_check_problem(check: dict[str, Any]) -> str | None:
    """Why ``report.json``'s ``side_check`` cannot be read as a check, or None."""
    if not check:
        return None
    if not isinstance(check.get("mismatch"), bool):
        return f"expected 'mismatch' true or false, got {check.get('mismatch')!r}"
    if not isinstance(check.get("message"), str):
        return f"expected 'message' as text, got {check.get('message')!r}"
    method = check.get("method", "detail")
    if method not in SIDE_CHECK_METHODS:
        return f"expected 'method' one of {', '.join(SIDE_CHECK_METHODS)}, got {method!r}"
    confidence = check.get("confidence")
    if confidence is not None and not (
        isinstance(confidence, int | float)
        and not isinstance(confidence, bool)
        and 0.0 <= confidence <= 1.0
    ):
        return f"expected 'confidence' in [0, 1], got {confidence!r}"
    return None


def write_pairs(path: Path, records: list[PairRecord]) -> None:
    """Write ``pairs.jsonl`` atomically, one compact JSON object per line."""
    lines = (json.dumps(to_plain(r), sort_keys=True, separators=(",", ":")) for r in records)
    atomic_write_lines(Path(path), lines)


def read_pairs(path: Path) -> list[PairRecord]:
    """Read ``pairs.jsonl``; a malformed line raises ``ConfigError`` naming file and line."""
    return [record for _, record in read_numbered_pairs(path)]


def read_numbered_pairs(path: Path) -> list[tuple[int, PairRecord]]:
    """``(line number, record)`` of each line of ``pairs.jsonl`` (:func:`read_pairs`)."""
    path = Path(path)
    records = []
    for number, line in text_lines(path):
        try:
            records.append((number, load_dataclass(PairRecord, json.loads(line))))
        except (json.JSONDecodeError, ConfigError) as exc:
            raise ConfigError(f"{path}:{number}: {exc}") from None
    return records


def write_report(path: Path, report: IngestReport) -> None:
    """Write ``report.json`` atomically."""
    atomic_write_json(Path(path), to_plain(report))


def read_report(path: Path) -> IngestReport:
    """Read ``report.json``; errors name the file."""
    path = Path(path)
    try:
        data = read_json(path)  # its errors name the file
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    try:
        return load_dataclass(IngestReport, data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
