"""PatchGAN discriminator: outputs, features and the 70x70 receptive field."""

import pytest
import torch

from lenspair.model.errors import ModelError
from lenspair.model.networks.discriminator import PatchDiscriminator, min_input_side
from lenspair.model.networks.variants import build_discriminator
from lenspair.model.training.config import MIN_CROP_SIZE, DataConfig


def test_outputs_and_features() -> None:
    discriminator = build_discriminator(1, width=0.25)
    features = discriminator(torch.rand(2, 2, 64, 48))
    assert len(features) == 5
    assert [f.shape[1] for f in features] == [16, 32, 64, 128, 1]
    assert features[-1].shape == (2, 1, 6, 4)


def test_receptive_field_is_70_by_computation() -> None:
    assert PatchDiscriminator(2, num_filters=4).receptive_field() == 70
    assert PatchDiscriminator(2, num_filters=4, num_layers=1).receptive_field() == 16
    assert PatchDiscriminator(2, num_filters=4, num_layers=2).receptive_field() == 34


def test_receptive_field_is_70_by_gradient_support() -> None:
    # Without instance norm (which couples all positions) one logit depends
    # on exactly a 70x70 input patch.
    torch.manual_seed(0)
    discriminator = PatchDiscriminator(1, num_filters=4, norm="none")
    x = torch.rand(1, 1, 160, 160, requires_grad=True)
    logits = discriminator(x)[-1]
    row, col = logits.shape[-2] // 2, logits.shape[-1] // 2
    logits[0, 0, row, col].backward()
    assert x.grad is not None
    support = x.grad[0, 0].abs() > 0
    rows = torch.nonzero(support.any(dim=1)).flatten()
    cols = torch.nonzero(support.any(dim=0)).flatten()
    assert int(rows[-1] - rows[0]) + 1 == 70
    assert int(cols[-1] - cols[0]) + 1 == 70
    assert int(support.sum()) == 70 * 70
    # Output (i, j) sees input rows 8i - 23 ... 8i + 46: total stride 8, and
    # the 1-pixel paddings add up to 1 + 2 + 4 + 8 + 8 = 23 input pixels.
    assert int(rows[0]) == 8 * row - 23 and int(cols[0]) == 8 * col - 23


def test_bad_arguments() -> None:
    with pytest.raises(ModelError, match="positive"):
        PatchDiscriminator(0)
    with pytest.raises(ModelError, match="valid names"):
        PatchDiscriminator(2, norm="batch")
    with pytest.raises(ModelError, match="1 \\(mono\\) or 3"):
        build_discriminator(4)


@pytest.mark.parametrize("num_layers", [1, 2, 3, 4])
def test_the_smallest_input_is_the_smallest_that_runs(num_layers: int) -> None:
    discriminator = PatchDiscriminator(2, num_filters=4, num_layers=num_layers).eval()
    least = min_input_side(num_layers)
    with torch.no_grad():
        assert discriminator(torch.zeros(1, 2, least, least))[-1].shape[-1] == 1
        with pytest.raises((RuntimeError, ValueError)):  # no output, or a 1x1 map to norm
            discriminator(torch.zeros(1, 2, least - 1, least - 1))


def test_training_crops_below_the_discriminators_smallest_input_are_refused() -> None:
    # crops of 8 to 23 passed the config and then died in the discriminator with a
    # traceback, after the run folder was made
    assert min_input_side() == MIN_CROP_SIZE  # the architecture the config states
    DataConfig(crop_size=MIN_CROP_SIZE)
    with pytest.raises(
        ValueError, match=rf"crop_size \(--crop-size\): expected >= {MIN_CROP_SIZE} .*got 23"
    ):
        DataConfig(crop_size=MIN_CROP_SIZE - 1)
