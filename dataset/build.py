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

import logging
import os
import shutil
from collections import Counter
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

from lenspair.core.fsutil import naming_errors, read_json_object, temporary_folder
from lenspair.core.leftovers import remove_leftovers
from lenspair.core.progress import progress
from lenspair.dataset import curation, splits
from lenspair.dataset.card import CARD_FILE, DatasetCard, Grouping, SourceInfo, make_card
from lenspair.dataset.config import SPLITS, DatasetConfig, SplitConfig
from lenspair.dataset.curation import Measured, Removals
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import MANIFEST_FILE, ManifestRow, RemovedPair, read_manifest
from lenspair.dataset.output import (
    LinkMode,
    check_replaceable,
    out_state,
    place_dataset,
    recover_swap,
    replacing,
    write_images,
    write_records,
)
from lenspair.dataset.preflight import check_file_system, check_out, check_paths, check_sides
from lenspair.dataset.rows import assemble_rows, changed_splits
from lenspair.dataset.sources import Source, load_source, measure_record, reading_sources
from lenspair.dataset.stats_cache import open_cache

logger = logging.getLogger(__name__)
_FILE_RULES = ("missing_file", "checksum", "bad_image")


@dataclass(frozen=True)
class BuildResult:
    """What :func:`build_dataset` made: the dataset folder, its rows and card.

    ``changed_splits`` says how many pairs changed split against the dataset
    this build replaced (:func:`~lenspair.dataset.rows.changed_splits`), or is
    None; it is logged, and kept out of the card, whose bytes depend on the
    inputs alone.
    """

    out: Path
    rows: tuple[ManifestRow, ...]
    card: DatasetCard
    changed_splits: str | None = None


def build_dataset(
    sources: Sequence[Path],
    out: Path,
    config: DatasetConfig,
    *,
    overwrite: bool = False,
    workers: int | None = None,
    link: LinkMode = "copy",
    accept_side_mismatch: bool = False,
    previous: Path | None = None,
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
        previous: an earlier version of this dataset built in another folder,
            which the build extends instead of the one at ``out`` (see
            :func:`_extended`): its grouping and hashed splits are kept, and
            the pairs that changed split against it are said.

    Raises:
        DatasetError: no sources, a bad source folder, two sources with one
            recording id, a side-check mismatch not accepted, or ``out``
            is a mount point or holds something that may not be replaced.
        OSError: the file system refused a write (checked before any pair is
            measured, and as the files are written); it names ``out``, or a
            file's final path under it.
    """
    if not sources:
        raise DatasetError("no ingested recordings given")
    out = Path(out).resolve()
    earlier_root = out if previous is None else _previous_dataset(previous)
    check_out(out)
    recover_swap(out)
    with replacing(out, probe=True):  # refused now, not after measuring every pair
        pass
    # held until the dataset is in place: no capture-ingest rewrites them meanwhile
    with reading_sources(sources):
        # in recording-id order: the same recordings in another order are the same dataset
        loaded = sorted(map(load_source, sources), key=lambda s: s.report.recording_id)
        check_paths(loaded, out)
        check_sides(loaded, accept_side_mismatch)
        out_state(out)
        check_file_system(loaded, out, link)
        measured = _measure(loaded, config.curation.anomaly_delta, workers)
        removed = curation.curate(measured, config.curation)
        recordings = {source.report.recording_id for source in loaded}
        earlier_rows = _earlier_rows(earlier_root)  # read once: the plan and the warning use it
        earlier = _extended(earlier_root, earlier_rows, recordings, config.split)
        pairs, plan = assemble_rows(loaded, measured, removed, config, *earlier)
        if plan.kept_earlier:
            # config.yaml says what was done: with "auto" it would rebuild other splits
            config = replace(config, split=replace(config.split, group_by=plan.mode))
        for warning in plan.warnings:
            logger.warning("split: %s", warning)
        rows = [row for row, _ in pairs]
        # said once the build has replaced that dataset (not when it is refused), and
        # kept out of the card: a note of what was on disk before made an identical
        # rerun's card differ, so the rerun was refused as "a different dataset"
        changed = changed_splits(earlier_rows, rows, earlier_root if previous else None)
        card = _make_card(loaded, rows, removed, plan, config, link)
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
                    check_replaceable(out, temp, rows)
                write_images(temp, pairs, link)
                place_dataset(temp, out, overwrite)
            finally:
                shutil.rmtree(temp, ignore_errors=True)
        if changed:
            logger.warning("split: %s", changed)
        return BuildResult(out, tuple(rows), card, changed)


def _measure(loaded: Sequence[Source], anomaly_delta: float, workers: int | None) -> list[Measured]:
    """Measure every line of every recording in threads, warning of each unusable pair.

    Figures measured by an earlier build of the same files are read back from
    the user's cache (:mod:`lenspair.dataset.stats_cache`) instead.

    Returns:
        One :class:`~lenspair.dataset.curation.Measured` per ``pairs.jsonl``
        line, in recording then line order, whatever ``workers`` is.
    """
    jobs = [(p, i) for p, s in enumerate(loaded) for i in range(len(s.records))]
    cache = open_cache()
    with ThreadPoolExecutor(max_workers=workers or min(4, os.cpu_count() or 1)) as pool:
        results = pool.map(
            lambda j: measure_record(loaded[j[0]], j[0], j[1], anomaly_delta, cache), jobs
        )
        measured = list(progress(results, desc="measuring", total=len(jobs), unit="pair"))
    if cache is not None and cache.hits:
        logger.info("measuring: %d pair(s) read back from %s", cache.hits, cache.folder)
    for m in measured:
        if m.rule in _FILE_RULES:
            logger.warning("pair skipped (%s): %s", m.rule, m.reason)
    return measured


def _previous_dataset(previous: Path) -> Path:
    """``--previous``, resolved, once it is a dataset ``dataset-build`` wrote."""
    root = Path(previous).resolve()
    if not (root / CARD_FILE).is_file() or not (root / MANIFEST_FILE).is_file():
        raise DatasetError(
            f"{root}: not a dataset built by dataset-build (no {CARD_FILE} and "
            f"{MANIFEST_FILE}); --previous names an earlier version of the dataset being built"
        )
    # its splits are what it hands on: unreadable, every pair was hashed anew without a word
    if read_json_object(root / CARD_FILE) is None:
        raise DatasetError(f"{root / CARD_FILE}: --previous: not a readable dataset card (JSON)")
    try:
        read_manifest(root / MANIFEST_FILE)
    except DatasetError as exc:
        raise DatasetError(f"--previous: {exc}") from None
    return root


def _earlier_rows(root: Path) -> list[ManifestRow] | None:
    """The manifest of the dataset at ``root`` a build extends; None if missing or unreadable."""
    try:
        return read_manifest(root / MANIFEST_FILE)
    except DatasetError:
        return None


def _extended(
    root: Path,
    earlier_rows: Sequence[ManifestRow] | None,
    recordings: set[str],
    split: SplitConfig,
) -> tuple[str | None, dict[str, str] | None]:
    """The grouping mode and group -> split of the dataset at ``root`` this build extends.

    Only a dataset that shares a recording with ``recordings`` is extended
    (its pairs are the ones a changed grouping would move); an unrelated
    dataset replaced with ``--overwrite`` hands on nothing, so the build is
    the one a fresh ``DS`` gets. Its splits are handed on only when it was
    built with the same seed and fractions (else every group is hashed anew
    anyway): :func:`~lenspair.dataset.splits.plan_splits` then keeps every
    group it held where the hash puts it.
    """
    card = read_json_object(root / CARD_FILE) or {}
    grouping, sources = card.get("grouping"), card.get("sources")
    if not isinstance(grouping, dict) or not isinstance(sources, list):
        return None, None
    earlier = {source.get("recording") for source in sources if isinstance(source, dict)}
    if not earlier & recordings:
        return None, None
    same = card.get("seed") == split.seed and card.get("fractions") == list(split.fractions)
    if not same or earlier_rows is None:  # unreadable: its grouping alone is handed on
        return grouping.get("mode"), None
    return grouping.get("mode"), {row.group: row.split for row in earlier_rows}


def _make_card(
    loaded: Sequence[Source],
    rows: Sequence[ManifestRow],
    removed: Removals,
    plan: splits.SplitPlan,
    config: DatasetConfig,
    link: LinkMode,
) -> DatasetCard:
    """The dataset card of ``rows``, with what curation removed and each ingest rejected."""
    # as each ingest counted them: by the stable part of the reason (one entry per
    # frame, with its path, made the card unreadable), and frames it could not list
    reasons: Counter[str] = Counter()
    for source in loaded:
        reasons.update(source.report.rejection_reasons)
    return make_card(
        rows,
        [_source_info(s, rows) for s in loaded],
        Counter(rule for rule, _ in removed.values()),
        reasons,
        Grouping(plan.mode, plan.moved, plan.warnings),
        config,
        image_files="hard-link" if link == "hard" else "copy",
    )


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
