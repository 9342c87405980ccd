"""Typed training configuration: one YAML file per experiment, diffable.

A run's configuration has four sections, each a frozen dataclass loaded
through :func:`lenspair.core.config.load_yaml`, which rejects unknown keys with
their dotted path (``train.lr: expected float, got 'le-4'``)::

    model: {variant: GEA, channels: null, width: 1.0, num_blocks: 9, discriminator_width: 1.0}
    data:  {crop_size: 256, hflip: true, vflip: false, drops: ours, ...}
    train: {lr: 2.0e-4, beta1: 0.5, beta2: 0.999, batch_size: 8, epochs: 200, ...}
    loss:  {adversarial: 1.0, feature_matching: 10.0, perceptual: 10.0, fidelity: 100.0, ...}

The file saved as ``RUN/config.yaml`` is the *resolved* configuration: every
default written out, ``model.channels`` fixed from the data, and a
``runtime`` section stating what the run actually did (device, precision,
whether the perceptual loss ran, the data it read).

This module holds the sections' dataclasses and their checks; reading a
file or a checkpoint's copy, layering a ``--config`` on another
configuration and comparing two are in
:mod:`lenspair.model.training.config_loading`.
"""

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from lenspair.core.config import MAX_SEED

Variant = Literal["G", "GE", "GEA"]
DropsPreset = Literal["ours", "sharp"]
TrainPrecision = Literal["auto", "fp32", "bf16", "fp16"]


@dataclass(frozen=True)
class ModelConfig:
    """Which restoration network to build (``lenspair.model.networks.variants.build_model``).

    Attributes:
        variant: ``G`` (generator only), ``GE`` (+ enhancer) or ``GEA``
            (+ aggregation), as in the paper's ablation.
        channels: 1 (mono) or 3 (RGB); ``None`` takes it from the data.
        width: multiplier of the number of filters (0.5 narrower, 2 wider).
        num_blocks: residual blocks of the generator (9 in the paper).
        discriminator_width: multiplier of the PatchGAN's 64 base filters
            (training only; the deployed network does not contain it).

    """

    variant: Variant = "GEA"
    channels: int | None = None
    width: float = 1.0
    num_blocks: int = 9
    discriminator_width: float = 1.0

    def __post_init__(self) -> None:
        if self.channels is not None and self.channels not in (1, 3):
            raise ValueError(f"channels: expected 1 or 3, got {self.channels}")
        if not 0.0 < self.width <= 16.0:
            raise ValueError(f"width: expected 0 < width <= 16, got {self.width}")
        if self.num_blocks < 0:
            raise ValueError(f"num_blocks: expected >= 0, got {self.num_blocks}")
        if not 0.0 < self.discriminator_width <= 16.0:
            raise ValueError(
                f"discriminator_width: expected 0 < width <= 16, got {self.discriminator_width}"
            )


MIN_CROP_SIZE = 24
"""The smallest training crop: the PatchGAN's three stride-2 4x4 layers leave no output
below it (:func:`lenspair.model.networks.discriminator.min_input_side`, not imported
here, so that reading a config does not load torch)."""


@dataclass(frozen=True)
class DataConfig:
    """How training pairs are drawn (``lenspair.model.training.pairs``, ``...datasets``).

    Attributes:
        crop_size: side of the square random training crop, pixels.
        hflip: random horizontal flips.
        vflip: random vertical flips (off: skies stay on top).
        train_split: dataset split trained on.
        val_split: split used for validation and early stopping (not
            ``train_split``).
        max_val_images: validate on at most this many images, spread evenly
            over the split in name order (``None``: all).
        num_workers: DataLoader worker processes (0: load in the main process).
        drops: synthetic pretraining only: ``ours`` (defocused, brightened
            lens drops) or ``sharp`` (Porav et al.'s in-focus drops).
        val_fraction: fraction held out for validation where there is no
            validation split: of the clean images in synthetic pretraining,
            of the pairs of a split-less paired folder (chosen by a hash of the
            names, so the choice is deterministic and stable).
        anomaly_crops: real pairs only: share of training crops drawn to hold
            pixels where input and target differ
            (:func:`lenspair.model.training.pairs.anomaly_crop_box`); the rest
            lie anywhere, so the network still sees clean glass it must leave
            alone. Drops and dust cover a small part of a frame, so uniform
            crops spend most steps on pixels that need no change. Off by
            default: on the demo's dataset (200 fine-tuning steps, 2 seeds),
            0.5 raised validation PSNR by about 0.3 dB and the hard test pairs
            by about 0.4 dB, but the nearly clean pairs lost 1.4 dB in
            one seed (the network learnt to change more), so the test mean did
            not move beyond the seed spread.
        clear_share: synthetic pretraining only: share of items seen through
            clear glass (no drops, no veil: the input is the target). The
            ``ours`` drops always come with a veil, and a network that never
            saw a frame without one darkened every clear frame by 11-13
            codes and put blotches into the noise of textureless ones (the
            weights shipped before 2026-11-25: 22-23 dB from a clear frame
            to itself). A robot's camera is clear most of the time, so a
            pretrained network must learn to leave such frames as they are.
            Training items only: validation keeps its drops, because clear
            frames, scored at 40 dB and more by a network that changes
            nothing, would outweigh them and pick that network. Below 1: the
            network must see drops.
    """

    crop_size: int = 256
    hflip: bool = True
    vflip: bool = False
    train_split: str = "train"
    val_split: str = "val"
    max_val_images: int | None = 64
    num_workers: int = 0
    drops: DropsPreset = "ours"
    val_fraction: float = 0.1
    anomaly_crops: float = 0.0
    clear_share: float = 0.2

    def __post_init__(self) -> None:
        if self.crop_size < MIN_CROP_SIZE:
            raise ValueError(
                f"data.crop_size (--crop-size): expected >= {MIN_CROP_SIZE} (the smallest "
                f"the PatchGAN discriminator's 4x4 layers can take), got {self.crop_size}"
            )
        if self.val_split == self.train_split:
            raise ValueError(
                f"val_split: must differ from train_split ({self.train_split!r}): validating "
                "on the training pairs picks best.pt and stops early by how well the network "
                "fits them"
            )
        if self.max_val_images is not None and self.max_val_images < 1:
            raise ValueError(f"max_val_images: expected >= 1, got {self.max_val_images}")
        if self.num_workers < 0:
            raise ValueError(f"num_workers: expected >= 0, got {self.num_workers}")
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"val_fraction: expected 0..1, got {self.val_fraction}")
        if not 0.0 <= self.anomaly_crops <= 1.0:
            raise ValueError(f"anomaly_crops: expected 0..1, got {self.anomaly_crops}")
        if not 0.0 <= self.clear_share < 1.0:
            raise ValueError(f"clear_share: expected 0 <= share < 1, got {self.clear_share}")


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation, schedule and safety settings (``lenspair.model.training.loop``).

    Attributes:
        lr: Adam learning rate of all networks.
        beta1: Adam beta1 (0.5, as for GANs).
        beta2: Adam beta2.
        batch_size: pairs per step (global: split across processes under torchrun).
        epochs: at most this many passes over the training split.
        patience: stop after this many validations without a better PSNR
            (0 disables early stopping).
        max_steps: optional budget in optimiser steps (stops mid-epoch).
        max_seconds: optional budget in wall-clock seconds of training.
        lr_decay: the share of the run, at its end, over which the learning
            rate of both networks falls linearly towards zero (pix2pix's
            schedule is 0.5: constant for the first half, then linear decay;
            the last step runs at ``lr`` / the number of decay steps); ``0``
            keeps it constant, as the paper trains. The run's length is
            counted in steps: the smaller of ``max_steps`` and ``epochs`` x
            steps per epoch (a ``max_seconds`` budget does not move it, so
            that every process of a torchrun run sets the same rate; a resume
            at another batch size changes the steps per epoch, and so the
            schedule). A budget-bound comparison (``lenspair tradeoff``)
            anneals so that each network's accuracy settles by the budget's end.
        precision: ``auto`` (bf16 autocast on a CPU with ``avx512_bf16``/AMX,
            fp32 on one without, and fp32 on CUDA: measured on an H100, these
            small networks train faster at fp32 than with bf16/fp16 autocast;
            see :func:`lenspair.model.precision.choose_precision`), ``fp32``,
            ``bf16`` or ``fp16`` (CUDA only, with a GradScaler).
        amp: ``false`` forces fp32 whatever ``precision`` says (older configs).
        seed: seeds network initialisation, crops, flips and rendered drops.
        deterministic: ask torch for deterministic kernels (slower on CUDA).
        vgg19_weights: VGG19 ImageNet weights for the perceptual loss (``~``
            is the home folder; a relative path is beside the config file);
            ``None`` falls back to ``LENSPAIR_VGG19_WEIGHTS``; without either
            the perceptual term is disabled (and the run says so).
        nan_patience: stop after this many consecutive non-finite steps (each
            one is skipped without updating any weight).
        grad_clip: optional max gradient norm of the restoration network.
        val_every: validate (and maybe save ``best.pt``) every N epochs.
        log_every: TensorBoard update interval, steps (unused without
            TensorBoard; the progress bar updates every step).
        tensorboard: also log to ``RUN/tensorboard`` when it is installed.
        checkpoint_every_steps: also write ``last.pt`` every N optimiser steps
            within an epoch (``None``: by time only).
        checkpoint_every_seconds: also write ``last.pt`` when this much
            training time passed since the last one (default 10 minutes: a
            kill loses at most that much, whatever the epoch length);
            ``None``: by steps only (neither: once per epoch).

    """

    lr: float = 2e-4
    beta1: float = 0.5
    beta2: float = 0.999
    batch_size: int = 8
    epochs: int = 200
    patience: int = 10
    max_steps: int | None = None
    max_seconds: float | None = None
    lr_decay: float = 0.0
    precision: TrainPrecision = "auto"
    amp: bool = True
    seed: int = 0
    deterministic: bool = False
    vgg19_weights: Path | None = None
    nan_patience: int = 5
    grad_clip: float | None = None
    val_every: int = 1
    log_every: int = 10
    tensorboard: bool = True
    checkpoint_every_steps: int | None = None
    checkpoint_every_seconds: float | None = 600.0

    def __post_init__(self) -> None:
        # the YAML loader refuses inf and NaN; a config built in Python must too, or its
        # config.yaml (max_seconds: .inf) refuses the run's checkpoint afterwards
        for name in ("lr", "max_seconds", "checkpoint_every_seconds", "grad_clip"):
            value = getattr(self, name)
            if value is not None and not math.isfinite(value):
                raise ValueError(f"{name}: expected a finite number, got {value}")
        if self.checkpoint_every_steps is not None and self.checkpoint_every_steps < 1:
            raise ValueError(
                f"checkpoint_every_steps: expected >= 1, got {self.checkpoint_every_steps}"
            )
        if self.checkpoint_every_seconds is not None and self.checkpoint_every_seconds <= 0:
            raise ValueError(
                f"checkpoint_every_seconds: expected > 0, got {self.checkpoint_every_seconds}"
            )
        if self.lr <= 0:
            raise ValueError(f"lr: expected > 0, got {self.lr}")
        if not 0 <= self.seed <= MAX_SEED:  # epoch seeds are seed * 100_003 + epoch: < 2**63
            raise ValueError(f"seed: expected 0 .. {MAX_SEED}, got {self.seed}")
        if not 0.0 <= self.lr_decay <= 1.0:
            raise ValueError(f"lr_decay: expected 0..1, got {self.lr_decay}")
        if not (0.0 <= self.beta1 < 1.0 and 0.0 <= self.beta2 < 1.0):
            raise ValueError("beta1, beta2: expected 0 <= beta < 1")
        for name in ("batch_size", "epochs", "nan_patience", "val_every", "log_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected >= 1, got {getattr(self, name)}")
        if self.patience < 0:
            raise ValueError(f"patience: expected >= 0, got {self.patience}")
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError(f"max_steps: expected >= 1, got {self.max_steps}")
        if self.max_seconds is not None and self.max_seconds <= 0:
            raise ValueError(f"max_seconds: expected > 0, got {self.max_seconds}")
        if self.grad_clip is not None and self.grad_clip <= 0:
            raise ValueError(f"grad_clip: expected > 0, got {self.grad_clip}")


UNTRAINED_WITHOUT = ("adversarial", "feature_matching", "perceptual", "fidelity")
"""The network's loss terms: with every weight 0 it learns nothing."""


@dataclass(frozen=True)
class LossConfig:
    """Weights of the loss terms.

    The generator output gets the LSGAN adversarial and feature-matching
    terms; the enhanced output gets the VGG19 perceptual and L2 fidelity
    terms; the restoration network minimises their weighted sum in one step.

    Attributes:
        adversarial: LSGAN generator term.
        feature_matching: L1 between discriminator features of real and fake.
        perceptual: VGG19 perceptual term (needs weights, else disabled).
        perceptual_layers: weights of the five VGG19 stages (1/32 ... 1).
        fidelity: L2 (mean squared error) to the target, in [0, 1] units.

    """

    adversarial: float = 1.0
    feature_matching: float = 10.0
    perceptual: float = 10.0
    perceptual_layers: tuple[float, ...] = (1 / 32, 1 / 16, 1 / 8, 1 / 4, 1.0)
    fidelity: float = 100.0

    def __post_init__(self) -> None:
        for f in ("adversarial", "feature_matching", "perceptual", "fidelity"):
            if getattr(self, f) < 0:
                raise ValueError(f"{f}: expected >= 0, got {getattr(self, f)}")
        if not any(getattr(self, f) > 0 for f in UNTRAINED_WITHOUT):
            # all four 0: the network never changed while D trained on, exit 0
            raise ValueError(
                f"{', '.join(UNTRAINED_WITHOUT)}: all 0 leave the network untrained; give at "
                "least one a weight above 0"
            )
        if len(self.perceptual_layers) != 5:
            raise ValueError(
                f"perceptual_layers: expected 5 weights, got {len(self.perceptual_layers)}"
            )


@dataclass(frozen=True)
class RuntimeInfo:
    """What a run actually did; written by the trainer, informative only.

    Attributes:
        perceptual: ``enabled (PATH)`` or ``disabled (reason)``.
        precision: ``fp32``, ``bf16 autocast`` or ``fp16 autocast + GradScaler``.
        precision_reason: why (:class:`lenspair.model.precision.PrecisionDecision`).
        native_precisions: what the device runs natively, fastest first.
        device: the torch device trained on.
        world_size: number of processes (``torchrun``), 1 otherwise.
        data: the dataset or clean-image folder trained on.
        synthetic: drops preset when training on synthetic drops, else ``None``.
        init: checkpoint the weights were initialised from, if any (a
            resumed run keeps its first session's).
        torch_version: ``torch.__version__``.
        earlier_precisions: a resumed run's earlier precisions, when they
            differ from ``precision``: ``bf16 autocast until step 300``.
        data_path: the resolved folder of ``data`` (empty in runs written
            before it was recorded).
        earlier_data: a resumed run's earlier data, when it differs from
            ``data_path``: ``/old/DS until step 300``.

    """

    perceptual: str = ""
    precision: str = ""
    precision_reason: str = ""
    native_precisions: tuple[str, ...] = ()
    device: str = ""
    world_size: int = 1
    data: str = ""
    synthetic: str | None = None
    init: str | None = None
    torch_version: str = ""
    earlier_precisions: tuple[str, ...] = ()
    data_path: str = ""
    earlier_data: tuple[str, ...] = ()


UNTIL_STEP = " until step "
"""Joins what a resumed run's earlier sessions had to the step it lasted until
(``RuntimeInfo.earlier_precisions``, ``earlier_data``): :func:`until_step`, :func:`split_until`."""


def until_step(what: str, step: int) -> str:
    """``/old/DS until step 300``: an entry of ``earlier_precisions`` or ``earlier_data``."""
    return f"{what}{UNTIL_STEP}{step}"


def split_until(entry: str) -> tuple[str, int | None]:
    """An :func:`until_step` entry's ``(what, step)``; the step None where it is no number."""
    what, found, step = entry.rpartition(UNTIL_STEP)
    if not found:
        return entry, None
    return what, int(step) if step.isdigit() else None


@dataclass(frozen=True)
class RunConfig:
    """A whole experiment: ``model``, ``data``, ``train``, ``loss`` (+ ``runtime``, resolved)."""

    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    runtime: RuntimeInfo | None = None
