"""Torch datasets over paired images and over clean images with rendered drops.

Conventions: readers hand out ``uint8``/``uint16`` arrays ``(H, W)`` or
``(H, W, 3)``; the datasets here return float32 tensors ``(C, H, W)`` in
``[0, 1]`` (``C`` = 1 mono, 3 RGB; converted with Rec. 601 luma or channel
repetition to what the network expects) and a ``valid`` map ``(1, H, W)``
that is 0 where the pair is not trustworthy (``mask`` > 0) and 1 elsewhere.

Every random choice (crop position, flips, rendered drops) comes from a
generator seeded by ``(seed, epoch, index)``: the same item of the same epoch
is identical whatever the number of workers or processes, and a resumed run
sees exactly the batches it would have seen.
"""

import hashlib
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TypedDict

import numpy as np
import torch
from torch.utils.data import Dataset

from lenspair.imageio import from_float, read_image, to_float
from model.config import DataConfig
from model.errors import ModelError
from simulate.effects.spec import (
    SHARP_DROPS,
    BrightnessSpec,
    DefocusSpec,
    EffectsSpec,
    RaindropsSpec,
)
from simulate.render import render_effects

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
CLEAN_FOLDER_NAMES = ("target", "gt", "clean")
_VAL_EPOCH = -1  # fixed seed slot for validation items: the same drops every time

OUR_DROPS = EffectsSpec(
    raindrops=RaindropsSpec(), defocus=DefocusSpec(), brightness=BrightnessSpec()
)
"""Our synthetic drops: lens-like drops, defocused glass, some drops brightened."""

DROPS_PRESETS: dict[str, EffectsSpec] = {"ours": OUR_DROPS, "sharp": SHARP_DROPS}
"""Synthetic-drop presets by name (``--drops``)."""


class PairItem(Protocol):
    """One pair from a reader (``dataset.readers``)."""

    @property
    def input(self) -> np.ndarray: ...  # noqa: D102
    @property
    def target(self) -> np.ndarray: ...  # noqa: D102
    @property
    def name(self) -> str: ...  # noqa: D102
    @property
    def mask(self) -> np.ndarray | None: ...  # noqa: D102
    @property
    def difficulty(self) -> str | None: ...  # noqa: D102


class PairSource(Protocol):
    """A sized, indexable collection of pairs (``dataset.readers.PairedDataset``)."""

    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> PairItem: ...


class Sample(TypedDict):
    """One training/validation sample (batched by the default collate)."""

    input: torch.Tensor
    target: torch.Tensor
    valid: torch.Tensor
    name: str


def drops_preset(name: str) -> EffectsSpec:
    """The effects of a synthetic-drop preset; unknown names list the valid ones."""
    try:
        return DROPS_PRESETS[name]
    except KeyError:
        valid = ", ".join(DROPS_PRESETS)
        raise ModelError(f"unknown drops preset {name!r}; valid presets: {valid}") from None


def to_channels(image: np.ndarray, channels: int) -> np.ndarray:
    """Float image ``(H, W)`` or ``(H, W, 3)`` to ``(H, W, channels)`` float32.

    RGB to mono uses Rec. 601 luma (0.299, 0.587, 0.114) on the encoded
    values, as OpenCV's grey conversion does; mono to RGB repeats the channel.
    """
    if image.ndim == 2:
        image = image[:, :, None]
    have = image.shape[2]
    if have == channels:
        return np.ascontiguousarray(image, dtype=np.float32)
    if have == 3 and channels == 1:
        weights = np.array([0.299, 0.587, 0.114], dtype=np.float32)
        return np.ascontiguousarray((image @ weights)[:, :, None], dtype=np.float32)
    if have == 1 and channels == 3:
        return np.ascontiguousarray(np.repeat(image, 3, axis=2), dtype=np.float32)
    raise ModelError(f"cannot convert a {have}-channel image to {channels} channels")


def to_tensor(image: np.ndarray, channels: int) -> torch.Tensor:
    """``uint8``/``uint16`` ``(H, W[, 3])`` to float32 ``(channels, H, W)`` in [0, 1]."""
    array = to_channels(to_float(image), channels)
    return torch.from_numpy(np.ascontiguousarray(array.transpose(2, 0, 1)))


def channels_of(image: np.ndarray) -> int:
    """1 for a mono image ``(H, W)``, 3 for RGB ``(H, W, 3)``."""
    return 1 if image.ndim == 2 else int(image.shape[2])


def item_rng(seed: int, epoch: int, index: int) -> np.random.Generator:
    """The generator of one item of one epoch (independent of workers and ranks)."""
    return np.random.default_rng([seed, epoch + 1, index])


def crop_box(
    height: int, width: int, crop_size: int | None, rng: np.random.Generator
) -> tuple[int, int, int, int]:
    """A random ``(top, left, height, width)`` crop; the whole image when ``crop_size`` is None.

    Raises:
        ModelError: the image is smaller than the crop.

    """
    if crop_size is None:
        return 0, 0, height, width
    if height < crop_size or width < crop_size:
        raise ModelError(
            f"crop of {crop_size} px does not fit an image of {width}x{height}; "
            "lower data.crop_size"
        )
    top = int(rng.integers(0, height - crop_size + 1))
    left = int(rng.integers(0, width - crop_size + 1))
    return top, left, crop_size, crop_size


def _flip(
    tensors: Sequence[torch.Tensor], rng: np.random.Generator, h: bool, v: bool
) -> list[torch.Tensor]:
    # Always draw both decisions so the stream does not depend on the flags.
    flip_h, flip_v = bool(rng.random() < 0.5), bool(rng.random() < 0.5)
    dims = [d for d, on in ((-1, h and flip_h), (-2, v and flip_v)) if on]
    return [t.flip(dims) if dims else t for t in tensors]


class PairedCrops(Dataset[Sample]):
    """Random crops and flips of real pairs (training), or whole pairs (validation).

    Args:
        source: pairs from ``dataset.readers.open_paired``.
        channels: channels the network takes (1 or 3).
        crop_size: side of the random square crop; ``None`` keeps whole images.
        hflip: random horizontal flips.
        vflip: random vertical flips.
        seed: seed of the crops and flips.
        limit: use only the first ``limit`` pairs (validation budget).

    """

    def __init__(
        self,
        source: PairSource,
        channels: int,
        crop_size: int | None = None,
        hflip: bool = False,
        vflip: bool = False,
        seed: int = 0,
        limit: int | None = None,
    ) -> None:
        self.source = source
        self.channels = channels
        self.crop_size = crop_size
        self.hflip, self.vflip = hflip, vflip
        self.seed = seed
        self.epoch = 0
        self.length = len(source) if limit is None else min(limit, len(source))

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose crops and flips ``__getitem__`` returns."""
        self.epoch = epoch

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> Sample:
        item = self.source[index]
        rng = item_rng(self.seed, self.epoch, index)
        height, width = item.input.shape[:2]
        if item.target.shape[:2] != (height, width):
            raise ModelError(
                f"{item.name}: input {item.input.shape} and target {item.target.shape} differ"
            )
        top, left, h, w = crop_box(height, width, self.crop_size, rng)
        window = (slice(top, top + h), slice(left, left + w))
        tensors = [
            to_tensor(item.input[window], self.channels),
            to_tensor(item.target[window], self.channels),
            _valid_map(item.mask, window, h, w),
        ]
        tensors = _flip(tensors, rng, self.hflip, self.vflip)
        return Sample(input=tensors[0], target=tensors[1], valid=tensors[2], name=item.name)


def _valid_map(
    mask: np.ndarray | None, window: tuple[slice, slice], height: int, width: int
) -> torch.Tensor:
    if mask is None:
        return torch.ones(1, height, width)
    part = mask[window]
    if part.ndim == 3:
        part = part.max(axis=2)
    return torch.from_numpy((part == 0).astype(np.float32))[None]


def find_clean_images(folder: Path) -> list[Path]:
    """Clean images under ``folder`` for synthetic pretraining, sorted.

    When the folder holds ``target/`` (or ``gt/``, ``clean/``) sub-folders, as
    a lenspair dataset does, only the images in them are used (for a dataset
    root, only those of ``train/``, so validation and test images stay
    unseen); otherwise every PNG/JPG/TIFF below ``folder``.

    Raises:
        ModelError: no image found.

    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ModelError(f"{folder}: not a folder of clean images")
    if (folder / "train").is_dir() and any(
        (folder / "train" / name).is_dir() for name in CLEAN_FOLDER_NAMES
    ):
        folder = folder / "train"  # a dataset root: never pretrain on val/test targets
    images = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    clean = [p for p in images if p.parent.name.lower() in CLEAN_FOLDER_NAMES]
    chosen = clean or images
    if not chosen:
        raise ModelError(f"{folder}: no PNG/JPG/TIFF images found")
    return chosen


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


class SyntheticDrops(Dataset[Sample]):
    """Clean images with drops rendered on the fly (synthetic pretraining).

    Training items are random crops with new drops every epoch; validation
    items (``fixed=True``) are whole images with the same drops every time.

    Args:
        images: clean image files (8- or 16-bit, mono or RGB).
        effects: what to render (``OUR_DROPS`` or ``SHARP_DROPS``).
        channels: channels the network takes.
        crop_size: random crop side; ``None`` keeps whole images.
        hflip: random horizontal flips.
        vflip: random vertical flips.
        seed: seed of crops, flips and drops.
        fixed: validation mode: drops do not change with the epoch.

    """

    def __init__(
        self,
        images: Sequence[Path],
        effects: EffectsSpec,
        channels: int,
        crop_size: int | None = None,
        hflip: bool = False,
        vflip: bool = False,
        seed: int = 0,
        fixed: bool = False,
    ) -> None:
        self.images = list(images)
        self.effects = effects
        self.channels = channels
        self.crop_size = crop_size
        self.hflip, self.vflip = hflip, vflip
        self.seed = seed
        self.fixed = fixed
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose crops and drops ``__getitem__`` returns."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int) -> Sample:
        path = self.images[index]
        rng = item_rng(self.seed, _VAL_EPOCH if self.fixed else self.epoch, index)
        clean = read_image(path)
        if channels_of(clean) != self.channels:
            clean = from_float(to_channels(to_float(clean), self.channels), clean.dtype)
            if self.channels == 1:
                clean = clean[:, :, 0]
        # Render on the whole frame, then crop: drop density and size match real frames.
        obstructed, _ = render_effects(clean, self.effects, rng)
        top, left, h, w = crop_box(clean.shape[0], clean.shape[1], self.crop_size, rng)
        window = (slice(top, top + h), slice(left, left + w))
        tensors = [
            to_tensor(obstructed[window], self.channels),
            to_tensor(clean[window], self.channels),
        ]
        tensors = _flip(tensors, rng, self.hflip, self.vflip)
        return Sample(
            input=tensors[0], target=tensors[1], valid=torch.ones(1, h, w), name=path.name
        )


def first_channels(dataset: PairSource) -> int:
    """Channels of the first pair's input (1 or 3)."""
    if len(dataset) == 0:
        raise ModelError("the dataset is empty")
    return channels_of(dataset[0].input)


class SubsetSource:
    """Some pairs of a source, by index (a deterministic hold-out)."""

    def __init__(self, source: PairSource, indices: Sequence[int]) -> None:
        self.source = source
        self.indices = list(indices)

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, index: int) -> PairItem:
        return self.source[self.indices[index]]


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


def _hash_rank(name: str) -> str:
    return hashlib.sha256(name.encode("utf-8")).hexdigest()


def holdout_indices(names: Sequence[str], fraction: float) -> tuple[list[int], list[int]]:
    """Split indices into (train, validation) by a hash of each name (deterministic).

    Raises:
        ModelError: fewer than two names.

    """
    if len(names) < 2:
        raise ModelError(f"need at least 2 pairs to hold out a validation set, got {len(names)}")
    count = min(len(names) - 1, max(1, math.ceil(fraction * len(names))))
    ranked = sorted(range(len(names)), key=lambda i: (_hash_rank(names[i]), i))
    held = set(ranked[:count])
    return [i for i in range(len(names)) if i not in held], sorted(held)


def _names(source: PairSource) -> list[str]:
    names = getattr(source, "names", None)
    if names is not None:
        return [str(n) for n in names]
    return [source[i].name for i in range(len(source))]


def paired_training_data(
    path: Path,
    data: DataConfig,
    channels: int | None,
    seed: int,
) -> TrainData:
    """Training pairs from any layout ``dataset.readers`` reads.

    A dataset with splits trains on ``data.train_split`` and validates on
    ``data.val_split``; a split-less paired folder (or a dataset without the
    validation split, like Raindrop) holds out ``data.val_fraction`` of the
    training pairs, chosen by a hash of their names, and says so.

    Args:
        path: dataset root or paired folder.
        data: the ``data`` section of the run config.
        channels: network channels; ``None`` takes the first input's.
        seed: seed of crops and flips.

    Raises:
        DatasetError: unreadable dataset; ModelError: too few pairs.

    """
    from dataset.errors import DatasetError
    from dataset.readers import detect_layout, open_paired

    path = Path(path)
    note = ""
    train_source: PairSource
    val_source: PairSource
    if detect_layout(path) is not None:
        every = open_paired(path)
        train_idx, val_idx = holdout_indices(_names(every), data.val_fraction)
        train_source, val_source = SubsetSource(every, train_idx), SubsetSource(every, val_idx)
        note = f"validation: {len(val_idx)} pairs held out by name hash"
    else:
        train_source = open_paired(path, data.train_split)
        try:
            val_source = open_paired(path, data.val_split)
        except DatasetError as exc:
            every = train_source
            train_idx, val_idx = holdout_indices(_names(every), data.val_fraction)
            train_source, val_source = SubsetSource(every, train_idx), SubsetSource(every, val_idx)
            note = f"no {data.val_split!r} split ({exc}); validation: {len(val_idx)} "
            note += f"{data.train_split!r} pairs held out by name hash"
            log.warning("%s: %s", path, note)
    resolved = channels or first_channels(train_source)
    train = PairedCrops(train_source, resolved, data.crop_size, data.hflip, data.vflip, seed=seed)
    val = PairedCrops(val_source, resolved, None, seed=seed, limit=data.max_val_images)
    description = f"{path} (train {len(train)} pairs, validation {len(val)} pairs"
    description += f"; {note})" if note else ")"
    return TrainData(train=train, val=val, channels=resolved, description=description)


def synthetic_training_data(
    folder: Path,
    data: DataConfig,
    channels: int | None,
    seed: int,
) -> TrainData:
    """Clean images with drops rendered on the fly, with a held-out validation subset.

    Args:
        folder: any folder of clean PNG/JPG/TIFF images, or a lenspair
            dataset (its ``target/`` images are used).
        data: the ``data`` section (``drops``, ``val_fraction``, crops, flips).
        channels: network channels; ``None`` takes the first image's.
        seed: seed of crops, flips and drops.

    """
    folder = Path(folder)
    images = find_clean_images(folder)
    train_images, val_images = split_holdout(images, data.val_fraction, folder)
    resolved = channels or channels_of(read_image(images[0]))
    effects = drops_preset(data.drops)
    train = SyntheticDrops(
        train_images, effects, resolved, data.crop_size, data.hflip, data.vflip, seed=seed
    )
    limit = data.max_val_images or len(val_images)
    val = SyntheticDrops(val_images[:limit], effects, resolved, None, seed=seed, fixed=True)
    description = (
        f"{folder} (synthetic {data.drops} drops on {len(train_images)} clean images, "
        f"validation {len(val)} held out by name hash)"
    )
    return TrainData(
        train=train, val=val, channels=resolved, description=description, synthetic=data.drops
    )


def open_eval_pairs(path: Path, split: str) -> PairSource:
    """Pairs to evaluate: ``path`` itself when it is a paired folder, else its ``split``."""
    from dataset.readers import detect_layout, open_paired

    path = Path(path)
    return open_paired(path) if detect_layout(path) is not None else open_paired(path, split)
