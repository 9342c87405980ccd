"""Synthetic pretraining data: clean images with drops rendered on the fly.

The drop presets (``--drops``), the search for clean images in a folder or a
lenspair dataset, and the dataset that renders drops on them. Items follow the
conventions of :mod:`lenspair.model.training.pairs`: float32 ``(C, H, W)`` in ``[0, 1]``, a
``valid`` map of ones, and every random choice (crop, flips, drops) drawn
from a generator seeded by ``(seed, epoch, index)``.
"""

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from lenspair.core.bitdepth import widen
from lenspair.core.imageio import read_image
from lenspair.core.pixels import from_float, to_float
from lenspair.model.training.config import DataConfig
from lenspair.model.training.pairs import (
    Sample,
    channels_of,
    crop_box,
    item_rng,
    random_flip,
    read_substituting,
    to_channels,
    to_tensor,
)
from lenspair.simulate.effects.spec import EffectsSpec
from lenspair.simulate.presets import DROPS_PRESETS as DROPS_PRESETS
from lenspair.simulate.presets import OUR_DROPS as OUR_DROPS
from lenspair.simulate.presets import drops_preset as drops_preset
from lenspair.simulate.presets import find_clean_images as find_clean_images
from lenspair.simulate.render import render_effects

_VAL_EPOCH = -1  # fixed seed slot for validation items: the same drops every time


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
        substitute_unreadable: an image that cannot be read (truncated or
            damaged after ``train`` checked the headers) is replaced by the
            next readable one, with a warning, instead of ending the run
            (training; see :func:`~lenspair.model.training.pairs.read_substituting`);
            validation reports its own.
        bits: what the 16-bit images hold (10, 12 or 16,
            :func:`~lenspair.dataset.folder_notes.clean_bits`): below 16 they are
            read widened to the full 16-bit range (:func:`lenspair.core.bitdepth.widen`).
        clear_share: share of items seen through clear glass: no effect is
            rendered and the input is the target, so that the network learns
            to leave frames without an anomaly as they are (see
            :attr:`~lenspair.model.training.config.DataConfig.clear_share`).
            Training draws it per item and epoch; validation (``fixed``)
            spreads it evenly over the items: with a share of ``1/3``, items
            2, 5, 8, ... are clear (so repeat each image three times in a row,
            as :func:`~lenspair.model.training.pretrained.validation_drops` does,
            for each to be seen clear once).

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
        substitute_unreadable: bool = False,
        clear_share: float = 0.0,
        bits: int = 16,
    ) -> None:
        if not 0.0 <= clear_share < 1.0:
            raise ValueError(f"clear_share: expected 0 <= share < 1, got {clear_share}")
        self.images = list(images)
        self.clear_share = clear_share
        self.substitute_unreadable = substitute_unreadable
        self.unreadable: set[int] = set()  # said once each (per worker process)
        self.effects = effects
        self.channels = channels
        self.crop_size = crop_size
        self.hflip, self.vflip = hflip, vflip
        self.seed = seed
        self.fixed = fixed
        self.epoch = 0
        self.bits = bits

    @classmethod
    def for_training(
        cls,
        images: Sequence[Path],
        effects: EffectsSpec,
        channels: int,
        data: DataConfig,
        seed: int,
        substitute_unreadable: bool = False,
        bits: int = 16,
    ) -> "SyntheticDrops":
        """Training items as ``data`` asks for them: its crop, flips and clear share."""
        return cls(
            images,
            effects,
            channels,
            data.crop_size,
            data.hflip,
            data.vflip,
            seed=seed,
            substitute_unreadable=substitute_unreadable,
            clear_share=data.clear_share,
            bits=bits,
        )

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose crops and drops ``__getitem__`` returns."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int) -> Sample:
        # a substitute image gets this index's crop and drops, not a copy of its own item
        rng = item_rng(self.seed, _VAL_EPOCH if self.fixed else self.epoch, index)
        if self.substitute_unreadable:
            read = read_substituting(self._read, index, len(self.images), self.unreadable, "image")
        else:
            read = self._read(index)
        path, clean = read
        if channels_of(clean) != self.channels:
            clean = from_float(to_channels(to_float(clean), self.channels), clean.dtype)
            if self.channels == 1:
                clean = clean[:, :, 0]
        clear = self._clear(index, rng)
        top, left, h, w = crop_box(clean.shape[0], clean.shape[1], self.crop_size, rng)
        window = (slice(top, top + h), slice(left, left + w))
        if clear:
            obstructed = clean[window]
        else:
            obstructed = render_crop(clean, self.effects, (top, left, h, w), rng)
        tensors = [to_tensor(obstructed, self.channels), to_tensor(clean[window], self.channels)]
        tensors = random_flip(tensors, rng, self.hflip, self.vflip)
        return Sample(
            input=tensors[0], target=tensors[1], valid=torch.ones(1, h, w), name=path.name
        )

    def clear(self, index: int) -> bool:
        """Whether validation item ``index`` is seen through clear glass (``fixed`` only)."""
        return self.fixed and self._clear(index, None)

    def _clear(self, index: int, rng: np.random.Generator | None) -> bool:
        if self.clear_share <= 0.0:
            return False  # no draw: the item's crop and drops are those of a run without
        if self.fixed or rng is None:
            return math.floor((index + 1) * self.clear_share) > math.floor(index * self.clear_share)
        return bool(rng.random() < self.clear_share)

    def _read(self, index: int) -> tuple[Path, np.ndarray]:
        return self.images[index], widen(read_image(self.images[index]), self.bits)


def render_crop(
    clean: np.ndarray,
    effects: EffectsSpec,
    box: tuple[int, int, int, int],
    rng: np.random.Generator,
) -> np.ndarray:
    """The crop ``box = (top, left, height, width)`` of ``clean`` with the glass of the whole frame.

    Drops and dirt are drawn with their density over the whole frame: their
    centres are uniform over the frame, so the number that lands in the
    crop grown by a margin (the largest drop or blob plus the blur reach,
    so that every sprite touching the crop is included) is binomial with the
    margin window's share of the frame. Only that window is rendered: a
    256 px crop of a 720x480 frame costs about half of the whole frame.
    The veil's light is the mean of that window, not of the frame.

    Each count and the glass draw from streams of their own, so an effect
    that does nothing (dirt of opacity 0, a defocus of no blur, dust that
    lets all light through) leaves the crop as it was. One that does
    something and reaches further (a defocus, large dirt) widens the window,
    so the crop shows other drops, drawn alike: the same drops under two
    presets hold for whole frames (:func:`~lenspair.simulate.render.render_effects`).

    Returns:
        The obstructed crop, ``clean``'s dtype, ``(height, width[, C])``.

    """
    frame_h, frame_w = clean.shape[:2]
    top, left, height, width = box
    reach = 0.0
    if effects.raindrops is not None:
        reach = max(reach, effects.raindrops.radius_px[1])
    dirt = effects.dirt
    if dirt is not None and dirt.count > 0 and dirt.opacity[1] > 0:
        reach = max(reach, dirt.radius_px[1] * (1 + dirt.irregularity))
    defocus = effects.defocus
    blur = 0.0 if defocus is None else defocus.shift_radius_px + defocus.disk_px
    if blur > 0:  # a defocus of no blur is no defocus: the same window, the same drops
        reach += blur + 2.0
    margin = math.ceil(reach) + 1
    y0, x0 = max(top - margin, 0), max(left - margin, 0)
    y1, x1 = min(top + height + margin, frame_h), min(left + width + margin, frame_w)
    share = (y1 - y0) * (x1 - x0) / (frame_h * frame_w)
    if share >= 0.9:
        obstructed, _ = render_effects(clean, effects, rng)
        crop: np.ndarray = obstructed[top : top + height, left : left + width]
        return crop
    drop_rng, dirt_rng, glass_rng = (
        np.random.default_rng(seed) for seed in rng.integers(0, 2**63, 3)
    )
    local = effects
    if effects.raindrops is not None:
        count = int(drop_rng.binomial(effects.raindrops.count, share))
        local = dataclasses.replace(
            local, raindrops=dataclasses.replace(effects.raindrops, count=count)
        )
    if effects.dirt is not None:
        count = int(dirt_rng.binomial(effects.dirt.count, share))
        local = dataclasses.replace(local, dirt=dataclasses.replace(effects.dirt, count=count))
    obstructed, _ = render_effects(np.ascontiguousarray(clean[y0:y1, x0:x1]), local, glass_rng)
    window: np.ndarray = obstructed[top - y0 : top - y0 + height, left - x0 : left - x0 + width]
    return window
