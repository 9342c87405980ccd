"""Leak-free train/val/test splits: groups, hashing, side stratification, border gaps.

**Groups.** Pairs are split by *group*, never one by one, so that near-identical
neighbouring frames never land in two splits. A group is a whole recording,
or, when there are too few recordings (``group_by: auto`` with fewer than
``min_groups_per_split`` recordings per non-empty split), a contiguous
segment of ``segment_frames`` lines of a recording's ``pairs.jsonl``; the
last ``segment_gap_frames`` frames before a border between two segments that
land in different splits are dropped (rule ``split_gap``).

**Hashing.** A group goes to the split whose interval of the cumulative
fractions holds ``u = int(sha256(f"{seed}:{group_id}")[:16], 16) / 2**64``.
The assignment of a group depends only on its id and the seed, so adding a
recording later does not move existing pairs between splits (with
``group_by: auto``, a rebuild keeps the grouping of the dataset it replaces).

**Side stratification.** Within each stratum (the obstructed camera, i.e.
the ground-truth side), when the stratum has at least as many groups as there
are non-empty splits, a deterministic fix-up makes sure every non-empty
split gets a group of that side: while a split lacks the side, the group of
that side whose hash ``u`` lies nearest to the split's interval (ties by id),
taken from a split that holds at least two groups of the side, is moved to
it. Only moved groups (listed in the card) can change split when data is
added; a stratum with too few groups is left as hashed, with a warning.

**Train first.** When the hash leaves train empty (one or two short
recordings give that often), the group nearest train's interval moves there,
with a warning: a dataset must have something to train on, even if val or
test then stays empty.
"""

import hashlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

from lenspair.dataset.config import SPLITS, SplitConfig

GroupMode = Literal["recording", "segment"]


@dataclass(frozen=True)
class SplitItem:
    """What splitting needs to know about one curated pair.

    Attributes:
        recording: recording id.
        index: line index of the pair in the recording's ``pairs.jsonl``.
        side: stratum, the obstructed camera (``cam0``/``cam1``).
    """

    recording: str
    index: int
    side: str


@dataclass(frozen=True)
class SplitPlan:
    """The result of :func:`plan_splits`.

    Attributes:
        mode: how pairs were grouped.
        assignment: group id -> split name, for every group that has pairs.
        moved: groups moved by the side fix-up (sorted).
        warnings: strata whose groups could not cover every split, and a
            kept earlier grouping.
        kept_earlier: ``group_by: auto`` kept the grouping of the dataset
            being rebuilt where it would now choose the other.
    """

    mode: GroupMode
    assignment: dict[str, str]
    moved: tuple[str, ...]
    warnings: tuple[str, ...]
    kept_earlier: bool = False


def choose_mode(num_recordings: int, config: SplitConfig) -> GroupMode:
    """Resolve ``group_by``: ``auto`` -> recordings when there are enough of them."""
    if config.group_by != "auto":
        return config.group_by
    active = sum(1 for f in config.fractions if f > 0)
    enough = num_recordings >= config.min_groups_per_split * active
    return "recording" if enough else "segment"


def group_id(recording: str, index: int, mode: GroupMode, segment_frames: int) -> str:
    """Group of a pair: the recording id, or ``<recording>#s<k>`` for segment ``k``."""
    if mode == "recording":
        return recording
    return f"{recording}#s{index // segment_frames:05d}"


def hash_unit(seed: int, group: str) -> float:
    """Map ``(seed, group)`` to [0, 1) with SHA-256 (stable across runs and machines)."""
    digest = hashlib.sha256(f"{seed}:{group}".encode()).hexdigest()
    return int(digest[:16], 16) / float(1 << 64)


def split_intervals(fractions: Sequence[float]) -> dict[str, tuple[float, float]]:
    """``[start, end)`` of each split on [0, 1); the last non-empty one ends at 1."""
    intervals: dict[str, tuple[float, float]] = {}
    start = 0.0
    for name, fraction in zip(SPLITS, fractions, strict=True):
        intervals[name] = (start, start + fraction)
        start += fraction
    last = max(i for i, f in enumerate(fractions) if f > 0)
    intervals[SPLITS[last]] = (intervals[SPLITS[last]][0], 1.0)
    return intervals


def hashed_split(u: float, fractions: Sequence[float]) -> str:
    """The split whose interval holds ``u``."""
    for name, (start, end) in split_intervals(fractions).items():
        if start <= u < end:
            return name
    raise AssertionError(f"u={u} outside [0, 1)")  # pragma: no cover


def plan_splits(
    items: Iterable[SplitItem], config: SplitConfig, earlier_mode: str | None = None
) -> SplitPlan:
    """Assign every group of ``items`` to a split (hash, then the side fix-up).

    Args:
        items: the curated pairs of all recordings.
        config: fractions, seed and grouping.
        earlier_mode: how the dataset being rebuilt grouped its pairs. With
            ``group_by: auto`` it is kept: auto switches from segments to whole
            recordings once there are enough recordings, and the switch moved
            about half the existing pairs between splits (test frames into
            train). A warning says so when auto would now choose otherwise.

    Returns:
        The plan; use :func:`group_id` with ``plan.mode`` to find a pair's group.
    """
    items = list(items)
    mode = choose_mode(len({item.recording for item in items}), config)
    warnings: list[str] = []
    known = earlier_mode in ("recording", "segment")
    kept_earlier = config.group_by == "auto" and known and earlier_mode != mode
    if kept_earlier:
        warnings.append(
            f"group_by auto: kept grouping by {earlier_mode} as the dataset being rebuilt "
            f"did (auto would now group by {mode}, moving pairs between splits; set "
            "split.group_by to choose)"
        )
        mode = "recording" if earlier_mode == "recording" else "segment"
    sides: dict[str, str] = {}
    for item in items:
        gid = group_id(item.recording, item.index, mode, config.segment_frames)
        sides.setdefault(gid, item.side)
    units = {gid: hash_unit(config.seed, gid) for gid in sides}
    assignment = {gid: hashed_split(units[gid], config.fractions) for gid in sorted(sides)}
    intervals = split_intervals(config.fractions)
    active = [name for name, f in zip(SPLITS, config.fractions, strict=True) if f > 0]
    moved: list[str] = []
    for side in sorted(set(sides.values())):
        members = sorted(gid for gid, s in sides.items() if s == side)
        if len(members) < len(active):
            warnings.append(
                f"obstructed {side}: {len(members)} group(s) cannot cover the {len(active)} splits"
            )
            continue
        while True:
            by_split = {name: [g for g in members if assignment[g] == name] for name in active}
            empty = [name for name in active if not by_split[name]]
            if not empty:
                break
            start, end = intervals[empty[0]]
            donors = [g for name in active if len(by_split[name]) >= 2 for g in by_split[name]]
            best = min(donors, key=lambda g: (_distance(units[g], start, end), g))
            assignment[best] = empty[0]
            moved.append(best)
    if "train" in active and assignment and "train" not in assignment.values():
        # Too few groups for every split: a dataset without training pairs is of no
        # use, so the group nearest the train interval moves there.
        start, end = intervals["train"]
        best = min(assignment, key=lambda g: (_distance(units[g], start, end), g))
        warnings.append(
            f"{len(assignment)} group(s) left train empty; moved {best} from "
            f"{assignment[best]} to train (add recordings to fill every split)"
        )
        assignment[best] = "train"
        moved.append(best)
    return SplitPlan(mode, assignment, tuple(sorted(moved)), tuple(warnings), kept_earlier)


def gap_items(items: Iterable[SplitItem], plan: SplitPlan, config: SplitConfig) -> set[SplitItem]:
    """Pairs to drop so that no two neighbouring frames straddle a split border.

    In segment mode, the last ``segment_gap_frames`` lines before the border
    of segments ``k`` and ``k + 1`` of a recording are dropped when both
    segments have pairs and land in different splits. Recording mode drops
    nothing.
    """
    if plan.mode == "recording" or config.segment_gap_frames == 0:
        return set()
    length = config.segment_frames
    dropped = set()
    for item in items:
        segment = item.index // length
        border = (segment + 1) * length
        if item.index < border - config.segment_gap_frames:
            continue
        here = plan.assignment.get(group_id(item.recording, item.index, "segment", length))
        there = plan.assignment.get(group_id(item.recording, border, "segment", length))
        if there is not None and here != there:
            dropped.add(item)
    return dropped


def _distance(u: float, start: float, end: float) -> float:
    if start <= u < end:
        return 0.0
    return min(abs(u - start), abs(u - end))
