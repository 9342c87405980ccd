"""The training and validation sets of one run, from real pairs or clean images.

The entry points of ``lenspair train`` (and of the trade-off study): a paired
dataset becomes random crops of its training pairs (:mod:`lenspair.model.training.pairs`), a
folder of clean images becomes synthetic drops rendered on them
(:mod:`lenspair.model.training.synthetic`). When no validation split exists, a fraction
is held out by a hash of the names (:mod:`lenspair.model.training.holdout`).

Warnings about the data are logged at once, or kept in ``notes`` for
:func:`~lenspair.model.training.loop.fit` to log: ``lenspair train`` loads before
``RUN/train.log`` exists, and in every ``torchrun`` process
(:func:`~lenspair.model.training.data_checks.warn_or_note`). The images are
checked before the first step (:mod:`lenspair.model.training.data_checks`).
"""

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lenspair.core.errors import LenspairError
from lenspair.core.spread import spread_indices
from lenspair.dataset.folder_notes import clean_bits
from lenspair.dataset.layouts import detect_layout
from lenspair.dataset.readers import open_paired
from lenspair.model.errors import ModelError
from lenspair.model.training.config import DataConfig
from lenspair.model.training.data_checks import (
    Headers,
    check_clean_images,
    check_training_images,
    check_validation_images,
    majority_channels,
    pair_headers,
    pairs_behind,
    warn_mixed,
    warn_or_note,
)
from lenspair.model.training.holdout import holdout_indices, holdout_names, split_holdout
from lenspair.model.training.pairs import (
    PairedCrops,
    PairSource,
    SubsetSource,
    channels_of,
    conversion_note,
)
from lenspair.model.training.synthetic import SyntheticDrops, drops_preset, find_clean_images


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


def first_channels(dataset: PairSource) -> int:
    """Channels of the first pair's input (1 or 3)."""
    if len(dataset) == 0:
        raise ModelError("the dataset is empty")
    return channels_of(dataset[0].input)


def _names(source: PairSource) -> list[str]:
    names = getattr(source, "names", None)
    if names is not None:
        return [str(n) for n in names]
    return [source[i].name for i in range(len(source))]


NAMES_DIGEST = "pair names sha256"


def names_digest(train: Sequence[str], val: Sequence[str]) -> str:
    """``pair names sha256 XXXXXXXXXXXX`` over both splits' names, for the run config.

    A dataset rebuilt in place (other pairs, another split) keeps its path;
    this tells a resume that its pairs changed (:func:`~lenspair.model.training.loop.fit`).
    A synthetic run's names are its clean images' hold-out names (:func:`holdout_names`).
    """
    digest = hashlib.sha256()
    for names in (train, val):
        digest.update("\n".join(names).encode("utf-8") + b"\0")
    return f"{NAMES_DIGEST} {digest.hexdigest()[:12]}"


def recorded_digest(data: str) -> str | None:
    """The pair-name digest in a run's data line (:func:`names_digest`), if it has one.

    Only it tells whether the pairs changed: the line also holds counts that
    other settings change (``data.max_val_images``).
    """
    _, found, rest = data.partition(NAMES_DIGEST + " ")
    return rest.split(")")[0].split(";")[0].strip() if found else None


def pairs_digest(path: Path, data: DataConfig) -> str | None:
    """The digest :func:`paired_training_data` would record for ``path``; None if not data.

    Reads the pairs' headers, not their pixels: what tells a copy of the data
    a run trained on (another path, the same pairs) from other data.
    """
    notes: list[str] = []
    try:
        train_source, val_source, _, _ = _good_split(Path(path), data, notes)
    except LenspairError:
        return None
    return recorded_digest(names_digest(_names(train_source), _names(val_source)))


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
        channels: network channels; ``None`` takes those of most training pairs.
        seed: seed of crops and flips.
        notes: collects the warnings about the data instead of logging them
            (module docstring); ``None`` logs them now.

    Raises:
        DatasetError: unreadable dataset, a validation split that is there but
            cannot be opened (an unpaired file: refused, not replaced by train
            pairs), more than half of the pairs bad (a pair whose headers
            disagree or cannot be read is otherwise left out, said:
            :func:`~lenspair.model.training.data_checks.pair_headers`), or
            validation pairs all too small to score;
            ModelError: too few pairs.

    """
    path = Path(path)
    # read before the first step, not in epoch 40
    train_source, val_source, note, (headers, left_out) = _good_split(path, data, notes)
    counts = check_training_images(train_source, headers, data.crop_size, channels, notes)
    check_validation_images(val_source, headers, data.max_val_images, notes)
    found = majority_channels(counts) if counts else first_channels(train_source)
    resolved = channels or found
    if channel_note := conversion_note(resolved, found, path):
        warn_or_note(notes, channel_note)
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
    description = f"{path} (train {len(train)} pairs, validation {_of(len(val), len(val_source))}"
    description += f"; {note}" if note else ""
    description += f"; {left_out} bad pairs left out" if left_out else ""
    description += f"; {names_digest(_names(train_source), _names(val_source))})"
    return TrainData(train=train, val=val, channels=resolved, description=description)


def _good_split(
    path: Path, data: DataConfig, notes: list[str] | None
) -> tuple[PairSource, PairSource, str, tuple[Headers, int]]:
    """:func:`_split_sources` without the bad pairs, and the good pairs' headers.

    Where every pair held out by name hash is bad, the hold-out is chosen
    again among the good pairs, and this is said: validation had been left
    empty, and the run refused with "needs at least one validation pair"
    while the warning naming the bad pairs went unsaid.

    Returns:
        ``(train, validation, note, (headers, bad pairs left out))``.
    """
    train_source, val_source, note = _split_sources(path, data, notes)
    listed_pairs = len(train_source) + len(val_source)
    (train_source, val_source), headers = pair_headers((train_source, val_source), notes)
    left_out = listed_pairs - len(train_source) - len(val_source)
    if note and len(val_source) == 0 and len(train_source) > 1:
        paired, indices = pairs_behind(train_source)
        train_idx, val_idx = holdout_indices(_names(train_source), data.val_fraction, path)
        train_source = SubsetSource(paired, [indices[i] for i in train_idx])
        val_source = SubsetSource(paired, [indices[i] for i in val_idx])
        note = f"validation: {len(val_idx)} pairs held out by name hash among the good ones"
        warn_or_note(notes, f"{path}: every pair held out for validation is bad; {note}")
    return train_source, val_source, note, (headers, left_out)


def _of(used: int, total: int) -> str:
    """``5 pairs``, or ``5 of 9 pairs`` when ``data.max_val_images`` leaves some out."""
    return f"{used} pairs" if used == total else f"{used} of {total} pairs"


def _split_sources(
    path: Path, data: DataConfig, notes: list[str] | None
) -> tuple[PairSource, PairSource, str]:
    """The training and validation pairs of ``path``, and how validation was chosen.

    Returns:
        ``(train, validation, note)``: ``note`` says how many pairs were held
        out by name hash, and is empty when the dataset's validation split is used.

    Raises:
        DatasetError: an unreadable dataset or validation split (see
            :func:`paired_training_data`); ModelError: too few pairs to hold out.
    """
    note = ""
    train_source: PairSource
    val_source: PairSource
    if detect_layout(path) is not None:
        every = open_paired(path, notes=notes)
        train_idx, val_idx = holdout_indices(_names(every), data.val_fraction, path)
        train_source, val_source = SubsetSource(every, train_idx), SubsetSource(every, val_idx)
        note = f"validation: {len(val_idx)} pairs held out by name hash"
    else:
        train_source = open_paired(path, data.train_split, notes=notes)
        val_dir = path / data.val_split
        opened = validation_split(path, data, notes)
        if opened is not None:
            val_source = opened
        else:  # none, or empty (dataset-build leaves a split empty on small inputs)
            why = f"{val_dir}: the split is empty" if val_dir.is_dir() else f"no {val_dir}"
            every = train_source
            train_idx, val_idx = holdout_indices(_names(every), data.val_fraction, path)
            train_source, val_source = SubsetSource(every, train_idx), SubsetSource(every, val_idx)
            note = f"no {data.val_split!r} split ({why}); validation: {len(val_idx)} "
            note += f"{data.train_split!r} pairs held out by name hash"
            warn_or_note(notes, f"{path}: {note}")
    return train_source, val_source, note


def validation_split(path: Path, data: DataConfig, notes: list[str] | None) -> PairSource | None:
    """A dataset's ``data.val_split`` when it holds pairs; None: training holds its own out.

    None when the split is missing or empty (dataset-build leaves a split
    empty on small inputs): training then holds validation pairs out of its
    train split by name hash.

    Raises:
        DatasetError: the split is there but broken (an unpaired file): holding
            out train pairs instead cost training pairs and the real validation set.
    """
    split = path / data.val_split
    if not split.is_dir():
        return None
    # a folder holding no file at all (an empty val/, or empty input/ and target/): the
    # reader refused it ("holds several splits; choose one of train", "no images")
    if not any(p.is_file() and not p.name.startswith(".") for p in split.rglob("*")):
        return None
    opened = open_paired(path, data.val_split, notes=notes)
    return opened if len(opened) > 0 else None


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
        channels: network channels; ``None`` takes those of most images.
        seed: seed of crops, flips and drops.
        notes: collects the warnings about the images instead of logging them
            (module docstring); ``None`` logs them now.

    """
    folder = Path(folder)
    images = find_clean_images(folder)
    train_images, held = split_holdout(images, data.val_fraction, folder)
    held_out = len(held)  # spread over the folders, as validation pairs are
    val_images = [held[i] for i in spread_indices(held_out, data.max_val_images)]
    counts = check_clean_images(folder, train_images, val_images, data.crop_size, notes)
    warn_mixed(folder, "clean images", counts, channels, notes)
    resolved = channels or majority_channels(counts)
    effects = drops_preset(data.drops)
    bits = clean_bits(folder, images, notes)
    train = SyntheticDrops.for_training(
        train_images, effects, resolved, data, seed, substitute_unreadable=True, bits=bits
    )
    # validation: drops only (see DataConfig.clear_share)
    val = SyntheticDrops(val_images, effects, resolved, None, seed=seed, fixed=True, bits=bits)
    digest = names_digest(holdout_names(train_images, folder), holdout_names(held, folder))
    description = (
        f"{folder} (synthetic {data.drops} drops on {len(train_images)} clean images, "
        f"validation {len(val)}{'' if len(val) == held_out else f' of {held_out}'} held out "
        f"by name hash; {digest})"
    )
    return TrainData(
        train=train, val=val, channels=resolved, description=description, synthetic=data.drops
    )
