"""``manifest.jsonl``: one row per pair of a built dataset.

Rows are written in split order (train, val, test), then by name, as compact
JSON with sorted keys; floats are rounded so that the bytes are stable.
Reading is strict: an unknown or missing key or a wrong type is reported with
the file and line (a hand-edited manifest is caught, not trusted).
"""

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, TypeVar

from lenspair.core.config import load_dataclass, text_lines, to_plain
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import atomic_write_lines
from lenspair.dataset.config import Difficulty
from lenspair.dataset.errors import DatasetError

_Line = TypeVar("_Line")

MANIFEST_FILE = "manifest.jsonl"
REMOVED_FILE = "removed.jsonl"
SplitName = Literal["train", "val", "test"]
IMAGE_KINDS: tuple[str, str, str] = ("input", "target", "mask")
"""Sub-folders of a split, in the order they are listed."""


@dataclass(frozen=True)
class ManifestRow:
    """One pair of the dataset.

    Attributes:
        split: ``train``, ``val`` or ``test``.
        name: file stem shared by ``input/``, ``target/`` (and ``mask/``):
            ``<recording>_<t_ns>``.
        recording: recording id (``report.json``'s ``recording_id``).
        group: split group (the recording, or ``<recording>#s<k>`` segment).
        t_ns: obstructed frame timestamp (ns).
        t_clean_ns: clean frame timestamp (ns), when ingest recorded it.
        obstructed: camera behind the anomaly (``cam0``/``cam1``); the input side.
        clean: the ground-truth camera; the target side.
        anomaly: anomaly labels of the recording (``rig.yaml``), e.g. ``["rain"]``.
        difficulty: ``easy``/``medium``/``hard`` from the input-vs-target
            PSNR, or ``clean`` when the views barely differ.
        psnr_db: input-vs-target PSNR over trustworthy pixels (dB).
        anomaly_fraction: fraction of pixels where the views differ.
        residual_px: registration residual from ingest (px), if measured.
        photometric_residual: photometric residual from ingest, if measured.
        inliers: homography inliers from ingest, if measured.
        sharpness: variance of the Laplacian of the clean view (8-bit scale).
        saturated: fraction of clean-view pixels at full scale.
        black: fraction of clean-view pixels at zero.
        mask_fraction: fraction of untrustworthy pixels.
        files: ``input``/``target``/``mask`` -> path relative to the dataset root.
        sha256: checksums of those files, same keys.
    """

    split: SplitName
    name: str
    recording: str
    group: str
    t_ns: int
    obstructed: str
    clean: str
    difficulty: Difficulty
    psnr_db: float
    anomaly_fraction: float
    sharpness: float
    saturated: float
    black: float
    mask_fraction: float
    anomaly: tuple[str, ...] = ()
    t_clean_ns: int | None = None
    residual_px: float | None = None
    photometric_residual: float | None = None
    inliers: int | None = None
    files: dict[str, str] = field(default_factory=dict)
    sha256: dict[str, str] = field(default_factory=dict)

    @property
    def anomaly_label(self) -> str:
        """The anomaly labels joined by ``+`` (``none`` when empty), for counting."""
        return "+".join(self.anomaly) if self.anomaly else "none"


@dataclass(frozen=True)
class RemovedPair:
    """One line of ``removed.jsonl``: a pair curation removed, and why.

    Attributes:
        recording: recording id.
        t_ns: obstructed frame timestamp (ns).
        rule: the curation rule (see :data:`lenspair.dataset.curation.RULES`).
        reason: the details (figure and threshold, or the file and its problem).
    """

    recording: str
    t_ns: int
    rule: str
    reason: str


def write_removed(path: Path, removed: list[RemovedPair]) -> None:
    """Write ``removed.jsonl`` atomically, sorted by recording and timestamp."""
    ordered = sorted(removed, key=lambda r: (r.recording, r.t_ns))
    atomic_write_lines(Path(path), (row_to_json(r) for r in ordered))


def row_to_json(row: ManifestRow | RemovedPair) -> str:
    """One compact, key-sorted JSON line (floats rounded to 6 significant digits)."""
    return json.dumps(_round(to_plain(row)), sort_keys=True, separators=(",", ":"))


def write_manifest(path: Path, rows: list[ManifestRow]) -> None:
    """Write ``manifest.jsonl`` atomically."""
    atomic_write_lines(Path(path), (row_to_json(row) for row in rows))


def read_manifest(path: Path) -> list[ManifestRow]:
    """Read ``manifest.jsonl`` strictly.

    Raises:
        DatasetError: the file is missing, or a line is not valid JSON or not
            a valid row; the message names the file and the line.
    """
    return _read_lines(Path(path), ManifestRow, "file not found (not a lenspair dataset?)")


def read_removed(path: Path) -> list[RemovedPair]:
    """Read ``removed.jsonl`` strictly, as :func:`read_manifest` reads the manifest.

    Raises:
        DatasetError: the file is missing, or a line is not a removed pair;
            the message names the file and the line.
    """
    missing = "missing (every build writes it: each pair curation removed, and why)"
    return _read_lines(Path(path), RemovedPair, missing)


def _read_lines(path: Path, kind: type[_Line], missing: str) -> list[_Line]:
    """One ``kind`` per line of a JSON-lines file; a problem names the file and the line."""
    try:
        lines = text_lines(path)
    except FileNotFoundError:
        raise DatasetError(f"{path}: {missing}") from None
    except ConfigError as exc:  # not UTF-8: names the line
        raise DatasetError(str(exc)) from None
    found = []
    for number, line in lines:
        try:
            found.append(load_dataclass(kind, json.loads(line)))
        except (json.JSONDecodeError, ConfigError) as exc:
            raise DatasetError(f"{path}:{number}: {exc}") from None
    return found


def _round(value: object) -> object:
    if isinstance(value, float):
        return float(f"{value:.6g}")
    if isinstance(value, dict):
        return {k: _round(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_round(v) for v in value]
    return value
