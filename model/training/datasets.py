"""The training and validation sets of one run, from real pairs or clean images.

The entry points of ``lenspair train`` (and of the trade-off study): a paired
dataset becomes random crops of its training pairs (:mod:`lenspair.model.training.pairs`), a
folder of clean images becomes synthetic drops rendered on them
(:mod:`lenspair.model.training.synthetic`). When no validation split exists, a fraction
is held out by a hash of the names, so the split is deterministic and stable
as data is added.

Warnings about the data are logged at once, or kept in ``notes`` for
:func:`~lenspair.model.training.loop.fit` to log: ``lenspair train`` loads before
``RUN/train.log`` exists, and in every ``torchrun`` process.
"""

import hashlib
import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lenspair.core.errors import ImageIOError, listed
from lenspair.core.imageio import format_problem, image_header
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.readers import PairedDataset, detect_layout, open_paired
from lenspair.model.errors import ModelError
from lenspair.model.metrics import gaussian_window
from lenspair.model.training.config import DataConfig
from lenspair.model.training.pairs import (
    PairedCrops,
    PairSource,
    SubsetSource,
    channels_of,
    conversion_note,
)
from lenspair.model.training.synthetic import SyntheticDrops, drops_preset, find_clean_images

log = logging.getLogger(__name__)


@dataclass
class TrainData:
    """Training and validation sets of one run, and what they are.

    Attributes:
        train: random crops (``set_epoch`` selects the epoch's draws).
        val: whole images with fixed content.
        channels: channels of the network (1 or 3).
        description: where the pairs come from and how many, for the run config.
        synthetic: the drops preset for synthetic pretraining, else ``None``.

    """

    train: "PairedCrops | SyntheticDrops"
    val: "PairedCrops | SyntheticDrops"
    channels: int
    description: str
    synthetic: str | None = None


def _say(notes: list[str] | None, message: str) -> None:
    """Log a warning about the data now, or keep it in ``notes`` for the run to say."""
    if notes is None:
        log.warning("%s", message)
    else:
        notes.append(message)


def first_channels(dataset: PairSource) -> int:
    """Channels of the first pair's input (1 or 3)."""
    if len(dataset) == 0:
        raise ModelError("the dataset is empty")
    return channels_of(dataset[0].input)


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
    """Split images into (train, validation) by a hash of their path below ``root``.

    The choice depends on the file names only (not on a seed or the listing
    order), so adding images never moves an old one across the split. At
    least one image lands on each side when there are two or more.
    """
    if len(images) < 2:
        raise ModelError(f"{root}: need at least 2 clean images, found {len(images)}")

    def key(path: Path) -> str:
        relative = path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
        return hashlib.sha256(relative.encode("utf-8")).hexdigest()

    ranked = sorted(images, key=key)
    count = min(len(images) - 1, max(1, math.ceil(fraction * len(images))))
    holdout = set(ranked[:count])
    return [p for p in images if p not in holdout], [p for p in images if p in holdout]


def _names(source: PairSource) -> list[str]:
    names = getattr(source, "names", None)
    if names is not None:
        return [str(n) for n in names]
    return [source[i].name for i in range(len(source))]


NAMES_DIGEST = "pair names sha256"


def names_digest(train: PairSource, val: PairSource) -> str:
    """``pair names sha256 XXXXXXXXXXXX`` over both splits' names, for the run config.

    A dataset rebuilt in place (other pairs, another split) keeps its path;
    this tells a resume that its pairs changed (:func:`~lenspair.model.training.loop.fit`).
    """
    digest = hashlib.sha256()
    for source in (train, val):
        digest.update("\n".join(_names(source)).encode("utf-8") + b"\0")
    return f"{NAMES_DIGEST} {digest.hexdigest()[:12]}"


def paired_training_data(
    path: Path,
    data: DataConfig,
    channels: int | None,
    seed: int,
    notes: list[str] | None = None,
) -> TrainData:
    """Training pairs from any layout ``lenspair.dataset.readers`` reads.

    A dataset with splits trains on ``data.train_split`` and validates on
    ``data.val_split``; a split-less paired folder (or a dataset without the
    validation split, like Raindrop) holds out ``data.val_fraction`` of the
    training pairs, chosen by a hash of their names, and says so.

    Args:
        path: dataset root or paired folder.
        data: the ``data`` section of the run config.
        channels: network channels; ``None`` takes the first input's.
        seed: seed of crops and flips.
        notes: collects the warnings about the data instead of logging them
            (module docstring); ``None`` logs them now.

    Raises:
        DatasetError: unreadable dataset, a validation split that is there but
            cannot be opened (an unpaired file: refused, not replaced by train
            pairs), or pairs whose headers disagree
            (:meth:`~lenspair.dataset.readers.PairedDataset.check_headers`);
            ModelError: too few pairs.

    """
    path = Path(path)
    note = ""
    train_source: PairSource
    val_source: PairSource
    if detect_layout(path) is not None:
        every = open_paired(path)
        train_idx, val_idx = holdout_indices(_names(every), data.val_fraction, path)
        train_source, val_source = SubsetSource(every, train_idx), SubsetSource(every, val_idx)
        note = f"validation: {len(val_idx)} pairs held out by name hash"
    else:
        train_source = open_paired(path, data.train_split)
        # A val folder that is there but broken (an unpaired file) is refused by open_paired:
        # holding out train pairs instead cost training pairs and the real validation set.
        val_dir = path / data.val_split
        opened = open_paired(path, data.val_split) if val_dir.is_dir() else None
        if opened is not None and len(opened) > 0:
            val_source = opened
        else:  # none, or empty (dataset-build leaves a split empty on small inputs)
            why = f"{val_dir}: the split is empty" if opened is not None else f"no {val_dir}"
            every = train_source
            train_idx, val_idx = holdout_indices(_names(every), data.val_fraction, path)
            train_source, val_source = SubsetSource(every, train_idx), SubsetSource(every, val_idx)
            note = f"no {data.val_split!r} split ({why}); validation: {len(val_idx)} "
            note += f"{data.train_split!r} pairs held out by name hash"
            _say(notes, f"{path}: {note}")
    headers: dict[int, list[tuple[int, int, int, str]]] = {}  # id(dataset) -> pair headers
    for source in (train_source, val_source):  # before the first step, not in epoch 40
        paired = source.source if isinstance(source, SubsetSource) else source
        if isinstance(paired, PairedDataset) and id(paired) not in headers:
            headers[id(paired)] = paired.check_headers()
    check_training_images(train_source, headers, data.crop_size, channels, notes)
    resolved = channels or first_channels(train_source)
    if channel_note := conversion_note(resolved, first_channels(train_source), path):
        _say(notes, channel_note)
    train = PairedCrops(
        train_source,
        resolved,
        data.crop_size,
        data.hflip,
        data.vflip,
        seed=seed,
        anomaly_crops=data.anomaly_crops,
        substitute_unreadable=True,
    )
    val = PairedCrops(val_source, resolved, None, seed=seed, limit=data.max_val_images)
    description = f"{path} (train {len(train)} pairs, validation {len(val)} pairs"
    description += f"; {note}" if note else ""
    description += f"; {names_digest(train_source, val_source)})"
    return TrainData(train=train, val=val, channels=resolved, description=description)


def check_training_images(
    source: PairSource,
    headers: dict[int, list[tuple[int, int, int, str]]],
    crop_size: int | None,
    channels: int | None,
    notes: list[str] | None = None,
) -> None:
    """Every training pair holds a crop, and mixed channels are said: from headers, up front.

    A smaller image would stop the run whenever the sampler first drew it; a
    dataset of grey and colour pairs trains a network of one channel count
    and converts the others, which must not pass unsaid.

    Args:
        source: the training pairs.
        headers: ``id(dataset)`` -> its pairs' headers, as
            :meth:`~lenspair.dataset.readers.PairedDataset.check_headers`
            returned them (the files are not opened again).
        crop_size: ``data.crop_size`` (``None``: whole images).
        channels: the network's channels (``None``: the first pair's).
        notes: collects the mixed-channels warning instead of logging it.

    Raises:
        DatasetError: naming the first three images too small and how many there are.
    """
    paired = source.source if isinstance(source, SubsetSource) else source
    if not isinstance(paired, PairedDataset) or id(paired) not in headers:
        return
    indices = source.indices if isinstance(source, SubsetSource) else range(len(paired))
    small, counts = [], {1: 0, 3: 0}
    for index in indices:
        height, width, have = headers[id(paired)][index][:3]
        counts[have] = counts.get(have, 0) + 1
        if crop_size is not None and min(height, width) < crop_size:
            small.append(f"{paired.entries[index].input_path} ({width}x{height})")
    if small:
        raise DatasetError(
            f"{len(small)} training image(s) smaller than the {crop_size} px crop "
            f"(data.crop_size, --crop-size): {listed(small, 3, ', ')}; lower the crop or "
            "leave them out"
        )
    _warn_mixed(paired.root, "training pairs", counts, channels, notes)


def _warn_mixed(
    root: Path,
    what: str,
    counts: dict[int, int],
    channels: int | None,
    notes: list[str] | None,
) -> None:
    """Say that grey and colour images are mixed and how they are converted, when they are."""
    if counts.get(1) and counts.get(3):
        takes = f"{channels} channel(s)" if channels else "the first image's channels"
        _say(
            notes,
            f"{root}: the {what} mix {counts[1]} grey and {counts[3]} colour images; the "
            f"network takes {takes}, so the others are converted (colour to Rec. 601 luma, "
            "grey repeated); set model.channels to choose",
        )


def _check_clean_images(
    folder: Path,
    train: Sequence[Path],
    val: Sequence[Path],
    crop_size: int | None,
    notes: list[str] | None,
) -> dict[int, int]:
    """Headers of every clean image, and training ones hold a crop: before the first step.

    Held-out images smaller than validation's SSIM window are said here, not
    after the first epoch (validation leaves them out); all of them is an error.

    Returns:
        How many images have 1 and 3 channels.

    Raises:
        DatasetError: naming the first three problems and how many there are.
    """
    problems, training, counts = [], set(train), {1: 0, 3: 0}
    window = gaussian_window().numel()  # the SSIM window of VAL_CONVENTION
    unscored = []
    for path in [*train, *val]:
        try:
            height, width, have, kind = image_header(path)
        except ImageIOError as exc:
            problems.append(str(exc))
            continue
        counts[have] += 1
        if problem := format_problem(kind):
            problems.append(f"{path}: {problem}")
        elif crop_size is not None and path in training and min(height, width) < crop_size:
            problems.append(f"{path}: {width}x{height}, smaller than the {crop_size} px crop")
        elif path not in training and min(height, width) < window:
            unscored.append(f"{path} ({width}x{height})")
    if problems:
        raise DatasetError(f"{folder}: {len(problems)} unusable clean image(s): {listed(problems)}")
    if unscored:
        what = f"held-out clean image(s) smaller than validation's {window}x{window} SSIM window"
        if len(unscored) == len(val):
            raise DatasetError(f"{folder}: every one of the {len(val)} {what}: {listed(unscored)}")
        _say(notes, f"{folder}: validation leaves out {len(unscored)} {what}: {listed(unscored)}")
    return counts


def synthetic_training_data(
    folder: Path,
    data: DataConfig,
    channels: int | None,
    seed: int,
    notes: list[str] | None = None,
) -> TrainData:
    """Clean images with drops rendered on the fly, with a held-out validation subset.

    Args:
        folder: any folder of clean PNG/JPG/TIFF images, or a lenspair
            dataset (its ``target/`` images are used).
        data: the ``data`` section (``drops``, ``val_fraction``, crops, flips).
        channels: network channels; ``None`` takes the first image's.
        seed: seed of crops, flips and drops.
        notes: collects the warnings about the images instead of logging them
            (module docstring); ``None`` logs them now.

    """
    folder = Path(folder)
    images = find_clean_images(folder)
    train_images, val_images = split_holdout(images, data.val_fraction, folder)
    val_images = val_images[: data.max_val_images or len(val_images)]
    counts = _check_clean_images(folder, train_images, val_images, data.crop_size, notes)
    _warn_mixed(folder, "clean images", counts, channels, notes)
    resolved = channels or image_header(images[0])[2]
    effects = drops_preset(data.drops)
    train = SyntheticDrops.for_training(
        train_images, effects, resolved, data, seed, substitute_unreadable=True
    )
    # validation: drops only (see DataConfig.clear_share)
    val = SyntheticDrops(val_images, effects, resolved, None, seed=seed, fixed=True)
    description = (
        f"{folder} (synthetic {data.drops} drops on {len(train_images)} clean images, "
        f"validation {len(val)} held out by name hash)"
    )
    return TrainData(
        train=train, val=val, channels=resolved, description=description, synthetic=data.drops
    )
