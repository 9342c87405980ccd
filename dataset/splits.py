"""Leak-free train/val/test splits: groups, hashing, side stratification, border gaps.

**Groups.** Pairs are split by *group*, never one by one, so that near-identical
neighbouring frames never land in two splits. A group is a whole recording,
or, when there are too few recordings (``group_by: auto`` with fewer than
``min_groups_per_split`` recordings per non-empty split), a contiguous
segment of ``segment_frames`` lines of a recording's ``pairs.jsonl``.

**Gaps.** In segment mode, wherever two frames of a recording that follow
each other among the pairs that survived curation lie in different splits,
the last ``segment_gap_frames`` surviving pairs before that border are dropped
(rule ``split_gap``). The gap is counted in surviving pairs, not in lines of
``pairs.jsonl``: a robot standing still at a border has its frames removed as
near-duplicates, and a gap of lines would only have removed frames already
gone, leaving the views on both sides of the border neighbours. So any two
kept pairs of one recording in different splits have at least
``segment_gap_frames`` surviving pairs of the recording between them.

**Hashing.** A group goes to the split whose interval of the cumulative
fractions holds ``u = int(sha256(f"{seed}:{group_id}")[:16], 16) / 2**64``.
The assignment of a group depends only on its id and the seed, so adding a
recording later does not move existing pairs between splits (with
``group_by: auto``, a rebuild keeps the grouping of the dataset it replaces).

**Sturdy groups.** A gap can drop every pair of a segment that has no more
surviving pairs than ``segment_gap_frames``. A group is *sturdy* when it
keeps a pair whatever the splits of the others: a whole recording, a segment
with more than ``segment_gap_frames`` surviving pairs, or the last segment
(with pairs) of its recording, which no gap reaches. Only sturdy groups are
moved by the two rules below, so that a move is not undone by the gap.

**Side stratification.** Within each stratum (the obstructed camera, i.e.
the ground-truth side), when the stratum has at least as many sturdy groups
as there are non-empty splits, a deterministic fix-up makes sure every
non-empty split keeps pairs of that side *after the gap*: while a split
keeps none, the sturdy group of that side whose hash ``u`` lies nearest to
the split's interval (ties by id), taken from a split that holds at least
two sturdy groups of the side, is moved to it. Only moved groups (listed in
the card) can change split when data is added; a stratum with too few sturdy
groups is left as hashed, with a warning (its splits may then lack the side).
When the stratum later gains enough groups, a rebuild moves only groups new
to it or moved before (``earlier_splits``): the earlier dataset's hashed
groups stay, and a split no such group can fill stays without the side,
with a warning.

**Train first.** When the hash (and the gap) leaves train without pairs (one
or two short recordings give that often), the sturdy group nearest train's
interval moves there, with a warning: a dataset must have something to train
on, even if val or test then stays empty. A sturdy group always exists where
there are pairs (the last segment of a recording is one), so a plan never
leaves train empty. It never undoes the side fix-up: a stratum the fix-up
covered already keeps pairs in train.
"""

import hashlib
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
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
    items: Iterable[SplitItem],
    config: SplitConfig,
    earlier_mode: str | None = None,
    earlier_splits: Mapping[str, str] | None = None,
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
        earlier_splits: group id -> split in the dataset this build extends
            (built with the same seed and fractions). A group the earlier
            dataset held where its hash puts it stays there: the side fix-up
            moves only groups new to this build and groups an earlier rule
            had moved, and leaves a split without the side (warned) rather
            than move one (a stratum crossing the group threshold moved a
            group that had always been where its hash put it, so a network
            trained on the earlier train split was validated on its own
            frames). Train first prefers such groups too, but fills train.

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
    sturdy = sturdy_groups(items, mode, config)
    moved: list[str] = []
    pinned = {g for g, split in (earlier_splits or {}).items() if assignment.get(g) == split}
    for side in sorted(set(sides.values())):
        members = sorted(gid for gid, s in sides.items() if s == side)
        strong = [gid for gid in members if gid in sturdy]
        if len(strong) < len(active):
            warnings.append(
                f"obstructed {side}: {len(members)} group(s) cannot cover the {len(active)} splits"
                + (
                    f" (only {len(strong)} of them keep pairs whatever the split gap of "
                    f"segment_gap_frames {config.segment_gap_frames} drops)"
                    if len(members) >= len(active)
                    else ""
                )
            )
            continue
        side_items = [item for item in items if item.side == side]
        while True:
            kept = _kept_splits(side_items, assignment, mode, config)
            empty = [name for name in active if name not in kept]
            if not empty:
                break
            by_split = {name: [g for g in strong if assignment[g] == name] for name in active}
            start, end = intervals[empty[0]]
            donors = [
                g
                for name in active
                if len(by_split[name]) >= 2
                for g in by_split[name]
                if g not in pinned
            ]
            if not donors:
                warnings.append(
                    f"obstructed {side}: no group can fill {empty[0]} without moving one the "
                    "earlier dataset held where it is (add recordings of this side)"
                )
                break
            best = min(donors, key=lambda g: (_distance(units[g], start, end), g))
            assignment[best] = empty[0]
            moved.append(best)
    if (
        "train" in active
        and assignment
        and "train" not in _kept_splits(items, assignment, mode, config)
    ):
        # Too few groups for every split: a dataset without training pairs is of no
        # use, so the sturdy group nearest the train interval moves there (a fragile
        # one could lose its pairs to the gap at its new border).
        start, end = intervals["train"]
        best = min(sturdy, key=lambda g: (g in pinned, _distance(units[g], start, end), g))
        if "train" in assignment.values():
            why = (
                f"the split gap (segment_gap_frames {config.segment_gap_frames}) dropped every "
                "pair of train"
            )
        else:
            why = f"{len(assignment)} group(s) left train empty"
        warnings.append(
            f"{why}; moved {best} from {assignment[best]} to train (add recordings to fill "
            "every split)"
        )
        assignment[best] = "train"
        moved.append(best)
    return SplitPlan(mode, assignment, tuple(sorted(moved)), tuple(warnings), kept_earlier)


def sturdy_groups(items: Iterable[SplitItem], mode: GroupMode, config: SplitConfig) -> set[str]:
    """Groups that keep a pair after the split gap, whatever split each group lands in.

    A group loses at most its last ``segment_gap_frames`` surviving pairs to the
    gap (:func:`gap_items`), and none when it is the last group of its recording
    (no border follows it); in recording mode, or without a gap, every group
    keeps all its pairs.
    """
    items = list(items)
    groups = Counter(group_id(i.recording, i.index, mode, config.segment_frames) for i in items)
    if mode == "recording" or config.segment_gap_frames == 0:
        return set(groups)
    last: dict[str, int] = {}
    for item in items:
        last[item.recording] = max(last.get(item.recording, item.index), item.index)
    ends = {group_id(rid, index, mode, config.segment_frames) for rid, index in last.items()}
    return {gid for gid, count in groups.items() if count > config.segment_gap_frames} | ends


def gap_items(items: Iterable[SplitItem], plan: SplitPlan, config: SplitConfig) -> set[SplitItem]:
    """Pairs to drop so that no two neighbouring frames straddle a split border.

    In segment mode, the pairs of each recording are taken in line order;
    wherever one pair and the next lie in different splits, the
    ``segment_gap_frames`` pairs before the later one are dropped. ``items``
    are the pairs that survived curation, so the gap is counted in surviving
    frames: frames curation already removed (a robot standing still, a
    rejected frame) do not count towards it. Recording mode drops nothing.
    """
    return _gapped(list(items), plan.assignment, plan.mode, config)


def _gapped(
    items: Sequence[SplitItem], assignment: Mapping[str, str], mode: GroupMode, config: SplitConfig
) -> set[SplitItem]:
    gap = config.segment_gap_frames
    if mode == "recording" or gap == 0:
        return set()
    by_recording: dict[str, list[SplitItem]] = {}
    for item in items:
        by_recording.setdefault(item.recording, []).append(item)
    dropped: set[SplitItem] = set()
    for recording, members in by_recording.items():
        members.sort(key=lambda item: item.index)
        split_of = [
            assignment.get(group_id(recording, m.index, mode, config.segment_frames))
            for m in members
        ]
        for position in range(1, len(members)):
            if split_of[position] != split_of[position - 1]:
                dropped.update(members[max(0, position - gap) : position])
    return dropped


def _kept_splits(
    items: Sequence[SplitItem], assignment: Mapping[str, str], mode: GroupMode, config: SplitConfig
) -> set[str]:
    """Splits that keep at least one of ``items`` after the gap."""
    dropped = _gapped(items, assignment, mode, config)
    return {
        assignment[group_id(item.recording, item.index, mode, config.segment_frames)]
        for item in items
        if item not in dropped
    }


def _distance(u: float, start: float, end: float) -> float:
    if start <= u < end:
        return 0.0
    return min(abs(u - start), abs(u - end))
