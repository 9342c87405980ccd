"""Tiny data and configs for the training/evaluation/export tests (32x48 images)."""

from dataclasses import replace
from pathlib import Path

import numpy as np

from lenspair.core.imagewrite import write_image
from lenspair.model.training.config import (
    DataConfig,
    LossConfig,
    ModelConfig,
    RunConfig,
    TrainConfig,
)

HEIGHT, WIDTH = 32, 48


def clean_image(rng: np.random.Generator, height: int = HEIGHT, width: int = WIDTH) -> np.ndarray:
    """A smooth uint8 mono image (a few sinusoids plus a gradient)."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    image = 0.5 + 0.2 * np.sin(xx / rng.uniform(3, 8) + rng.uniform(0, 6))
    image += 0.2 * np.cos(yy / rng.uniform(3, 8)) + 0.1 * (xx / width)
    return np.asarray(np.clip(image, 0, 1) * 255, dtype=np.uint8)


def obstruct(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Darken a few discs (stand-in drops)."""
    out = image.astype(np.float32)
    height, width = image.shape[:2]
    yy, xx = np.mgrid[0:height, 0:width]
    for _ in range(3):
        cy, cx, r = rng.uniform(0, height), rng.uniform(0, width), rng.uniform(3, 7)
        out[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] *= 0.5
    return np.asarray(np.clip(out, 0, 255), dtype=np.uint8)


def write_paired_folder(
    root: Path,
    count: int = 6,
    seed: int = 0,
    height: int = HEIGHT,
    width: int = WIDTH,
    rgb: bool = False,
) -> Path:
    """``root/input`` and ``root/target`` with ``count`` pairs named ``000.png`` ..."""
    rng = np.random.default_rng(seed)
    for index in range(count):
        target = clean_image(rng, height, width)
        if rgb:
            target = np.stack([target, np.roll(target, 1, axis=1), target[::-1]], axis=2)
            target = np.ascontiguousarray(target)
        source = obstruct(target, rng)
        write_image(root / "input" / f"{index:03d}.png", source)
        write_image(root / "target" / f"{index:03d}.png", target)
    return root


def write_split_dataset(root: Path, counts: dict[str, int] | None = None) -> Path:
    """A split dataset ``root/{train,val,test}/{input,target}`` (generic paired layout)."""
    counts = counts or {"train": 6, "val": 2, "test": 3}
    for offset, (split, count) in enumerate(counts.items()):
        write_paired_folder(root / split, count, seed=100 + offset)
    return root


def tiny_config(**train: object) -> RunConfig:
    """A network of a few thousand parameters, 32 px crops, batch 2, fp32."""
    base = RunConfig(
        model=ModelConfig(
            variant="GEA", channels=1, width=0.25, num_blocks=1, discriminator_width=0.125
        ),
        data=DataConfig(crop_size=32, max_val_images=4),
        train=TrainConfig(batch_size=2, epochs=2, amp=False, tensorboard=False),
        loss=LossConfig(),
    )
    return replace(base, train=replace(base.train, **train))  # type: ignore[arg-type]


def make_checkpoint(
    path: Path, config: RunConfig | None = None, perturb: bool = True, best_epoch: int = 0
) -> Path:
    """Save an untrained checkpoint (weights nudged off the identity when ``perturb``).

    ``best_epoch`` > 0 records a best validation (30 dB) taken at that epoch.
    """
    import torch

    from lenspair.model.checkpoint import save_checkpoint
    from lenspair.model.training.step import Trainer

    config = config or tiny_config()
    trainer = Trainer(config, torch.device("cpu"))
    if perturb:
        generator = torch.Generator().manual_seed(1)
        with torch.no_grad():
            for parameter in trainer.model.parameters():
                noise = torch.randn(parameter.shape, generator=generator)
                parameter.add_(0.02 * noise)
    payload = {**trainer.state_dict(), "epoch": 0, "step": 0, "step_in_epoch": 0}
    if best_epoch:
        payload.update(best_metric=30.0, best_epoch=best_epoch, stale_validations=0)
    save_checkpoint(path, payload, config)
    return path
