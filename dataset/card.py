"""``dataset.json``: the dataset card.

It says what is in the dataset and how it was made: counts per split, side
(ground-truth camera), anomaly and difficulty, the balance of sides per
anomaly, the curation rules with how many pairs each removed, the resolved
thresholds and split settings (seed included), and the sources with their
calibration and the lenspair version that ingested them. Every count can be
recomputed from ``manifest.jsonl`` (see :func:`count_rows`), which is what
``dataset-build --verify`` checks.
"""

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from lenspair import __version__
from lenspair.core.config import load_dataclass, read_json, to_plain
from lenspair.core.contact_sheet import make_contact_sheet
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import atomic_write_json
from lenspair.core.imageio import read_image
from lenspair.dataset.config import DIFFICULTIES, SPLITS, DatasetConfig
from lenspair.dataset.curation import RULES
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import ManifestRow

CARD_FILE = "dataset.json"
CARD_FORMAT = "lenspair-dataset/1"
SIDES: tuple[str, str] = ("cam0", "cam1")
CONTACT_PAIRS = 8


@dataclass(frozen=True)
class Counts:
    """Counts of one split (or of all splits together).

    Attributes:
        pairs: number of pairs.
        recordings: distinct recordings contributing pairs.
        groups: distinct split groups (recordings or segments).
        clean_side: ground-truth (clean, target) camera -> pairs.
        anomaly: anomaly label (``+``-joined) -> pairs.
        difficulty: ``easy``/``medium``/``hard``/``clean`` -> pairs.
        clean_side_by_anomaly: anomaly label -> ground-truth camera -> pairs.
    """

    pairs: int
    recordings: int
    groups: int
    clean_side: dict[str, int]
    anomaly: dict[str, int]
    difficulty: dict[str, int]
    clean_side_by_anomaly: dict[str, dict[str, int]]


@dataclass(frozen=True)
class RuleCount:
    """One curation rule and how many pairs it removed."""

    rule: str
    description: str
    removed: int


@dataclass(frozen=True)
class SourceInfo:
    """One ingested recording that went into the dataset.

    Attributes:
        recording: recording id.
        path: the ingested folder (absolute).
        obstructed: camera behind the anomaly; ``clean`` is the ground truth.
        clean: ground-truth camera.
        anomaly: anomaly labels.
        calibration_source: the calibration file ingest used.
        ingest_version: lenspair version that ingested it.
        pairs: lines in ``pairs.jsonl``.
        kept_at_ingest: lines with status ``kept``.
        in_dataset: split -> pairs that made it into the dataset.
    """

    recording: str
    path: str
    obstructed: str
    clean: str
    anomaly: tuple[str, ...]
    calibration_source: str
    ingest_version: str
    pairs: int
    kept_at_ingest: int
    in_dataset: dict[str, int]


@dataclass(frozen=True)
class Grouping:
    """How pairs were grouped for splitting (see :mod:`lenspair.dataset.splits`).

    Attributes:
        mode: ``recording`` or ``segment``.
        moved_by_side_fixup: groups moved to give every split both sides.
        warnings: strata with too few groups to cover every split.
    """

    mode: str
    moved_by_side_fixup: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class DatasetCard:
    """Contents of ``dataset.json``.

    Attributes:
        format: card format tag.
        lenspair_version: version that built the dataset.
        seed: split seed.
        fractions: requested train/val/test fractions (of groups).
        counts: ``train``/``val``/``test``/``all`` -> counts.
        curation: rules in the order applied, with removed counts.
        pairs_in: lines of ``pairs.jsonl`` over all sources.
        tagged_clean: pairs kept with difficulty ``clean``.
        ingest_reasons: frames rejected or left unlisted at ingest, by the stable
            part of the reason (the sources' ``report.json`` ``rejection_reasons``,
            summed) -> count.
        grouping: how groups were formed and assigned.
        config: the resolved configuration (thresholds, split settings).
        sources: the ingested recordings.
        image_files: ``"copy"``: the images are independent of the ingested
            ones (reflinked or copied); ``"hard-link"``: they are the ingested
            files themselves, made read-only (an edit would change the
            recording and every dataset built from it).
        image_files_note: that choice in words, for a reader of the card.
    """

    lenspair_version: str
    seed: int
    fractions: tuple[float, float, float]
    counts: dict[str, Counts]
    curation: tuple[RuleCount, ...]
    pairs_in: int
    tagged_clean: int
    grouping: Grouping
    config: DatasetConfig
    sources: tuple[SourceInfo, ...]
    ingest_reasons: dict[str, int] = field(default_factory=dict)
    image_files: Literal["copy", "hard-link"] = "copy"
    image_files_note: str = ""
    format: str = CARD_FORMAT


IMAGE_FILES_NOTES = {
    "copy": "images are independent copies of the ingested files (reflinked where the "
    "file system supports it, else copied): editing one changes nothing else",
    "hard-link": "images are hard links to the ingested files and read-only: they are the "
    "same files as the ingested recording's (rebuild without --link hard to edit them)",
}


def count_rows(rows: Iterable[ManifestRow]) -> dict[str, Counts]:
    """Counts per split and over ``all``, recomputed from manifest rows."""
    rows = list(rows)
    selections = {name: [r for r in rows if r.split == name] for name in SPLITS}
    selections["all"] = rows
    return {name: _counts(selected) for name, selected in selections.items()}


def _counts(rows: list[ManifestRow]) -> Counts:
    side = dict.fromkeys(SIDES, 0)
    difficulty: dict[str, int] = dict.fromkeys(DIFFICULTIES, 0)
    anomaly: dict[str, int] = {}
    by_anomaly: dict[str, dict[str, int]] = {}
    for row in rows:
        side[row.clean] = side.get(row.clean, 0) + 1
        difficulty[row.difficulty] += 1
        label = row.anomaly_label
        anomaly[label] = anomaly.get(label, 0) + 1
        sides = by_anomaly.setdefault(label, dict.fromkeys(SIDES, 0))
        sides[row.clean] = sides.get(row.clean, 0) + 1
    return Counts(
        pairs=len(rows),
        recordings=len({r.recording for r in rows}),
        groups=len({r.group for r in rows}),
        clean_side=side,
        anomaly=anomaly,
        difficulty=difficulty,
        clean_side_by_anomaly=by_anomaly,
    )


def write_card(path: Path, card: DatasetCard) -> None:
    """Write ``dataset.json`` atomically (sorted keys, stable bytes)."""
    atomic_write_json(Path(path), to_plain(card))


def read_card(path: Path) -> DatasetCard:
    """Read ``dataset.json`` strictly.

    Raises:
        DatasetError: missing file, invalid JSON or an invalid card (names the file).
    """
    path = Path(path)
    try:
        data = read_json(path)
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found (not a lenspair dataset?)") from None
    except ConfigError as exc:  # not UTF-8 or not JSON: names the file
        raise DatasetError(str(exc)) from None
    try:
        return load_dataclass(DatasetCard, data)
    except ConfigError as exc:
        raise DatasetError(f"{path}: {exc}") from None


def compare_counts(recorded: dict[str, Counts], actual: dict[str, Counts]) -> list[str]:
    """Differences between two count tables as ``counts.<path>: card X, manifest Y``."""
    problems: list[str] = []
    _diff(to_plain(recorded), to_plain(actual), "counts", problems)
    return problems


def _diff(recorded: object, actual: object, path: str, problems: list[str]) -> None:
    if isinstance(recorded, dict) and isinstance(actual, dict):
        for key in sorted(set(recorded) | set(actual)):
            _diff(recorded.get(key, 0), actual.get(key, 0), f"{path}.{key}", problems)
    elif recorded != actual:
        problems.append(f"{path}: card says {recorded}, manifest gives {actual}")


def make_card(
    rows: Sequence[ManifestRow],
    sources: Sequence[SourceInfo],
    removed_by_rule: Mapping[str, int],
    ingest_reasons: Mapping[str, int],
    grouping: Grouping,
    config: DatasetConfig,
    image_files: Literal["copy", "hard-link"] = "copy",
) -> DatasetCard:
    """The card of a build; counts are recomputed from ``rows``."""
    return DatasetCard(
        lenspair_version=__version__,
        seed=config.split.seed,
        fractions=config.split.fractions,
        counts=count_rows(rows),
        curation=tuple(RuleCount(name, text, removed_by_rule.get(name, 0)) for name, text in RULES),
        pairs_in=sum(source.pairs for source in sources),
        tagged_clean=sum(1 for row in rows if row.difficulty == "clean"),
        grouping=grouping,
        config=config,
        sources=tuple(sources),
        ingest_reasons=dict(ingest_reasons),
        image_files=image_files,
        image_files_note=IMAGE_FILES_NOTES[image_files],
    )


def contact_sheet(folder: Path, split: str, rows: Sequence[ManifestRow]) -> np.ndarray:
    """``uint8`` RGB sheet of up to 8 evenly spaced pairs of a split: input | target.

    Args:
        folder: dataset root holding the rows' files.
        split: split name, for the title.
        rows: the split's rows, in manifest order.
    """
    count = min(CONTACT_PAIRS, len(rows))
    picks = sorted({round(i * (len(rows) - 1) / max(1, count - 1)) for i in range(count)})
    images, labels = [], []
    for row in (rows[i] for i in picks):
        images.append(
            [read_image(folder / row.files["input"]), read_image(folder / row.files["target"])]
        )
        labels.append(
            [
                f"{row.name} input ({row.obstructed})",
                f"target ({row.clean}) {row.difficulty} {row.psnr_db:.1f} dB",
            ]
        )
    sides = count_rows(rows)[split].clean_side
    title = f"{split}: {len(rows)} pairs; clean side cam0 {sides['cam0']}, cam1 {sides['cam1']}"
    return make_contact_sheet(images, labels, title=title, cell_width=240)
