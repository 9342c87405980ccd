"""Validation scores whole frames the way ``restore`` runs them, without touching training."""

import math

import numpy as np
import pytest
import torch
from torch import nn

from lenspair.model.errors import TrainingDivergedError
from lenspair.model.evaluation.scoring import score_tensors
from lenspair.model.evaluation.summary import mean_psnr
from lenspair.model.networks.variants import build_model
from lenspair.model.training.pairs import Sample
from lenspair.model.training.validation import VAL_CONVENTION, validate


class _Frames:
    """Whole validation frames (odd sizes, as real crops are not)."""

    def __init__(self, count: int = 3, valid: torch.Tensor | None = None) -> None:
        self.valid = torch.ones(1, 37, 61) if valid is None else valid
        generator = torch.Generator().manual_seed(3)
        self.pairs = [
            (torch.rand(1, 37, 61, generator=generator), torch.rand(1, 37, 61, generator=generator))
            for _ in range(count)
        ]

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, index: int) -> Sample:
        x, y = self.pairs[index]
        return Sample(input=x, target=y, valid=self.valid, name=f"{index:02d}")


def test_validation_runs_channels_last_on_a_copy_and_scores_as_the_training_layout() -> None:
    torch.manual_seed(0)
    network = build_model("GEA", 1, width=0.25, num_blocks=2).train()
    layouts: list[bool] = []

    def record(module: nn.Module, args: tuple[torch.Tensor, ...]) -> None:
        # a weight whose layouts differ (with one input channel or a 1x1 kernel both coincide)
        weight = max((p for p in module.parameters() if p.ndim == 4), key=lambda p: p.shape[1])
        assert weight.shape[1] > 1 and weight.shape[2] > 1
        layouts.append(weight.is_contiguous(memory_format=torch.channels_last))

    network.register_forward_pre_hook(record)
    frames = _Frames()
    psnr, ssim, sheet = validate(network, frames, torch.device("cpu"))

    # the copy ran in restore's layout; the trained network kept its own and its mode
    assert layouts == [True] * len(frames)
    assert network.training
    assert all(p.is_contiguous() for p in network.parameters())
    # ... and scores what the training layout computes
    network.eval()
    psnrs, ssims = [], []
    with torch.inference_mode():
        for x, y in frames.pairs:
            output = network(x[None])[1].float().clamp(0.0, 1.0)
            scores = score_tensors(output, y[None], VAL_CONVENTION)
            psnrs.append(scores[0])
            ssims.append(scores[1])
    assert abs(psnr - mean_psnr(psnrs)) < 1e-3
    assert abs(ssim - float(np.mean(ssims))) < 1e-5
    assert sheet.ndim == 3 and sheet.size > 0


def test_validation_leaves_out_the_pixels_the_loss_leaves_out() -> None:
    # best.pt was chosen partly on misregistered pixels that training never fitted
    torch.manual_seed(0)
    network = build_model("GEA", 1, width=0.25, num_blocks=2)
    valid = torch.ones(1, 37, 61)
    valid[:, :, :9] = 0.0  # mask/'s strip
    frames, spoiled = _Frames(valid=valid), _Frames(valid=valid)
    spoiled.pairs = [(x, torch.where(valid > 0, y, 1.0 - y)) for x, y in spoiled.pairs]
    first = validate(network, frames, torch.device("cpu"))
    second = validate(network, spoiled, torch.device("cpu"))
    assert first[:2] == second[:2]
    assert validate(network, _Frames(), torch.device("cpu"))[0] != first[0]  # the strip counted


def test_a_non_finite_output_is_divergence_and_a_non_finite_pair_is_the_pairs_problem() -> None:
    # the network's NaN was taken for each pair's problem: "no validation pair can be scored"
    torch.manual_seed(0)
    network = build_model("GEA", 1, width=0.25, num_blocks=2)
    skipped: dict[int, str] = {}
    frames = _Frames()
    frames.pairs[1] = (frames.pairs[1][0], torch.full_like(frames.pairs[1][1], math.nan))
    frames.pairs[2] = (torch.full_like(frames.pairs[2][0], math.nan), frames.pairs[2][1])
    psnr, _, _ = validate(network, frames, torch.device("cpu"), skipped=skipped)
    assert math.isfinite(psnr) and sorted(skipped) == [1, 2]  # left out; the run goes on
    with torch.no_grad():
        next(p for p in network.parameters() if p.ndim == 4).view(-1)[0] = math.nan
    kept: dict[int, str] = {}
    with pytest.raises(TrainingDivergedError, match=r"validation pair 00 holds NaN or Inf"):
        validate(network, _Frames(), torch.device("cpu"), skipped=kept)
    assert kept == {}  # no pair blamed for the rest of the run
