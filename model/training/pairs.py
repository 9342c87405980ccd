"""Torch datasets over paired images: tensor conventions, random crops and flips.

Conventions: readers hand out ``uint8``/``uint16`` arrays ``(H, W)`` or
``(H, W, 3)``; the datasets of ``model`` (here and in
:mod:`lenspair.model.training.synthetic`) return float32 tensors ``(C, H, W)`` in
``[0, 1]`` (``C`` = 1 mono, 3 RGB; converted with Rec. 601 luma or channel
repetition to what the network expects) and a ``valid`` map ``(1, H, W)``
that is 0 where the pair is not trustworthy (``mask`` > 0) and 1 elsewhere.

Every random choice (crop position, flips, rendered drops) comes from a
generator seeded by ``(seed, epoch, index)``: the same item of the same epoch
is identical whatever the number of workers or processes, and a resumed run
sees exactly the batches it would have seen.
"""

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TypedDict, TypeVar

import numpy as np
import torch
from torch.utils.data import Dataset

from lenspair.core.errors import LenspairError
from lenspair.core.pixels import to_float
from lenspair.core.quality import anomaly_cells, to_grey
from lenspair.core.spread import spread_indices
from lenspair.dataset.config import CurationConfig
from lenspair.dataset.curation import channel_max
from lenspair.dataset.layouts import detect_layout
from lenspair.dataset.readers import open_paired
from lenspair.model.errors import ModelError

log = logging.getLogger(__name__)

T = TypeVar("T")


class PairItem(Protocol):
    """One pair from a reader (``lenspair.dataset.readers``)."""

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
    """A sized, indexable collection of pairs (``lenspair.dataset.readers.PairedDataset``)."""

    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> PairItem: ...


@dataclass(frozen=True)
class Unread:
    """A pair that could not be read, and why (the reason names the file)."""

    index: int
    reason: str


class SubsetSource:
    """Some pairs of a source, by index, in that order (a hold-out, the readable ones)."""

    def __init__(self, source: PairSource, indices: Sequence[int]) -> None:
        self.source = source
        self.indices = list(indices)
        self.root = getattr(source, "root", None)

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, index: int) -> PairItem:
        return self.source[self.indices[index]]

    @property
    def names(self) -> list[str] | None:
        """The pairs' names, in order, when the source lists them without reading."""
        names = getattr(self.source, "names", None)
        return None if names is None else [str(names[i]) for i in self.indices]


def read_pair(pairs: PairSource, index: int, unread: list[Unread]) -> PairItem | None:
    """Pair ``index``, or ``None`` after logging and recording why it cannot be read.

    One bad pair (a truncated file, input and target of different sizes)
    costs only itself: the caller goes on with the others and reports
    ``unread`` at the end, so that every pair is accounted for.
    """
    try:
        return pairs[index]
    except LenspairError as exc:
        log.warning("skipped pair %d: %s", index, exc)
        unread.append(Unread(index, str(exc)))
        return None


class Sample(TypedDict):
    """One training/validation sample (batched by the default collate)."""

    input: torch.Tensor
    target: torch.Tensor
    valid: torch.Tensor
    name: str


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


def conversion_note(network_channels: int, data_channels: int, where: object) -> str | None:
    """The warning to give when a network's channels differ from its data's, else None.

    The conversion itself (:func:`to_channels`) is well defined, but a mono
    network scored on colour pairs (or the reverse) is seldom what was meant,
    so it is never silent.
    """
    if network_channels == data_channels:
        return None
    conversion = "luma (Rec. 601)" if network_channels == 1 else "three equal channels"
    return (
        f"{where}: the network takes {network_channels} channel(s) and the images have "
        f"{data_channels}: they are converted to {conversion}"
    )


def channels_of(image: np.ndarray) -> int:
    """1 for a mono image ``(H, W)``, 3 for RGB ``(H, W, 3)``."""
    return 1 if image.ndim == 2 else int(image.shape[2])


ANOMALY_DELTA = CurationConfig.anomaly_delta
"""Grey difference (in [0, 1]) that makes a cell anomalous for :func:`anomaly_crop_box`:
``dataset-build``'s default ``curation.anomaly_delta``, which decides that a pair is clean."""


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


def anomaly_crop_box(
    item: PairItem, crop_size: int, rng: np.random.Generator
) -> tuple[int, int, int, int] | None:
    """A ``(top, left, height, width)`` crop holding pixels where the pair differs.

    A cell is drawn uniformly among the anomalous cells of
    :func:`lenspair.core.quality.anomaly_cells` (threshold :data:`ANOMALY_DELTA`,
    untrustworthy pixels left out), and the crop uniformly among those that
    hold the whole cell: large drops are drawn more often than small ones, and
    no drop always sits in the crop's centre. None when the pair shows no
    anomaly (a clean pair): the caller crops at random.
    """
    height, width = item.input.shape[:2]
    valid = None if item.mask is None else channel_max(item.mask) == 0
    anomalous, _ = anomaly_cells(to_grey(item.input), to_grey(item.target), valid, ANOMALY_DELTA)
    rows, cols = np.nonzero(anomalous)
    if rows.size == 0:
        return None
    pick = int(rng.integers(rows.size))
    top = _around(int(rows[pick]), height / anomalous.shape[0], height, crop_size, rng)
    left = _around(int(cols[pick]), width / anomalous.shape[1], width, crop_size, rng)
    return top, left, crop_size, crop_size


def _around(cell: int, scale: float, size: int, crop_size: int, rng: np.random.Generator) -> int:
    """A crop start, drawn uniformly among those whose crop holds the whole cell.

    A cell is the area average of the pixels ``[cell * scale, (cell + 1) * scale)``,
    so a crop holding them all holds what made the cell anomalous.
    """
    first, end = math.floor(cell * scale), math.ceil((cell + 1) * scale)
    low, high = max(0, end - crop_size), min(first, size - crop_size)
    if low > high:  # a cell wider than the crop: hold its start
        return min(first, size - crop_size)
    return int(rng.integers(low, high + 1))


def random_flip(
    tensors: Sequence[torch.Tensor], rng: np.random.Generator, h: bool, v: bool
) -> list[torch.Tensor]:
    """Flip all ``tensors`` alike: horizontally and/or vertically at random.

    Args:
        tensors: tensors ``(..., H, W)`` of one sample (input, target, valid map).
        rng: the item's generator; two draws are taken from it.
        h: allow horizontal flips (each with probability 1/2).
        v: allow vertical flips (each with probability 1/2).

    Returns:
        The tensors, flipped the same way (unchanged when no flip is drawn).

    """
    # Always draw both decisions so the stream does not depend on the flags.
    flip_h, flip_v = bool(rng.random() < 0.5), bool(rng.random() < 0.5)
    dims = [d for d, on in ((-1, h and flip_h), (-2, v and flip_v)) if on]
    return [t.flip(dims) if dims else t for t in tensors]


class PairedCrops(Dataset[Sample]):
    """Random crops and flips of real pairs (training), or whole pairs (validation).

    Args:
        source: pairs from ``lenspair.dataset.readers.open_paired``.
        channels: channels the network takes (1 or 3).
        crop_size: side of the random square crop; ``None`` keeps whole images.
        hflip: random horizontal flips.
        vflip: random vertical flips.
        seed: seed of the crops and flips.
        limit: use only ``limit`` pairs, spread evenly over the source
            (:func:`~lenspair.core.spread.spread_indices`; validation's
            budget): the first ``limit`` by name were one or two recordings of
            ``<recording>_<t_ns>`` names, so ``best.pt`` and early stopping
            judged the network on those alone.
        anomaly_crops: share of crops that hold a pixel where input and
            target differ (:func:`anomaly_crop_box`); the others, and every
            crop of a clean pair, lie anywhere.
        substitute_unreadable: a pair that cannot be read (a file truncated
            or damaged after ``train`` checked the headers) is replaced by the
            next readable one, with a warning once per pair (once per epoch
            with loader workers, whose copies of the dataset live an epoch),
            instead of ending the run mid-epoch (training); validation reports
            its own.

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
        anomaly_crops: float = 0.0,
        substitute_unreadable: bool = False,
    ) -> None:
        if not 0.0 <= anomaly_crops <= 1.0:
            raise ValueError(f"anomaly_crops: expected 0..1, got {anomaly_crops}")
        self.source = source
        self.anomaly_crops = anomaly_crops
        self.substitute_unreadable = substitute_unreadable
        self.unreadable: set[int] = set()  # said once each (per worker process)
        self.channels = channels
        self.crop_size = crop_size
        self.hflip, self.vflip = hflip, vflip
        self.seed = seed
        self.epoch = 0
        self.indices = spread_indices(len(source), limit)  # position -> index in source
        self.length = len(self.indices)

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose crops and flips ``__getitem__`` returns."""
        self.epoch = epoch

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> Sample:
        item = self._read(index)
        rng = item_rng(self.seed, self.epoch, index)
        height, width = item.input.shape[:2]
        if item.target.shape[:2] != (height, width):
            raise ModelError(
                f"{item.name}: input {item.input.shape} and target {item.target.shape} differ"
            )
        box = None
        # drawn only when asked: a share of 0 keeps the crops of earlier versions
        on_anomaly = self.anomaly_crops > 0 and bool(rng.random() < self.anomaly_crops)
        if on_anomaly and self.crop_size is not None and min(height, width) >= self.crop_size:
            box = anomaly_crop_box(item, self.crop_size, rng)
        top, left, h, w = box or crop_box(height, width, self.crop_size, rng)
        window = (slice(top, top + h), slice(left, left + w))
        tensors = [
            to_tensor(item.input[window], self.channels),
            to_tensor(item.target[window], self.channels),
            _valid_map(item.mask, window, h, w),
        ]
        tensors = random_flip(tensors, rng, self.hflip, self.vflip)
        return Sample(input=tensors[0], target=tensors[1], valid=tensors[2], name=item.name)

    def _read(self, index: int) -> PairItem:
        if not self.substitute_unreadable:
            return self.source[self.indices[index]]
        return read_substituting(
            lambda position: self.source[self.indices[position]],
            index,
            self.length,
            self.unreadable,
        )


def read_substituting(
    read: Callable[[int], T], index: int, length: int, unreadable: set[int], what: str = "pair"
) -> T:
    """``read(index)``, or when it fails, the next index (cyclically) that reads.

    A training item that cannot be read (a file truncated or damaged after
    the headers were checked) must not end a run mid-epoch: it is replaced,
    with a warning once per index (``unreadable`` remembers them; once per
    epoch with loader workers, whose copies of the dataset live an epoch).

    Raises:
        ModelError: no item of the ``length`` can be read any more.
    """
    for step in range(length):
        candidate = (index + step) % length
        if candidate in unreadable:
            continue
        try:
            return read(candidate)
        except LenspairError as exc:
            unreadable.add(candidate)
            log.warning("training goes on without %s %d: %s", what, candidate, exc)
    raise ModelError(f"no training {what} can be read any more (see the warnings above)")


def _valid_map(
    mask: np.ndarray | None, window: tuple[slice, slice], height: int, width: int
) -> torch.Tensor:
    if mask is None:
        return torch.ones(1, height, width)
    return torch.from_numpy((channel_max(mask[window]) == 0).astype(np.float32))[None]


def open_eval_pairs(path: Path, split: str) -> PairSource:
    """Pairs to evaluate: ``path`` itself when it is a paired folder, else its ``split``."""
    path = Path(path)
    return open_paired(path) if detect_layout(path) is not None else open_paired(path, split)
