"""Generator, aggregation, enhancer and the G/GE/GEA variants on tiny networks."""

import io

import pytest
import torch
import torch.nn.functional as F

from lenspair.model.errors import ModelError
from lenspair.model.networks.aggregation import Aggregation
from lenspair.model.networks.enhancer import Enhancer
from lenspair.model.networks.generator import Generator
from lenspair.model.networks.layers import (
    InstanceNorm,
    NarrowConv2d,
    cat_channels,
    clamp_unit_straight_through,
    make_norm,
    scaled_channels,
)
from lenspair.model.networks.padding import crop_to, pad_to_multiple
from lenspair.model.networks.variants import (
    VARIANTS,
    AnomalyMitigator,
    MitigatorOutput,
    build_model,
)
from tests.model.network_helpers import randomise

TINY = {"width": 0.25, "num_blocks": 2}


def _images(channels: int, height: int, width: int, batch: int = 2, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(batch, channels, height, width, generator=generator)


@pytest.mark.parametrize("variant", ["G", "GE", "GEA"])
@pytest.mark.parametrize("channels", [1, 3])
def test_output_shapes_and_range(variant: str, channels: int) -> None:
    model = build_model(variant, channels, **TINY)
    randomise(model)
    x = _images(channels, 20, 28)
    with torch.no_grad():
        out = model(x)
    assert isinstance(out, MitigatorOutput)
    for tensor in out:
        assert tensor.shape == x.shape
        assert tensor.dtype == torch.float32
        assert float(tensor.min()) >= 0.0 and float(tensor.max()) <= 1.0
    if variant == "G":
        assert out.enhanced is out.generator
    else:
        assert not torch.equal(out.enhanced, out.generator)
    with torch.no_grad():
        assert torch.equal(model.restore(x), out.enhanced)


@pytest.mark.parametrize("size", [(357, 531), (9, 13), (8, 8), (33, 65)])
def test_any_input_size_gives_same_size(size: tuple[int, int]) -> None:
    model = build_model("GEA", 1, width=0.125, num_blocks=1)
    x = _images(1, *size, batch=1)
    with torch.inference_mode():
        out = model(x)
    assert out.generator.shape == x.shape and out.enhanced.shape == x.shape


def test_fresh_model_is_identity() -> None:
    # Zero-initialised residual heads: an untrained network returns its input.
    model = build_model("GEA", 3, **TINY)
    x = _images(3, 16, 20)
    out = model(x)
    assert torch.allclose(out.generator, x) and torch.allclose(out.enhanced, x)


def test_padding_round_trip() -> None:
    x = _images(1, 10, 13)
    padded = pad_to_multiple(x, 4)
    assert padded.shape[-2:] == (12, 16)
    assert torch.equal(crop_to(padded, 10, 13), x)
    assert torch.equal(pad_to_multiple(padded, 4), padded)


def test_bad_inputs_raise_model_error() -> None:
    model = build_model("G", 1, **TINY)
    with pytest.raises(ModelError, match=r"expected 1 channel\(s\)"):
        model(torch.rand(1, 3, 16, 16))
    with pytest.raises(ModelError, match="at least 8"):
        model(torch.rand(1, 1, 7, 16))
    with pytest.raises(ModelError, match=r"\(N, C, H, W\)"):
        model(torch.rand(1, 16, 16))
    with pytest.raises(ModelError, match="floating-point"):
        model(torch.zeros(1, 1, 16, 16, dtype=torch.uint8))


def test_unknown_names_list_valid_ones() -> None:
    with pytest.raises(ModelError, match="valid variants: G, GE, GEA"):
        build_model("GAE", 1)
    with pytest.raises(ModelError, match="valid names: instance, none"):
        make_norm("batch", 4)
    with pytest.raises(ModelError, match="1 \\(mono\\) or 3"):
        build_model("G", 2)
    with pytest.raises(ModelError, match="width"):
        build_model("G", 1, width=0.0)
    with pytest.raises(ModelError, match="num_blocks"):
        build_model("G", 1, num_blocks=-1)
    assert set(VARIANTS) == {"G", "GE", "GEA"}


def _count(variant: str = "GEA", width: float = 1.0, num_blocks: int = 9) -> int:
    return sum(p.numel() for p in build_model(variant, 1, width, num_blocks).parameters())


def test_parameter_counts_scale_with_width_and_blocks() -> None:
    widths = [_count(width=w) for w in (0.25, 0.5, 1.0, 2.0)]
    assert widths == sorted(widths) and len(set(widths)) == 4
    # Convolutions dominate: doubling the width roughly quadruples the count.
    assert 3.5 < widths[3] / widths[2] < 4.1
    blocks = [_count(num_blocks=n) for n in (0, 1, 9)]
    per_block = 2 * 64 * 64 * 9
    assert blocks[1] - blocks[0] == per_block and blocks[2] - blocks[0] == 9 * per_block
    assert scaled_channels(8, 0.01) == 1
    assert _count("G") < _count("GE") < _count("GEA")


def test_state_dict_round_trip_gives_identical_outputs() -> None:
    model = build_model("GEA", 3, **TINY)
    randomise(model)
    buffer = io.BytesIO()
    torch.save(model.state_dict(), buffer)
    buffer.seek(0)
    clone = build_model("GEA", 3, **TINY)
    clone.load_state_dict(torch.load(buffer, weights_only=True))
    x = _images(3, 16, 24)
    with torch.inference_mode():
        assert torch.equal(model(x).enhanced, clone(x).enhanced)
        assert torch.equal(model(x).generator, clone(x).generator)


@pytest.mark.parametrize("variant", ["G", "GEA"])
def test_one_step_lowers_a_simple_loss(variant: str) -> None:
    torch.manual_seed(0)
    model = build_model(variant, 1, **TINY)
    randomise(model)
    x = _images(1, 16, 16, batch=2)
    target = (x * 0.5 + 0.2).clamp(0, 1)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    losses = []
    for _ in range(2):
        optimizer.zero_grad()
        loss = F.mse_loss(model(x).enhanced, target)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    with torch.no_grad():
        final = float(F.mse_loss(model(x).enhanced, target))
    assert final < losses[0]


def test_straight_through_clamp_passes_gradient_back_into_range() -> None:
    # Output saturates at 1 while the target is 0.5: a plain clamp would give no gradient.
    model = build_model("G", 1, **TINY)
    x = torch.ones(1, 1, 16, 16)
    loss = F.mse_loss(model(x).enhanced, torch.full_like(x, 0.5))
    loss.backward()
    assert model.generator.head.bias is not None and model.generator.head.bias.grad is not None
    assert float(model.generator.head.bias.grad.abs().sum()) > 0


def test_straight_through_clamp_gradient_is_the_identity_s_out_of_range() -> None:
    # at exactly 1.0 a plain clamp passes gradient too: beyond the range only the
    # straight-through form does (the reason it exists: an overshoot can be pulled back)
    x = torch.tensor([-0.3, 0.4, 1.2], requires_grad=True)
    out = clamp_unit_straight_through(x)
    assert out.tolist() == pytest.approx([0.0, 0.4, 1.0])
    out.sum().backward()
    assert x.grad is not None and x.grad.tolist() == [1.0, 1.0, 1.0]


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16, torch.float16])
def test_straight_through_clamp_is_exact_far_out_of_range(dtype: torch.dtype) -> None:
    # x + (clamp(x) - x).detach() rounds 1 - x away once x is large: 1.7e7 came out 0
    big = torch.finfo(dtype).max / 4
    x = torch.tensor([-big, -1.7e4, 0.25, 1.7e4, big], dtype=dtype, requires_grad=True)
    out = clamp_unit_straight_through(x)
    assert out.tolist() == [0.0, 0.0, 0.25, 1.0, 1.0]
    out.sum().backward()
    assert x.grad is not None and x.grad.tolist() == [1.0] * 5


def test_instance_norm_matches_torch_and_handles_constants() -> None:
    x = torch.randn(2, 5, 9, 7) * 3 + 1
    reference = torch.nn.InstanceNorm2d(5, affine=False, eps=1e-5)
    assert torch.allclose(InstanceNorm(5)(x), reference(x), atol=1e-5)
    constant = torch.full((1, 4, 6, 6), 0.7, requires_grad=True)
    out = InstanceNorm(4)(constant)
    assert torch.equal(out, torch.zeros_like(out))
    out.sum().backward()
    assert constant.grad is not None and bool(torch.isfinite(constant.grad).all())


def test_aggregation_shapes() -> None:
    encoder = Aggregation(4, 6, 5, downsample_first=True)
    assert encoder(torch.rand(1, 4, 16, 12), torch.rand(1, 6, 8, 6)).shape == (1, 5, 8, 6)
    decoder = Aggregation(4, 4, 4, downsample_first=False)
    assert decoder(torch.rand(1, 4, 8, 6), torch.rand(1, 4, 8, 6)).shape == (1, 4, 8, 6)


def test_generator_aggregation_flag_adds_blocks() -> None:
    plain = Generator(1, 2, (4, 8), 16, num_blocks=1, aggregation=False)
    aggregated = Generator(1, 2, (4, 8), 16, num_blocks=1, aggregation=True)
    assert plain.agg1 is None and aggregated.agg1 is not None
    x = torch.rand(1, 1, 16, 16)
    assert aggregated(x).shape == plain(x).shape == x.shape


def test_enhancer_pyramid_is_exact_for_partial_cells() -> None:
    # The fused 1x1-then-pool pyramid equals EPDN's pool-then-1x1, ceil-mode cells included.
    enhancer = Enhancer(1, num_filters=3)
    randomise(enhancer)
    features = torch.rand(1, 3, 37, 45)
    for scale, conv in zip(enhancer.scales, enhancer.pyramid, strict=True):
        direct = conv(F.avg_pool2d(features, scale, scale, ceil_mode=True))
        fused = F.avg_pool2d(conv(features), scale, scale, ceil_mode=True)
        assert torch.allclose(direct, fused, atol=1e-6)
    # A partial border cell averages only the pixels it covers.
    pooled = F.avg_pool2d(features, 32, 32, ceil_mode=True)
    assert torch.allclose(pooled[..., 1, 1], features[..., 32:, 32:].mean(dim=(-2, -1)), atol=1e-6)


def test_mitigator_attributes() -> None:
    model = AnomalyMitigator("GE", 3, width=0.5, num_blocks=3)
    assert (model.variant, model.channels, model.width, model.num_blocks) == ("GE", 3, 0.5, 3)
    assert model.enhancer is not None and model.generator.agg1 is None


@pytest.mark.parametrize(
    ("in_channels", "out_channels", "kernel", "padding_mode"),
    [(8, 1, 7, "reflect"), (8, 3, 7, "reflect"), (20, 1, 3, "zeros"), (5, 2, 3, "zeros")],
)
def test_narrow_conv_equals_conv(
    in_channels: int, out_channels: int, kernel: int, padding_mode: str
) -> None:
    narrow = NarrowConv2d(
        in_channels, out_channels, kernel, padding=kernel // 2, padding_mode=padding_mode
    )
    reference = torch.nn.Conv2d(
        in_channels, out_channels, kernel, padding=kernel // 2, padding_mode=padding_mode
    )
    reference.load_state_dict(narrow.state_dict())
    x = torch.randn(2, in_channels, 13, 17, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        expected = reference(x)
        assert torch.allclose(narrow(x), expected, atol=1e-5)
        assert torch.allclose(
            narrow(x.contiguous(memory_format=torch.channels_last)), expected, atol=1e-5
        )


def test_cat_channels_matches_torch_cat() -> None:
    a = torch.randn(2, 3, 5, 6).contiguous(memory_format=torch.channels_last)
    b = torch.randn(2, 1, 8, 9)[..., :5, :6]  # a strided single-channel view
    c = torch.randn(2, 4, 5, 6)
    for tensors in ([a, b], [b, a, c], [c, c]):
        assert torch.equal(cat_channels(tensors), torch.cat(tensors, dim=1))
    assert cat_channels([a, b]).is_contiguous(memory_format=torch.channels_last)
