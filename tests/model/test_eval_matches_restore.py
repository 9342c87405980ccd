"""eval scores what restore writes: the same layouts on the CPU, so the same codes.

eval ran the network in the default layout and restore channels-last; their
rounding differs, and on nearly flat frames the outputs differed by a code or more.
"""

from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.core.pixels import to_float
from lenspair.model.evaluation.evaluate import evaluate_checkpoint
from lenspair.model.evaluation.scoring import score_tensors
from lenspair.model.inference.backends import open_backend
from lenspair.model.training.pretrained import pretrained_weights


def _nearly_flat_pairs(folder: Path, count: int) -> list[Path]:
    """Grey frames with faint noise (a fog, a wall): where the layouts disagreed most."""
    rng = np.random.default_rng(3)
    names = []
    for index in range(count):
        level = 60 + 60 * index
        frame = np.clip(level + rng.normal(0, 2.0, (96, 128)), 0, 255).astype(np.uint8)
        target = np.clip(level + rng.normal(0, 2.0, (96, 128)), 0, 255).astype(np.uint8)
        name = f"frame_{index:02d}.png"
        write_image(folder / "input" / name, frame)
        write_image(folder / "target" / name, target)
        names.append(folder / "input" / name)
    return names


@pytest.mark.usefixtures("one_thread")
def test_eval_scores_exactly_what_restore_writes(tmp_path: Path) -> None:
    inputs = _nearly_flat_pairs(tmp_path / "pairs", 3)
    weights = pretrained_weights(1)
    result = evaluate_checkpoint(
        weights, tmp_path / "pairs", "test", torch.device("cpu"), latency_runs=0
    )
    backend = open_backend(weights, "cpu", "fp32")  # what restore runs
    for score, path in zip(result.scores, inputs, strict=True):
        frame = to_float(read_image(path))[None, None].astype(np.float32)
        restored = torch.from_numpy(np.round(backend(frame) * 255) / 255)  # as written, 8-bit
        target = to_float(read_image(path.parent.parent / "target" / path.name))
        psnr, ssim = score_tensors(
            restored, torch.from_numpy(target)[None, None], "skimage-gaussian"
        )
        assert (score.psnr_db, score.ssim) == (psnr, ssim), path.name
