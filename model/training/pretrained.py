"""The pretrained starting point that ships with lenspair (``--init pretrained``).

GEA networks, mono and RGB, pretrained on ``ours`` synthetic drops rendered
over the clean natural photographs that installed packages ship
(:mod:`lenspair.simulate.natural_images`; ``coffee`` and ``clock`` held out
for validation) and over a few textureless scenes with sensor noise
(:data:`PLAIN_SCENES`: a wall, a sky, a night, fog), a share of them seen
through clear glass (:attr:`~lenspair.model.training.config.DataConfig.clear_share`),
so that the network leaves frames without an anomaly as they are. They live
in ``lenspair/model/weights/`` as ordinary lenspair checkpoints (network
weights only, stored as float16 to stay small, loaded with
``weights_only=True``) beside ``MODEL_CARD.md``, which states the data,
budget, seed and validation figures. ``python -m benchmarks.pretrain_weights``
rebuilds them (:func:`pretrain_on_natural_images` and :func:`ship_weights`).
"""

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import torch

from lenspair.core.imagewrite import write_image
from lenspair.model.checkpoint import (
    WEIGHTS_DIR,
    WEIGHTS_FILES,
    checkpoint_config,
    load_checkpoint,
    save_checkpoint,
)
from lenspair.model.errors import ModelError
from lenspair.model.training.config import RunConfig
from lenspair.model.training.loop import TrainSummary, fit, resolve_config
from lenspair.model.training.synthetic import OUR_DROPS, SyntheticDrops
from lenspair.simulate.natural_images import HELD_OUT, NATURAL_IMAGES, load_natural_images
from lenspair.simulate.natural_images import fit as fit_image

FRAME = (480, 720)
"""Size the natural images are rendered at (Raindrop's 720x480)."""

VALIDATION_DRAWS = 2
"""Each held-out image is validated under this many fixed drop draws (the card: and once clear)."""

PLAIN_SCENES: dict[str, tuple[tuple[float, float, float], float, float]] = {
    "plain_wall": ((0.45, 0.44, 0.42), 0.15, 2.0),
    "plain_sky": ((0.62, 0.74, 0.88), 0.25, 1.5),
    "plain_night": ((0.06, 0.06, 0.07), 0.0, 3.0),
    "plain_fog": ((0.72, 0.72, 0.74), 0.05, 2.0),
}
"""Textureless scenes: name -> (RGB level, top-to-bottom ramp, sensor noise in 8-bit codes).

A grey wall with vignetting, a sky brightening towards the horizon, a night
frame where the noise is all there is, and fog: what a robot's camera sees
when nothing in the scene has texture. Instance normalisation scales a
feature map to unit variance whatever its contrast, so a network that never
saw such frames turns their noise into blotches.
"""

HELD_OUT_PLAIN = "plain_fog"
"""Textureless scene kept for validation, with the natural :data:`HELD_OUT` images."""


def plain_scene(name: str, channels: int) -> np.ndarray:
    """The textureless scene ``name`` of :data:`PLAIN_SCENES` at :data:`FRAME`, ``uint8``.

    Level, ramp and faint shading are smooth; the sensor noise is Gaussian,
    independent per pixel and channel, drawn from a seed fixed per scene.
    """
    level, ramp, noise_codes = PLAIN_SCENES[name]
    height, width = FRAME
    rng = np.random.default_rng(list(PLAIN_SCENES).index(name))
    rows = np.linspace(-0.5, 0.5, height, dtype=np.float32)[:, None]
    cols = np.linspace(-0.5, 0.5, width, dtype=np.float32)[None, :]
    shading = 1.0 + ramp * rows - 0.2 * (rows**2 + cols**2)  # ramp and vignetting
    colour = np.asarray(level, np.float32) if channels == 3 else np.float32(np.mean(level))
    image = shading[..., None] * colour if channels == 3 else shading * colour
    image = image + rng.normal(0.0, noise_codes / 255.0, image.shape).astype(np.float32)
    scene: np.ndarray = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    return scene


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
    steps, and each :data:`PLAIN_SCENES` scene once; the :data:`HELD_OUT`
    images and :data:`HELD_OUT_PLAIN` are written whole for validation.

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
    for name in PLAIN_SCENES:
        path = folder / ("val" if name == HELD_OUT_PLAIN else "train") / f"{name}.png"
        write_image(path, plain_scene(name, channels))
        (validation if name == HELD_OUT_PLAIN else train).append(path)
    return train, validation


def validation_drops(files: list[Path], channels: int, clear: bool = False) -> SyntheticDrops:
    """The held-out items: each file under :data:`VALIDATION_DRAWS` fixed drop draws.

    With ``clear``, each file's draws are followed by the file seen through
    clear glass (input = target; ``clear(index)`` tells which), for scoring
    the shipped weights. Training validates on the drops only (see
    :attr:`~lenspair.model.training.config.DataConfig.clear_share`).
    """
    repeats = VALIDATION_DRAWS + 1 if clear else VALIDATION_DRAWS
    items = [path for path in files for _ in range(repeats)]
    share = 1.0 / repeats if clear else 0.0
    return SyntheticDrops(items, OUR_DROPS, channels, None, fixed=True, clear_share=share)


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
    """Pretrain on ``ours`` drops over :func:`write_natural_images` (validation: held out).

    Args:
        run: run folder (the clean images go to ``run/clean/``).
        channels: 1 or 3.
        config: the run configuration (budget, seed, batch, crop).
        device: training device.

    """
    train_files, val_files = write_natural_images(run / "clean", channels)
    data = config.data
    train = SyntheticDrops.for_training(train_files, OUR_DROPS, channels, data, config.train.seed)
    val = validation_drops(val_files, channels)
    config = resolve_config(config, channels)
    held_out = ", ".join((*HELD_OUT, HELD_OUT_PLAIN))
    description = (
        f"bundled natural photographs and textureless scenes, ours drops "
        f"({len(train_files)} training views, {data.clear_share:.0%} through clear glass; "
        f"validation {len(val)}: {held_out} x {VALIDATION_DRAWS} drop draws)"
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
