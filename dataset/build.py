"""Build a dataset from ingested recordings: measure, curate, split, write, place.

Entry point :func:`build_dataset`. The output layout::

    DS/{train,val,test}/{input,target[,mask]}/<recording>_<t_ns>.png
    DS/manifest.jsonl      one ManifestRow per pair (dataset.manifest)
    DS/dataset.json        the dataset card (dataset.card)
    DS/removed.jsonl       every pair curation removed, with its rule and reason
    DS/config.yaml         the resolved configuration
    DS/contact_<split>.png input | target of a few pairs per split

Images are independent of the ingested files by default: reflinked where the
file system supports copy-on-write clones, else copied, so editing a dataset
image never changes the recording or another dataset. ``link="hard"`` (CLI
``--link hard``) hard-links them instead to save space, makes them read-only
and says so in the card. The dataset is written into a temporary sibling folder
and renamed into place, so ``DS`` never holds a half-written dataset. A ``DS``
that already holds a *different* dataset is only replaced with
``overwrite=True``; rebuilding the same dataset is always allowed, and that
decision is taken from the manifest, card, config and file list before any
image is copied. The same sources, configuration and seed give byte-identical
files, whatever the folder held before: what a rebuild moved between splits
against the dataset it replaced is logged (and returned in
:attr:`BuildResult.changed_splits`), not written into ``dataset.json``.

Bad input: a folder without ``pairs.jsonl`` or ``report.json`` is an error
naming it; a missing, corrupt or mismatched (sha256) image only removes its
pair, which is counted under its rule and logged as a warning. So does a
``pairs.jsonl`` line whose ``files`` entry points outside the recording folder
(an absolute path, or one climbing out with ``..``): rule ``bad_image``, the
reason naming the line. The check is on the path as written; a symbolic link
inside the recording folder is followed as any file is.
"""

import itertools
import logging
import os
import shutil
import stat
from collections import Counter
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

from lenspair.capture.ingested import (
    PAIRS_FILE,
    REPORT_FILE,
    IngestReport,
    PairRecord,
    read_numbered_pairs,
    read_report,
)
from lenspair.core.config import dump_yaml
from lenspair.core.errors import ImageIOError
from lenspair.core.fsutil import (
    atomic_write_text,
    check_writable,
    clone_file,
    naming_errors,
    read_json_field,
    sha256_bytes,
    temporary_folder,
)
from lenspair.core.imageio import read_image, write_image
from lenspair.core.leftovers import leftovers, remove_leftovers
from lenspair.core.progress import progress
from lenspair.dataset import curation, splits
from lenspair.dataset.card import (
    CARD_FILE,
    CARD_FORMAT,
    DatasetCard,
    Grouping,
    SourceInfo,
    contact_sheet,
    make_card,
    write_card,
)
from lenspair.dataset.config import SPLITS, DatasetConfig
from lenspair.dataset.curation import Measured, Removals
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import (
    MANIFEST_FILE,
    REMOVED_FILE,
    ManifestRow,
    RemovedPair,
    read_manifest,
    write_manifest,
    write_removed,
)
from lenspair.dataset.verify import dataset_difference, user_files

logger = logging.getLogger(__name__)
CONFIG_FILE = "config.yaml"
LinkMode = Literal["copy", "hard"]
_WRITE_BITS = stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH
_FILE_RULES = ("missing_file", "checksum", "bad_image")


@dataclass(frozen=True)
class Source:
    """One ingested recording, as read from disk.

    Attributes:
        path: the ingested folder (absolute).
        report: its ``report.json``.
        records: its ``pairs.jsonl`` lines, in file order.
        lines: the line number in ``pairs.jsonl`` of each record (blank lines
            counted), for messages; empty: ``index + 1``.
    """

    path: Path
    report: IngestReport
    records: tuple[PairRecord, ...]
    lines: tuple[int, ...] = ()

    def line(self, index: int) -> int:
        """Line number in ``pairs.jsonl`` of record ``index``."""
        return self.lines[index] if self.lines else index + 1

    @property
    def clean(self) -> str:
        """The ground-truth camera (the one that is not obstructed)."""
        return "cam0" if self.report.obstructed == "cam1" else "cam1"


@dataclass(frozen=True)
class BuildResult:
    """What :func:`build_dataset` made: the dataset folder, its rows and card.

    ``changed_splits`` says how many pairs changed split against the dataset
    this build replaced (:func:`changed_splits`), or is None; it is logged,
    and kept out of the card, whose bytes depend on the inputs alone.
    """

    out: Path
    rows: tuple[ManifestRow, ...]
    card: DatasetCard
    changed_splits: str | None = None


def load_source(path: Path) -> Source:
    """Read an ingested recording's ``report.json`` and ``pairs.jsonl``.

    Raises:
        DatasetError: the folder or one of the two files is missing, the
            obstructed camera or recording id is invalid, or a timestamp
            repeats; the message names the file.
        ConfigError: a malformed line or key (names the file and line).
    """
    path = Path(path).resolve()
    if not path.is_dir():
        raise DatasetError(f"{path}: not a folder (expected an ingested recording)")
    for name in (PAIRS_FILE, REPORT_FILE):
        if not (path / name).is_file():
            raise DatasetError(
                f"{path}: missing {name} (not an ingested recording, or capture-ingest was "
                "stopped before it finished: run it again)"
            )
    report = read_report(path / REPORT_FILE)
    if report.obstructed not in ("cam0", "cam1"):
        raise DatasetError(
            f"{path / REPORT_FILE}: obstructed must be cam0 or cam1, got {report.obstructed!r}"
        )
    rid = report.recording_id
    if not rid or rid.startswith(".") or any(c in rid for c in "/\\\0"):
        raise DatasetError(f"{path / REPORT_FILE}: recording_id {rid!r} is not a file name")
    numbered = read_numbered_pairs(path / PAIRS_FILE)
    records = tuple(record for _, record in numbered)
    seen: set[int] = set()
    for number, record in numbered:  # the file's own line numbers, blank lines counted
        if record.status != "kept":
            continue  # a rejected frame may repeat a kept one's timestamp (another file)
        if record.t_ns in seen:
            raise DatasetError(f"{path / PAIRS_FILE}:{number}: timestamp {record.t_ns} repeats")
        seen.add(record.t_ns)
    return Source(path, report, records, tuple(number for number, _ in numbered))


def measure_record(source: Source, position: int, index: int, anomaly_delta: float) -> Measured:
    """Read, check and measure the images of line ``index`` of ``source``.

    A problem with the pair's files removes the pair (rules ``missing_file``,
    ``checksum``, ``bad_image``); it is not raised. A ``files`` entry that
    points outside the recording folder is a ``bad_image``, its reason naming
    the ``pairs.jsonl`` line: a dataset must not copy files it was not given.

    Args:
        source: the recording.
        position: its index in the list of sources.
        index: line index in ``pairs.jsonl``.
        anomaly_delta: see :class:`lenspair.dataset.config.CurationConfig`.
    """
    record = source.records[index]
    files = _source_files(source.path, record)
    base = Measured(position, index, record, files, {})
    if record.status == "rejected":
        return _removed(base, "ingest_rejected", record.reason or "unspecified")
    for kind, relative in sorted(record.files.items()):
        if _escapes(relative):
            reason = (
                f"{source.path / PAIRS_FILE}:{source.line(index)}: files.{kind} {relative!r} "
                "points outside the recording folder"
            )
            return _removed(base, "bad_image", reason)
    hashes: dict[str, str] = {}
    for kind, file in files.items():
        try:
            hashes[kind] = sha256_bytes(file.read_bytes())
        except OSError:
            return _removed(base, "missing_file", f"{file}: file missing (named in {PAIRS_FILE})")
        expected = record.sha256.get(kind)
        if expected is not None and expected != hashes[kind]:
            found = hashes[kind][:12]
            reason = f"{file}: sha256 {found}... differs from {PAIRS_FILE} ({expected[:12]}...)"
            return _removed(base, "checksum", reason)
    if files["input"].suffix != files["target"].suffix:
        return _removed(base, "bad_image", f"{files['input']}: input and target file types differ")
    try:
        images = {kind: read_image(file) for kind, file in files.items()}
        stats = curation.measure_pair(
            images["input"], images["target"], images.get("mask"), anomaly_delta
        )
    except ImageIOError as exc:
        return _removed(base, "bad_image", str(exc))
    except ValueError as exc:
        return _removed(base, "bad_image", f"{files['input']}: {exc}")
    return Measured(position, index, record, files, hashes, stats)


def _source_files(folder: Path, record: PairRecord) -> dict[str, Path]:
    """Image paths of a line: from its ``files``, else the default layout."""
    files = {
        kind: folder / record.files.get(kind, f"{kind}/{record.t_ns}.png")
        for kind in ("input", "target")
    }
    default_mask = folder / "mask" / f"{record.t_ns}.png"
    if "mask" in record.files:
        files["mask"] = folder / record.files["mask"]
    elif not record.files and default_mask.is_file():
        files["mask"] = default_mask
    return files


def _escapes(relative: str) -> bool:
    """True when a ``files`` entry of ``pairs.jsonl`` names a path outside its folder."""
    normal = os.path.normpath(relative)
    return os.path.isabs(normal) or normal == os.pardir or normal.startswith(os.pardir + os.sep)


def _removed(measured: Measured, rule: str, reason: str) -> Measured:
    m = measured
    return Measured(m.source, m.index, m.record, m.files, {}, None, rule, reason)


def assemble_rows(
    sources: Sequence[Source],
    measured: Sequence[Measured],
    removed: Removals,
    config: DatasetConfig,
    earlier_mode: str | None = None,
) -> tuple[list[tuple[ManifestRow, Measured]], splits.SplitPlan]:
    """Split the surviving pairs (adding ``split_gap`` removals) and make their rows.

    Returns:
        ``(row, measured pair)`` in manifest order (split, then name), and the plan.

    Raises:
        DatasetError: pairs survived curation but the split gap left train
            without any (:func:`~lenspair.dataset.splits.plan_splits` moves a
            group that keeps pairs into train, so this is a last check, never a
            silent empty train split).
    """
    survivors = [m for m in measured if (m.source, m.index) not in removed]
    items = {
        (m.source, m.index): splits.SplitItem(
            sources[m.source].report.recording_id, m.index, sources[m.source].report.obstructed
        )
        for m in survivors
    }
    plan = splits.plan_splits(items.values(), config.split, earlier_mode)
    if joins := split_sessions(sources, items, plan, config):
        plan = replace(plan, warnings=(*plan.warnings, *joins))
    gapped = splits.gap_items(items.values(), plan, config.split)
    pairs: list[tuple[ManifestRow, Measured]] = []
    for m in survivors:
        if items[(m.source, m.index)] in gapped:
            removed[(m.source, m.index)] = ("split_gap", "frame before a split border")
        else:
            pairs.append((_row(sources[m.source], m, plan, config), m))
    pairs.sort(key=lambda pair: (SPLITS.index(pair[0].split), pair[0].name))
    if survivors and not any(row.split == "train" for row, _ in pairs):
        split = config.split
        raise DatasetError(
            f"split: the gap of segment_gap_frames {split.segment_gap_frames} at split borders "
            f"left train without pairs ({len(survivors)} survived curation); set a smaller "
            f"split.segment_gap_frames or a larger split.segment_frames ({split.segment_frames})"
        )
    splits_of: dict[str, set[str]] = {}
    for row, _ in pairs:
        if digest := row.sha256.get("input"):
            splits_of.setdefault(digest, set()).add(row.split)
    if leaks := sum(1 for found in splits_of.values() if len(found) > 1):
        # groups keep a recording's frames together; byte-identical frames from two
        # "recordings" (one copied under another name) defeat that: say so
        warning = (
            f"{leaks} input image(s) are byte-identical to one in another split (the same "
            "recording given twice under two names?): those splits are not independent"
        )
        plan = replace(plan, warnings=(*plan.warnings, warning))
    return pairs, plan


def _row(source: Source, m: Measured, plan: splits.SplitPlan, config: DatasetConfig) -> ManifestRow:
    assert m.stats is not None
    record, stats, cfg = m.record, m.stats, config.curation
    recording = source.report.recording_id
    group = splits.group_id(recording, m.index, plan.mode, config.split.segment_frames)
    split = plan.assignment[group]
    name = f"{recording}_{record.t_ns}"
    tagged = curation.is_clean(stats, cfg)
    return ManifestRow(
        split=split,  # type: ignore[arg-type]
        name=name,
        recording=recording,
        group=group,
        t_ns=record.t_ns,
        t_clean_ns=record.t_clean_ns,
        obstructed=source.report.obstructed,
        clean=source.clean,
        anomaly=tuple(source.report.anomaly),
        difficulty="clean" if tagged else curation.difficulty(stats.psnr_db, cfg),
        psnr_db=stats.psnr_db,
        anomaly_fraction=stats.anomaly_fraction,
        residual_px=record.residual_px,
        photometric_residual=record.photometric_residual,
        inliers=record.inliers,
        sharpness=_first(record.sharpness, stats.sharpness),
        saturated=_first(record.saturated, stats.saturated),
        black=_first(record.black, stats.black),
        mask_fraction=_first(record.mask_fraction, stats.mask_fraction),
        files={kind: f"{split}/{kind}/{name}{file.suffix}" for kind, file in m.files.items()},
        sha256=dict(m.sha256),
    )


def _first(recorded: float | None, measured: float) -> float:
    return measured if recorded is None else recorded


def _source_info(source: Source, rows: Sequence[ManifestRow]) -> SourceInfo:
    rid = source.report.recording_id
    per_split: Counter[str] = Counter(row.split for row in rows if row.recording == rid)
    return SourceInfo(
        recording=rid,
        path=str(source.path),
        obstructed=source.report.obstructed,
        clean=source.clean,
        anomaly=tuple(source.report.anomaly),
        calibration_source=source.report.calibration_source,
        ingest_version=source.report.lenspair_version,
        pairs=len(source.records),
        kept_at_ingest=sum(1 for r in source.records if r.status == "kept"),
        in_dataset={name: per_split.get(name, 0) for name in SPLITS},
    )


def write_records(
    folder: Path,
    rows: Sequence[ManifestRow],
    card: DatasetCard,
    config: DatasetConfig,
    removed: list[RemovedPair],
) -> None:
    """Write the manifest, card, ``removed.jsonl`` and ``config.yaml`` into ``folder``.

    They are what tells two datasets apart (with the file list the rows give),
    so a rebuild can be compared with the dataset it would replace before a
    single image is copied.
    """
    write_manifest(folder / MANIFEST_FILE, list(rows))
    write_card(folder / CARD_FILE, card)
    write_removed(folder / REMOVED_FILE, removed)
    atomic_write_text(folder / CONFIG_FILE, dump_yaml(config))


def write_images(
    folder: Path, pairs: Sequence[tuple[ManifestRow, Measured]], link: LinkMode = "copy"
) -> None:
    """Place every pair's images under ``folder`` and draw the contact sheets."""
    for name in SPLITS:
        for kind in ("input", "target"):
            (folder / name / kind).mkdir(parents=True, exist_ok=True)
    for row, m in progress(pairs, desc="linking", total=len(pairs), unit="pair"):
        for kind, relative in row.files.items():
            destination = folder / relative
            destination.parent.mkdir(parents=True, exist_ok=True)
            _place_image(m.files[kind], destination, link)
    rows = [row for row, _ in pairs]
    for name in SPLITS:
        selected = [row for row in rows if row.split == name]
        if selected:
            write_image(folder / f"contact_{name}.png", contact_sheet(folder, name, selected))


def _place_image(source: Path, destination: Path, link: LinkMode) -> None:
    if link == "hard":
        try:
            os.link(source, destination)
        except OSError as exc:
            raise DatasetError(
                f"{destination.parent}: --link hard cannot link {source} ({exc.strerror}); "
                "the default copies instead"
            ) from None
        os.chmod(destination, os.stat(destination).st_mode & ~_WRITE_BITS)
        return
    clone_file(source, destination)


def build_dataset(
    sources: Sequence[Path],
    out: Path,
    config: DatasetConfig,
    *,
    overwrite: bool = False,
    workers: int | None = None,
    link: LinkMode = "copy",
    accept_side_mismatch: bool = False,
) -> BuildResult:
    """Curate ingested recordings into a split dataset at ``out``.

    Args:
        sources: ingested recording folders (``capture-ingest`` outputs).
        out: dataset folder to create (or replace, see ``overwrite``).
        config: curation thresholds and split settings.
        overwrite: replace ``out`` even when it holds a different dataset.
        workers: threads reading and measuring images (default: up to 4);
            the output does not depend on it.
        link: ``"copy"`` (independent files, reflinked where possible) or
            ``"hard"`` (hard links, made read-only; recorded in the card).
        accept_side_mismatch: build a recording whose side check contradicts
            its declared obstructed camera as declared (with a warning).

    Raises:
        DatasetError: no sources, a bad source folder, two sources with one
            recording id, a side-check mismatch not accepted, or ``out``
            holds something that may not be replaced.
        OSError: the file system refused a write (checked before any pair is
            measured, and as the files are written); it names ``out``, or a
            file's final path under it.
    """
    if not sources:
        raise DatasetError("no ingested recordings given")
    out = Path(out).resolve()
    _recover_swap(out)
    # in recording-id order: the same recordings in another order are the same dataset
    loaded = sorted((load_source(path) for path in sources), key=lambda s: s.report.recording_id)
    _check_paths(loaded, out)
    _check_sides(loaded, accept_side_mismatch)
    _out_state(out)
    _check_file_system(loaded, out, link)
    jobs = [(p, i) for p, s in enumerate(loaded) for i in range(len(s.records))]
    delta = config.curation.anomaly_delta
    with ThreadPoolExecutor(max_workers=workers or min(4, os.cpu_count() or 1)) as pool:
        results = pool.map(lambda j: measure_record(loaded[j[0]], j[0], j[1], delta), jobs)
        measured = list(progress(results, desc="measuring", total=len(jobs), unit="pair"))
    for m in measured:
        if m.rule in _FILE_RULES:
            logger.warning("pair skipped (%s): %s", m.rule, m.reason)
    removed = curation.curate(measured, config.curation)
    grouping = read_json_field(out / CARD_FILE, "grouping")  # of the dataset being rebuilt
    earlier = grouping.get("mode") if isinstance(grouping, dict) else None
    pairs, plan = assemble_rows(loaded, measured, removed, config, earlier)
    if plan.kept_earlier:
        # config.yaml says what was done: with "auto" it would rebuild other splits
        config = replace(config, split=replace(config.split, group_by=plan.mode))
    for warning in plan.warnings:
        logger.warning("split: %s", warning)
    rows = [row for row, _ in pairs]
    # said once the build has replaced that dataset (not when it is refused), and
    # kept out of the card: a note of what was on disk before made an identical
    # rerun's card differ, so the rerun was refused as "a different dataset"
    changed = changed_splits(out / MANIFEST_FILE, rows)
    # as each ingest counted them: by the stable part of the reason (one entry per
    # frame, with its path, made the card unreadable), and frames it could not list
    reasons: Counter[str] = Counter()
    for source in loaded:
        reasons.update(source.report.rejection_reasons)
    card = make_card(
        rows,
        [_source_info(s, rows) for s in loaded],
        Counter(rule for rule, _ in removed.values()),
        reasons,
        Grouping(plan.mode, plan.moved, plan.warnings),
        config,
        image_files="hard-link" if link == "hard" else "copy",
    )
    if not rows:  # an empty dataset trains nothing: said now, not by train later
        why = ", ".join(f"{c.rule} {c.removed}" for c in card.curation if c.removed) or "none"
        raise DatasetError(
            f"no pair survived curation: {card.pairs_in} pairs in, removed: {why}; "
            "see the sources' pairs.jsonl (and --min-* thresholds)"
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_leftovers(out.parent, out.name)  # of killed builds of this same output only
    gone = [
        RemovedPair(loaded[s].report.recording_id, loaded[s].records[i].t_ns, rule, reason)
        for (s, i), (rule, reason) in removed.items()
    ]
    # a refusal names out, or a file's final path under it, never the .building folder
    with naming_errors(out):
        temp = temporary_folder(out.parent, out.name, ".building")
        try:
            write_records(temp, rows, card, config, gone)
            if not overwrite:  # refused now, not after minutes of copying images
                _check_replaceable(out, temp, rows)
            write_images(temp, pairs, link)
            _place(temp, out, overwrite)
        finally:
            shutil.rmtree(temp, ignore_errors=True)
    if changed:
        logger.warning("split: %s", changed)
    return BuildResult(out, tuple(rows), card, changed)


SESSION_JOIN_PERIODS = 3
"""Frame periods within which one recording starting after another ends reads as its sequel."""


def split_sessions(
    sources: Sequence[Source],
    items: dict[tuple[int, int], splits.SplitItem],
    plan: splits.SplitPlan,
    config: DatasetConfig,
) -> list[str]:
    """Warnings for one session cut into recordings whose join straddles two splits.

    ``rosbag record --split`` (or a driver's file rotation) cuts one session into
    consecutive recordings. Each is its own split group, so the last frame of one
    and the first of the next, a frame period apart, can land in train and val.
    Two recordings read as one session when they share the obstructed camera and
    the calibration and the second starts within :data:`SESSION_JOIN_PERIODS`
    frame periods after the first ends.
    """
    ends = []
    for number, source in enumerate(sources):
        kept = sorted(
            (r.t_ns, index) for index, r in enumerate(source.records) if (number, index) in items
        )
        if len(kept) < 2:
            continue
        gaps = sorted(b - a for (a, _), (b, _) in itertools.pairwise(kept) if b > a)
        period = gaps[len(gaps) // 2] if gaps else 0
        ends.append((number, kept[0], kept[-1], period))
    warnings = []
    for a, _, last_a, period_a in ends:
        for b, first_b, _, period_b in ends:
            source_a, source_b = sources[a], sources[b]
            gap = first_b[0] - last_a[0]
            if (
                a == b
                or source_a.report.obstructed != source_b.report.obstructed
                or source_a.report.calibration != source_b.report.calibration
                or not 0 < gap <= SESSION_JOIN_PERIODS * max(period_a, period_b)
            ):
                continue
            sides = [
                plan.assignment.get(
                    splits.group_id(items[key].recording, items[key].index, plan.mode,
                                    config.split.segment_frames)
                )
                for key in ((a, last_a[1]), (b, first_b[1]))
            ]  # fmt: skip
            if sides[0] != sides[1]:
                warnings.append(
                    f"{source_b.report.recording_id} starts {gap / 1e6:.1f} ms after "
                    f"{source_a.report.recording_id} ends, with the same calibration: one "
                    f"session cut in two? Their neighbouring frames are in {sides[0]} and "
                    f"{sides[1]}; ingest the session as one recording to keep them together (a "
                    "ROS 2 bag folder is one; merge split ROS 1 bags into one .bag first)"
                )
    return warnings


def changed_splits(earlier_manifest: Path, rows: Sequence[ManifestRow]) -> str | None:
    """What a rebuild moves between splits, against the dataset it replaces, or None.

    Hashing keeps a group's split when recordings are added, but a group moved
    to fill a split (side stratification, train first) can move back once new
    groups fill it, and a network trained on the old train split would then be
    validated on its own training frames. A missing or unreadable earlier
    manifest compares nothing.
    """
    try:
        earlier = {(r.recording, r.t_ns): r.split for r in read_manifest(earlier_manifest)}
    except DatasetError:
        return None
    moves: Counter[tuple[str, str]] = Counter(
        (earlier[key], row.split)
        for row in rows
        if (key := (row.recording, row.t_ns)) in earlier and earlier[key] != row.split
    )
    if not moves:
        return None
    said = ", ".join(f"{n} {a} -> {b}" for (a, b), n in sorted(moves.items()))
    return (
        f"{sum(moves.values())} pair(s) changed split against the dataset this build "
        f"replaces ({said}): do not validate a network trained on the old splits on the new ones"
    )


SIDE_MISMATCH_CONFIDENCE = 0.5
"""Detector side-check confidence from which a mismatch refuses the build (below: a warning).

A detector sure of a swapped side says 0.99 against 0.09 (confidence 0.9).
The fine-detail check only warns, whatever its confidence: refracting drops
add detail, and on heavy rain it has named the clean camera with confidence
0.52 (:mod:`lenspair.capture.side_check`).
"""


def _check_sides(sources: Sequence[Source], accept: bool) -> None:
    """Refuse recordings whose images clearly contradict the declared obstructed camera.

    capture-ingest checks the declared side and records a mismatch in
    ``report.json``, but builds the pairs as declared: built into a dataset,
    their input is the clean view and their target the obstructed one, and a
    network trained on them learns to add the anomaly. A detector's mismatch
    of confidence :data:`SIDE_MISMATCH_CONFIDENCE` or more refuses; a weaker
    one, or the fine-detail check's (reports without a ``method`` are its),
    is a warning.

    Raises:
        DatasetError: naming each such recording and what its check said.
    """
    strong: list[str] = []
    weak: list[str] = []
    for source in sources:
        check = source.report.side_check
        if check.get("mismatch") is not True:
            continue
        said = f"{source.path}: {check.get('message', 'side check mismatch')}"
        confidence = check.get("confidence")
        sure = (
            check.get("method") == "detector"
            and isinstance(confidence, int | float)
            and confidence >= SIDE_MISMATCH_CONFIDENCE
        )
        (strong if sure and not accept else weak).append(said)
    for said in weak:
        logger.warning("building as declared, although %s", said)
    if strong:
        raise DatasetError(
            f"{'; '.join(strong)}. Their pairs would have input and target swapped: fix "
            "rig.yaml (or --obstructed) and run capture-ingest again, or pass "
            "--accept-side-mismatch if the declared side is right"
        )


def _check_paths(sources: Sequence[Source], out: Path) -> None:
    ids: dict[str, Path] = {}
    for source in sources:
        rid = source.report.recording_id
        if rid in ids:
            if ids[rid] == source.path:
                raise DatasetError(f"{source.path}: given twice")
            raise DatasetError(f"{source.path}: recording id {rid!r} is also that of {ids[rid]}")
        ids[rid] = source.path
        if out == source.path or out in source.path.parents or source.path in out.parents:
            raise DatasetError(f"{out}: the dataset folder overlaps source {source.path}")


def _check_file_system(sources: Sequence[Source], out: Path, link: LinkMode) -> None:
    """What the file system of ``out`` would refuse, found before any pair is measured.

    A recording id near 255 bytes ingests (its frames are ``<t_ns>.png``) but
    its dataset files ``<id>_<t_ns>.png`` would not fit; ``--link hard`` cannot
    link across file systems. Both failed after every pair had been measured,
    naming the build's temporary folder. So did a read-only or another user's
    folder (:func:`~lenspair.core.fsutil.check_writable`).

    Raises:
        DatasetError: a file name too long, or ``--link hard`` across file systems.
        OSError: the file system refuses to write beside ``out``; it names ``out``.
    """
    check_writable(out)
    existing = next(folder for folder in (out, *out.parents) if folder.exists())
    try:
        limit = os.pathconf(existing, "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    for source in sources:
        rid = source.report.recording_id
        names = (  # a line without files: the default layout, <kind>/<t_ns>.png
            f"{rid}_{record.t_ns}{Path(file).suffix}"
            for record in source.records
            if record.status == "kept"
            for file in (record.files.values() or ["default.png"])
        )
        longest = max(names, key=lambda name: len(name.encode()), default="")
        if len(longest.encode()) > limit:
            raise DatasetError(
                f"{source.path}: its dataset file names <recording id>_<t_ns> would be "
                f"{len(longest.encode())} bytes, over the {limit} its file system allows "
                f"(recording id {rid[:40]!r}... of {len(rid.encode())} bytes); ingest it again "
                "from a folder or bag of a shorter name"
            )
        if link == "hard" and os.stat(source.path).st_dev != os.stat(existing).st_dev:
            raise DatasetError(
                f"--link hard: {source.path} and {out} are on different file systems, "
                "which cannot share files; leave --link out to copy"
            )


def _own_entries() -> frozenset[str]:
    """Top-level names a build writes (:func:`write_records`, :func:`write_images`).

    Anything else is the user's.
    """
    contact = {f"contact_{name}.png" for name in SPLITS}
    return frozenset({*SPLITS, MANIFEST_FILE, CARD_FILE, REMOVED_FILE, CONFIG_FILE, *contact})


def _out_state(out: Path) -> Literal["absent", "empty", "dataset"]:
    """What ``out`` holds now; raise when it is something that must not be replaced.

    A lenspair dataset is told by its card's format tag: a ``dataset.json``
    of another tool (COCO, Hugging Face) is not one, even with ``--overwrite``.
    """
    if not out.exists():
        return "absent"
    if not out.is_dir():
        raise DatasetError(f"{out}: exists and is not a folder")
    if not any(out.iterdir()):
        return "empty"
    card = out / CARD_FILE
    if card.is_file():
        if read_json_field(card, "format") != CARD_FORMAT:
            raise DatasetError(
                f"{out}: its {CARD_FILE} is not a lenspair dataset card; refusing to replace "
                "the folder (choose another --out)"
            )
    elif not (out / MANIFEST_FILE).is_file():
        raise DatasetError(f"{out}: not empty and not a lenspair dataset; refusing to replace it")
    return "dataset"


def _check_replaceable(out: Path, temp: Path, rows: Sequence[ManifestRow] | None = None) -> None:
    """Refuse to replace a different dataset at ``out`` (see :func:`_place`).

    With ``rows``, ``temp`` need only hold the new manifest, card, config and
    ``removed.jsonl`` (:func:`write_records`): the new file list is the rows'
    files, so the refusal comes before any image is copied. Without, the
    images in ``temp`` are listed.

    Raises:
        DatasetError: ``out`` holds a dataset that differs from the new one.
    """
    if _out_state(out) != "dataset":
        return
    listed = None
    if rows is not None:
        listed = {Path(relative) for row in rows for relative in row.files.values()}
    difference = dataset_difference(out, temp, listed)
    if difference is not None:
        raise DatasetError(
            f"{out}: holds a different dataset ({difference}); use --overwrite to replace it"
        )


def _place(temp: Path, out: Path, overwrite: bool) -> None:
    """Rename the finished ``temp`` to ``out``, replacing an old dataset when allowed.

    Files and folders the user put into an old dataset (notes, evaluations)
    are carried over into the new one, with a warning; a rebuild used to
    delete them.
    """
    state = _out_state(out)
    if state == "dataset" and not overwrite:
        _check_replaceable(out, temp)
    if state == "absent":
        os.replace(temp, out)
        return
    own = _own_entries()
    theirs = sorted(p.name for p in out.iterdir() if p.name not in own)
    # and what they put inside the split folders (an evaluation in train/restored/)
    inside = [p for p in user_files(out) if not (temp / p).exists()]
    for name in [*theirs, *map(str, inside)]:  # linked, not moved: kept until the swap
        (temp / name).parent.mkdir(parents=True, exist_ok=True)
        _link_tree(out / name, temp / name)
    theirs += sorted({str(Path(*p.parts[:2])) for p in inside})  # by folder: train/restored
    trash = temporary_folder(out.parent, out.name, ".old")
    try:
        os.replace(out, trash / "dataset")
        try:
            os.replace(temp, out)
        except OSError:
            os.replace(trash / "dataset", out)  # put the old dataset back
            raise
    finally:
        shutil.rmtree(trash, ignore_errors=True)
    if theirs:
        logger.warning(
            "%s: kept %s, not part of the dataset, in the rebuilt one", out, ", ".join(theirs)
        )


def _recover_swap(out: Path) -> None:
    """Put back the dataset a build killed during its swap (:func:`_place`) had set aside.

    Between the swap's two renames the old dataset, with the user's files in it,
    lies in a ``.<name>.<pid>.*.old`` folder and ``out`` is missing; the rerun's
    clean-up of leftovers would delete it. When ``out`` exists the swap finished
    and the set-aside copy is a leftover like any other.
    """
    if out.exists():
        return
    for trash in leftovers(out.parent, out.name):
        if trash.name.endswith(".old") and (trash / "dataset").is_dir():
            os.replace(trash / "dataset", out)
            logger.warning("%s: put back from %s, set aside by an interrupted rebuild", out, trash)
            return


def _link_tree(source: Path, destination: Path) -> None:
    """Hard-link ``source`` (a file, or a folder's files) at ``destination``, else copy."""

    def link(src: str, dst: str) -> None:
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)

    if source.is_dir() and not source.is_symlink():
        shutil.copytree(source, destination, symlinks=True, copy_function=link)
    elif source.is_symlink():
        os.symlink(os.readlink(source), destination)
    else:
        link(str(source), str(destination))
