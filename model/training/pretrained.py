"""The pretrained starting point that ships with lenspair (``--init pretrained``).

GEA networks, mono and RGB, pretrained on ``ours`` synthetic drops rendered
over the clean natural photographs that installed packages ship
(:mod:`lenspair.simulate.natural_images`; ``coffee`` and ``clock`` held out
for validation). They live in ``lenspair/model/weights/`` as ordinary
lenspair checkpoints (network weights only, stored as float16 to stay small,
loaded with ``weights_only=True``) beside ``MODEL_CARD.md``, which states the
data, budget, seed and validation figures. ``python -m benchmarks.pretrain_weights``
rebuilds them (:func:`pretrain_on_natural_images` and :func:`ship_weights`).
"""

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import torch

from lenspair.core.imageio import write_image
from lenspair.model.checkpoint import checkpoint_config, load_checkpoint, save_checkpoint
from lenspair.model.errors import ModelError
from lenspair.model.training.config import RunConfig
from lenspair.model.training.loop import TrainSummary, fit, resolve_config
from lenspair.model.training.synthetic import OUR_DROPS, SyntheticDrops
from lenspair.simulate.natural_images import HELD_OUT, NATURAL_IMAGES, load_natural_images
from lenspair.simulate.natural_images import fit as fit_image

WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
"""Package data folder of the shipped weights (``lenspair/model/weights``)."""

WEIGHTS_FILES: dict[int, str] = {1: "gea_ours_mono.pt", 3: "gea_ours_rgb.pt"}
"""Shipped checkpoint per channel count."""

FRAME = (480, 720)
"""Size the natural images are rendered at (Raindrop's 720x480)."""

VALIDATION_DRAWS = 2
"""Each held-out image is validated under this many fixed drop draws."""


def pretrained_weights(channels: int) -> Path:
    """The shipped checkpoint for ``channels`` (1 or 3).

    Raises:
        ModelError: no shipped weights for that channel count.

    """
    if channels not in WEIGHTS_FILES:
        raise ModelError(f"--init pretrained: no shipped weights for {channels} channels")
    path = WEIGHTS_DIR / WEIGHTS_FILES[channels]
    if not path.is_file():
        raise ModelError(f"--init pretrained: {path} is missing from this installation")
    return path


def write_natural_images(folder: Path, channels: int) -> tuple[list[Path], list[Path]]:
    """Write the natural images as PNG: training views and held-out images.

    Each training photograph is written whole (720x480) and as two 1.5x
    zoomed views (upper left, lower right), so that one epoch is a few
    steps; the :data:`HELD_OUT` images are written whole for validation.

    Returns:
        ``(train, validation)`` file lists.

    """
    images = load_natural_images(FRAME, channels)
    train, validation = [], []
    for name, image in images.items():
        if name in HELD_OUT:
            path = folder / "val" / f"{name}.png"
            write_image(path, image)
            validation.append(path)
            continue
        source = NATURAL_IMAGES[name]()
        source = np.asarray(source, np.uint8)[..., :3] if source.ndim == 3 else source
        views = {"whole": image}
        height, width = source.shape[:2]
        for label, (top, left) in {"zoom_a": (0, 0), "zoom_b": (1, 1)}.items():
            h, w = int(height / 1.5), int(width / 1.5)
            crop = source[top * (height - h) : top * (height - h) + h]
            crop = crop[:, left * (width - w) : left * (width - w) + w]
            views[label] = load_view(crop, channels)
        for label, view in views.items():
            path = folder / "train" / f"{name}_{label}.png"
            write_image(path, view)
            train.append(path)
    return train, validation


def load_view(image: np.ndarray, channels: int) -> np.ndarray:
    """A crop of a natural image at :data:`FRAME` in the requested channels."""
    if channels == 1 and image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    elif channels == 3 and image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    view: np.ndarray = fit_image(np.ascontiguousarray(image), FRAME)
    return view


def pretrain_on_natural_images(
    run: Path, channels: int, config: RunConfig, device: torch.device
) -> TrainSummary:
    """Pretrain on ``ours`` drops over the natural images (validation: :data:`HELD_OUT`).

    Args:
        run: run folder (the clean images go to ``run/clean/``).
        channels: 1 or 3.
        config: the run configuration (budget, seed, batch, crop).
        device: training device.

    """
    train_files, val_files = write_natural_images(run / "clean", channels)
    data = config.data
    seed = config.train.seed
    train = SyntheticDrops(
        train_files, OUR_DROPS, channels, data.crop_size, data.hflip, data.vflip, seed=seed
    )
    val = SyntheticDrops(val_files * VALIDATION_DRAWS, OUR_DROPS, channels, None, fixed=True)
    config = resolve_config(config, channels)
    description = (
        f"bundled natural photographs, ours drops ({len(train_files)} training views, "
        f"validation {len(val)}: {', '.join(HELD_OUT)} x {VALIDATION_DRAWS} drop draws)"
    )
    return fit(config, train, val, run, device, data_description=description, synthetic="ours")


def ship_weights(best: Path, destination: Path) -> int:
    """Write a compact copy of a checkpoint: network weights as float16, no optimiser.

    Returns:
        The file size in bytes.

    """
    data = load_checkpoint(best)
    config = checkpoint_config(data, best)
    model = {
        key: value.to(torch.float16) if value.is_floating_point() else value
        for key, value in data["model"].items()
    }
    payload = {"model": model, "epoch": data.get("epoch", 0), "step": data.get("step", 0)}
    save_checkpoint(destination, payload, dataclasses.replace(config, runtime=config.runtime))
    return destination.stat().st_size
