"""The networks' faster eager forms compute what their layers, as written, compute.

Two layers have a second formulation for speed on the CPU: the enhancer's
pyramid-and-fuse head as matrix products and shifts
(``Enhancer._head_by_taps``), and the generator's residual blocks with their
reflection pads written in place when no gradient is recorded
(``Generator._residual_features``). Exports use the layers as written.
"""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.model.networks.enhancer import Enhancer, _ShiftedTapSum
from lenspair.model.networks.generator import Generator, _reflect_border
from lenspair.model.networks.tracing import exporting
from lenspair.model.networks.variants import build_model
from tests.model.network_helpers import randomise


@settings(max_examples=25, deadline=None)
@given(
    channels=st.sampled_from([1, 3]),
    batch=st.integers(1, 3),
    height=st.integers(1, 40),
    width=st.integers(1, 40),
    channels_last=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_enhancer_head_by_taps_equals_layers(
    channels: int, batch: int, height: int, width: int, channels_last: bool, seed: int
) -> None:
    # Any size (partial pyramid cells, one-pixel images), either memory format, both
    # image channel counts: the zero-padded borders and the tap order are exercised.
    enhancer = Enhancer(channels, num_filters=5)
    randomise(enhancer, seed, scale=0.3)
    features = torch.rand(batch, 5, height, width, generator=torch.Generator().manual_seed(seed))
    if channels_last:
        features = features.contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        expected = enhancer._head_by_layers(features)
        actual = enhancer._head_by_taps(features)
    assert actual.shape == expected.shape == (batch, channels, height, width)
    assert actual.dtype == expected.dtype
    torch.testing.assert_close(actual, expected, rtol=1e-5, atol=1e-5)


def test_enhancer_head_by_taps_has_the_layers_gradients() -> None:
    # Training runs the taps form: its gradients must be the convolutions' ones.
    enhancer = Enhancer(3, num_filters=6)
    randomise(enhancer, 3, scale=0.3)
    features = torch.rand(2, 6, 19, 23, generator=torch.Generator().manual_seed(3))
    upstream = torch.randn(2, 3, 19, 23, generator=torch.Generator().manual_seed(4))
    gradients = []
    for head in (enhancer._head_by_layers, enhancer._head_by_taps):
        enhancer.zero_grad()
        leaf = features.clone().requires_grad_()
        (head(leaf) * upstream).sum().backward()
        assert leaf.grad is not None
        weights = [p.grad for p in enhancer.parameters() if p.grad is not None]
        gradients.append([leaf.grad, *weights])
    assert len(gradients[0]) == len(gradients[1]) == 1 + 2 + 2 * len(enhancer.scales)
    for by_layers, by_taps in zip(*gradients, strict=True):
        torch.testing.assert_close(by_taps, by_layers, rtol=1e-4, atol=1e-5)


@settings(max_examples=15, deadline=None)
@given(channels=st.sampled_from([1, 3]), height=st.integers(1, 6), width=st.integers(1, 6))
def test_shifted_tap_sum_backward_is_the_exact_gradient(
    channels: int, height: int, width: int
) -> None:
    # The head's shifted sum has its own backward (one gradient tensor instead of one
    # per tap): checked against finite differences, one-pixel borders included.
    taps = torch.rand(2, 3, 3, channels, height, width, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: _ShiftedTapSum.apply(t, torch.float64), (taps,))


def test_shifted_tap_sum_gradient_keeps_the_taps_dtype() -> None:
    # bf16 taps (autocast) are summed in fp32; their gradient comes back in bf16
    taps = torch.rand(1, 3, 3, 1, 5, 4).to(torch.bfloat16).requires_grad_()
    out = _ShiftedTapSum.apply(taps, torch.float32)
    assert out.dtype == torch.float32
    out.sum().backward()
    assert taps.grad is not None and taps.grad.dtype == torch.bfloat16
    # each tap's gradient counts the output pixels it reaches: the centre tap all 20
    assert float(taps.grad[0, 1, 1].sum()) == 20.0
    assert float(taps.grad[0, 0, 0].sum()) == 4 * 3


def test_enhancer_head_by_taps_sums_bf16_taps_in_fp32() -> None:
    # bf16 weights: the nine taps are summed in fp32 and rounded once, as a convolution
    # does, so the result stays within bf16 rounding of the fp32 head.
    enhancer = Enhancer(1, num_filters=16)
    randomise(enhancer, 5, scale=0.3)
    features = torch.rand(1, 16, 30, 30, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        reference = enhancer._head_by_layers(features)
        low = enhancer.to(torch.bfloat16)._head_by_taps(features.to(torch.bfloat16))
    assert low.dtype == torch.bfloat16
    error = (low.float() - reference).abs().max().item()
    assert error <= 0.03 * reference.abs().max().item()


def test_enhancer_head_by_taps_keeps_float64() -> None:
    # A float64 network is summed in float64 (gradcheck-grade), not rounded to fp32.
    enhancer = Enhancer(1, num_filters=6).double()
    randomise(enhancer, 9, scale=0.3)
    features = torch.rand(2, 6, 17, 13, dtype=torch.float64)
    with torch.no_grad():
        actual = enhancer._head_by_taps(features)
        expected = enhancer._head_by_layers(features)
    assert actual.dtype == torch.float64
    torch.testing.assert_close(actual, expected, rtol=1e-12, atol=1e-12)


def test_enhancer_head_by_taps_has_the_convolutions_dtype_under_autocast() -> None:
    # Under CPU autocast the fuse convolution's fp32 bias promotes its output to fp32.
    enhancer = Enhancer(1, num_filters=4)
    randomise(enhancer, 11, scale=0.3)
    features = torch.rand(1, 4, 12, 12)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        by_layers = enhancer._head_by_layers(features)
        by_taps = enhancer._head_by_taps(features)
    assert by_taps.dtype == by_layers.dtype == torch.float32
    torch.testing.assert_close(by_taps, by_layers, rtol=0.02, atol=0.02)


def _refuse(features: torch.Tensor) -> torch.Tensor:
    raise AssertionError("the taps form ran inside an export")


def test_exports_see_the_layers_as_written() -> None:
    # A TorchScript trace and torch.export (ONNX's dynamo exporter and the int8
    # quantisers go through it) record the layers: the taps form refuses to run.
    enhancer = Enhancer(1, num_filters=4)
    randomise(enhancer, 7, scale=0.3)
    generated, image = torch.rand(2, 1, 1, 16, 16, generator=torch.Generator().manual_seed(7))
    with torch.no_grad():
        expected = enhancer(generated, image)
    assert not exporting()
    enhancer._head_by_taps = _refuse  # type: ignore[method-assign]
    traced = torch.jit.trace(enhancer, (generated, image), check_trace=False)
    exported = torch.export.export(enhancer, (generated, image)).module()
    with torch.no_grad():
        for program in (traced, exported):
            torch.testing.assert_close(program(generated, image), expected)


def test_compiled_network_equals_eager() -> None:
    # torch.compile with freezing (as the latency benchmark compiles): the taps form
    # compiles, the residual blocks run as written there, and the result is eager's;
    import torch._inductor.config as inductor_config

    # channels-last, as the benchmark runs it: there freezing turned the in-place
    # residual form into NaN (torch 2.13)
    model = build_model("GEA", 1, width=0.25, num_blocks=2).eval()
    randomise(model, 13, scale=0.3)
    model = model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    image = torch.rand(1, 1, 24, 32, generator=torch.Generator().manual_seed(13))
    image = image.contiguous(memory_format=torch.channels_last)
    with torch.inference_mode():
        eager = model.restore(image)
        with inductor_config.patch(freezing=True):
            compiled = torch.compile(model.restore)(image)
    assert torch.isfinite(compiled).all()
    torch.testing.assert_close(compiled, eager, rtol=1e-4, atol=1e-4)


def test_residual_blocks_refuse_a_one_pixel_side() -> None:
    # Reflection needs two pixels: the in-place form refuses as the layers do instead
    # of reading its buffers' uninitialised border.
    generator = Generator(1, 4, (8, 8), 16, num_blocks=2)
    with torch.no_grad(), pytest.raises(RuntimeError, match=r"[Pp]adding size"):
        generator._residual_features(torch.rand(1, 8, 1, 3))


@pytest.mark.parametrize("channels_last", [False, True])
@pytest.mark.parametrize(("height", "width"), [(8, 8), (12, 20), (36, 28)])
@pytest.mark.parametrize("norm", ["instance", "none"])
def test_residual_blocks_in_place_equal_the_blocks(
    channels_last: bool, height: int, width: int, norm: str
) -> None:
    # The in-place form (inference) gives exactly the blocks' values, down to a
    # 2x2 quarter-resolution map, where reflection reaches across the whole map.
    generator = Generator(1, 4, (8, 8), 16, num_blocks=3, norm=norm)
    randomise(generator, height * width, scale=0.3)
    quarter = torch.rand(2, 8, height // 4, width // 4, generator=torch.Generator().manual_seed(1))
    if channels_last:
        generator = generator.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        quarter = quarter.contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        expected = generator.blocks(generator.expand(quarter))
        actual = generator._residual_features(quarter)
    assert torch.equal(actual, expected)


def test_residual_blocks_keep_autograd_when_training() -> None:
    # With gradients recorded the blocks run as written: the input gets a gradient.
    generator = Generator(1, 4, (8, 8), 16, num_blocks=2)
    randomise(generator, 2, scale=0.3)
    quarter = torch.rand(1, 8, 5, 6, requires_grad=True)
    generator._residual_features(quarter).sum().backward()
    assert quarter.grad is not None and quarter.grad.abs().sum() > 0


@settings(max_examples=20, deadline=None)
@given(height=st.integers(2, 9), width=st.integers(2, 9), seed=st.integers(0, 2**16))
def test_reflect_border_is_reflection_padding(height: int, width: int, seed: int) -> None:
    interior = torch.rand(1, 3, height, width, generator=torch.Generator().manual_seed(seed))
    padded = torch.full((1, 3, height + 2, width + 2), float("nan"))
    padded[..., 1:-1, 1:-1] = interior
    _reflect_border(padded)
    expected = torch.nn.functional.pad(interior, (1, 1, 1, 1), mode="reflect")
    assert torch.equal(padded, expected)
