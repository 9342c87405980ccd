"""Manifest rows from measured pairs: split assignment, split gaps and split warnings.

:func:`assemble_rows` splits the pairs that survived curation into train, val
and test (:mod:`lenspair.dataset.splits`), drops the frames next to a split
border, and makes one :class:`~lenspair.dataset.manifest.ManifestRow` per
remaining pair. Two warnings about splits that are not independent are made
here too: one session cut into recordings that straddle two splits
(:func:`split_sessions`), and pairs a rebuild moved between splits
(:func:`changed_splits`).
"""

import itertools
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from lenspair.dataset import curation, splits
from lenspair.dataset.config import SPLITS, DatasetConfig
from lenspair.dataset.curation import Measured, Removals
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import ManifestRow
from lenspair.dataset.sources import Source


def assemble_rows(
    sources: Sequence[Source],
    measured: Sequence[Measured],
    removed: Removals,
    config: DatasetConfig,
    earlier_mode: str | None = None,
    earlier_splits: dict[str, str] | None = None,
) -> tuple[list[tuple[ManifestRow, Measured]], splits.SplitPlan]:
    """Split the surviving pairs and make their rows.

    ``removed`` is updated in place: the pairs the split gap drops are added
    to it with reason ``split_gap``, so the caller's dataset card and
    ``removed.jsonl`` count them with the curation's removals.

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
    plan = splits.plan_splits(items.values(), config.split, earlier_mode, earlier_splits)
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


def changed_splits(
    earlier_rows: Sequence[ManifestRow] | None,
    rows: Sequence[ManifestRow],
    previous: Path | None = None,
) -> str | None:
    """What a rebuild moves between splits, against the dataset it replaces, or None.

    Hashing keeps a group's split when recordings are added, but a group moved
    to fill a split (side stratification, train first) can move back once new
    groups fill it, and a network trained on the old train split would then be
    validated on its own training frames. ``earlier_rows``: the earlier
    dataset's manifest, None when missing or unreadable (nothing to compare).
    ``previous``: the earlier dataset is ``--previous`` (named), not the one
    the build replaces.
    """
    if earlier_rows is None:
        return None
    earlier = {(r.recording, r.t_ns): r.split for r in earlier_rows}
    moves: Counter[tuple[str, str]] = Counter(
        (earlier[key], row.split)
        for row in rows
        if (key := (row.recording, row.t_ns)) in earlier and earlier[key] != row.split
    )
    if not moves:
        return None
    said = ", ".join(f"{n} {a} -> {b}" for (a, b), n in sorted(moves.items()))
    against = f"the earlier dataset {previous}" if previous else "the dataset this build replaces"
    return (
        f"{sum(moves.values())} pair(s) changed split against {against} ({said}): do not "
        "validate a network trained on the old splits on the new ones"
    )
