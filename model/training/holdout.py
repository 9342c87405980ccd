"""The validation hold-out: which pairs or clean images a run validates on.

When no validation split exists, a fraction of the training data is held out
by a hash of the names, so the split is deterministic and stable as data is
added: adding pairs or images never moves an old one across the split.
Frames of one recording are held out together in time windows
(:func:`holdout_group`), since neighbouring frames are near duplicates.
"""

import hashlib
import math
import re
from collections.abc import Sequence
from pathlib import Path

from lenspair.dataset.layouts import Layout, detect_layout, raindrop_key
from lenspair.model.errors import ModelError


def _hash_rank(name: str) -> str:
    return hashlib.sha256(name.encode("utf-8")).hexdigest()


RECORDING_FRAME = re.compile(r"^(?P<recording>.+)_(?P<t_ns>\d{16,20})$")
"""A dataset-build pair name: ``<recording id>_<timestamp in ns>``."""

HOLDOUT_WINDOWS_NS = (10 * 10**9, 5 * 10**9, 2 * 10**9, 10**9)
"""Windows of a recording held out together, tried longest first (:func:`holdout_indices`)."""


def holdout_group(name: str, window_ns: int | None = HOLDOUT_WINDOWS_NS[0]) -> str:
    """The group a pair is held out with: ``rec@<window>`` for recording frames.

    Neighbouring frames of a recording are near duplicates: held out one by
    one, a validation frame had its neighbours in training (frames 5 and 7
    held out, 4, 6 and 8 trained on), and validation measured memory. Any
    other name (a Raindrop image, a photograph), or any name when
    ``window_ns`` is None, is its own group.
    """
    match = RECORDING_FRAME.match(name)
    if window_ns is None or match is None:
        return name
    return f"{match['recording']}@{int(match['t_ns']) // window_ns}"


def _groups(names: Sequence[str], window_ns: int | None) -> dict[str, list[int]]:
    """Indices of ``names`` by :func:`holdout_group`."""
    groups: dict[str, list[int]] = {}
    for index, name in enumerate(names):
        groups.setdefault(holdout_group(name, window_ns), []).append(index)
    return groups


def _hold_out_groups(groups: dict[str, list[int]], count: int, upper: int) -> set[int]:
    """Whole groups in hash order, skipping any that would pass ``upper``, up to ``count``."""
    held: set[int] = set()
    for key in sorted(groups, key=lambda g: (_hash_rank(g), g)):
        if len(held) >= count:
            break
        if len(held) + len(groups[key]) <= upper:
            held.update(groups[key])
    return held


def holdout_indices(
    names: Sequence[str], fraction: float, where: Path | None = None
) -> tuple[list[int], list[int]]:
    """Split indices into (train, validation) by a hash of each name's group (deterministic).

    Whole groups (:func:`holdout_group`) are held out in the order of their
    hash, so adding pairs never moves an old group, until ``fraction`` of the
    pairs are; a group that would take the share past 1.5 times ``fraction``
    is skipped. When no window length (10 s, then 5, 2 and 1 s) lands within
    half to 1.5 times the share, pairs are held out one by one, the only
    choice left (one short recording).

    Raises:
        ModelError: fewer than two names (naming ``where``, the dataset, if given).

    """
    if len(names) < 2:
        raise ModelError(
            f"{where}: " * (where is not None)
            + f"need at least 2 pairs to hold out a validation set, got {len(names)}"
        )
    count = min(len(names) - 1, max(1, math.ceil(fraction * len(names))))
    upper = min(len(names) - 1, max(count, math.floor(1.5 * count)))
    for window in HOLDOUT_WINDOWS_NS:
        groups = _groups(names, window)
        if len(groups) == len(names):
            break  # every pair its own group already: the per-pair split below
        held = _hold_out_groups(groups, count, upper)
        if len(held) >= max(1, count // 2):
            return [i for i in range(len(names)) if i not in held], sorted(held)
    held = _hold_out_groups(_groups(names, None), count, upper)
    return [i for i in range(len(names)) if i not in held], sorted(held)


def split_holdout(
    images: Sequence[Path], fraction: float, root: Path
) -> tuple[list[Path], list[Path]]:
    """Split clean images into (train, validation) as fine-tuning splits their pairs.

    An image of a paired folder is named as the paired readers name the pair
    it is the target of (:func:`pair_name`), any other by its path below
    ``root`` (photographs in scene folders, each numbered from ``000.png``,
    are no one pair), and the names are split by :func:`holdout_indices`.
    Pretraining on the targets of a paired folder (``raindrop/train/gt``, the
    ``train/target`` of a dataset without a validation split) then holds out
    exactly the images whose pairs fine-tuning on that folder validates on, so
    the fine-tune's validation pairs were never pretrained on. The choice
    depends on the names only, not on a seed or the listing order.

    Raises:
        ModelError: fewer than two images (naming ``root``).
    """
    if len(images) < 2:
        raise ModelError(f"{root}: need at least 2 clean images, found {len(images)}")
    train, val = holdout_indices(holdout_names(images, root), fraction, root)
    return [images[i] for i in train], [images[i] for i in val]


def holdout_names(images: Sequence[Path], root: Path) -> list[str]:
    """The names :func:`split_holdout` splits clean images by (and a run's digest records).

    An image of a paired folder: the pair it is the target of (:func:`pair_name`);
    any other: its path below ``root``.
    """
    layouts: dict[Path, Layout | None] = {}
    names = []
    for image in images:
        pairs_folder = image.parent.parent
        if pairs_folder not in layouts:
            layouts[pairs_folder] = detect_layout(pairs_folder)
        layout = layouts[pairs_folder]
        relative = image.relative_to(root) if image.is_relative_to(root) else image
        names.append(relative.as_posix() if layout is None else pair_name(image, layout))
    return names


def pair_name(image: Path, layout: Layout) -> str:
    """The name of the pair ``image`` is the target of in a folder of ``layout``.

    A Raindrop ``gt/0_clean.png`` is pair ``0`` (:func:`lenspair.dataset.layouts.raindrop_key`);
    in the other layouts a pair is named by its files' stem, as the paired readers name it.
    """
    return raindrop_key(image) if layout == "raindrop" else image.stem
