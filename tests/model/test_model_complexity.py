"""Parameter and FLOP accounting."""

import pytest
import torch
from torch import nn

from lenspair.model.errors import ModelError
from lenspair.model.networks.complexity import ModelSummary, count_flops, count_parameters, describe
from lenspair.model.networks.variants import build_model


def test_conv_flops_are_two_per_mac() -> None:
    conv = nn.Conv2d(3, 8, 3, padding=1, bias=False)
    assert count_flops(conv, (3, 10, 12)) == 2 * 3 * 8 * 9 * 10 * 12
    assert count_parameters(conv) == 3 * 8 * 9


def test_describe_model() -> None:
    model = build_model("GEA", 1, width=0.25, num_blocks=1)
    summary = describe(model, (1, 36, 52))
    assert isinstance(summary, ModelSummary)
    assert summary.parameters == sum(p.numel() for p in model.parameters())
    assert summary.trainable_parameters == summary.parameters
    assert summary.macs * 2 == summary.flops and summary.gflops == summary.flops / 1e9
    record = summary.as_dict()
    assert record["input_shape"] == [1, 36, 52] and record["gflops"] == summary.gflops
    # FLOPs scale with the number of pixels (sides multiples of 4: no padding).
    bigger = describe(model, (1, 72, 104))
    assert 3.9 < bigger.flops / summary.flops < 4.1
    model.generator.requires_grad_(False)
    assert count_parameters(model, trainable_only=True) < summary.parameters


def test_residual_blocks_dominate_flops() -> None:
    # Each residual block: two 3x3 convolutions, 64 -> 64 filters, at 1/4 resolution.
    base = describe(build_model("G", 1, num_blocks=0), (1, 40, 60)).flops
    nine = describe(build_model("G", 1, num_blocks=9), (1, 40, 60)).flops
    assert nine - base == 9 * 2 * (2 * 64 * 64 * 9 * 10 * 15)


def test_bad_shape() -> None:
    with pytest.raises(ModelError, match=r"\(C, H, W\)"):
        count_flops(nn.Identity(), (1, 0, 4))
    assert count_flops(nn.Identity(), (1, 4, 4)) == 0
    assert torch.get_default_dtype() == torch.float32
