"""Hard cases stay finite: constant and saturated images, flat frames, bf16, a GAN step."""

import math
import threading

import pytest
import torch

from lenspair.model.checkpoint import load_model
from lenspair.model.networks.enhancer import Enhancer
from lenspair.model.networks.flat_frames import FLAT_RAMP, FLAT_RMS_RAMP, FLAT_TOLERANCE, flat_keep
from lenspair.model.networks.layers import InstanceNorm
from lenspair.model.networks.variants import build_model
from lenspair.model.training.pretrained import pretrained_weights
from lenspair.model.training.step import Trainer
from tests.model.network_helpers import randomise
from tests.model.train_fixtures import tiny_config

TINY = {"width": 0.25, "num_blocks": 2}


def _finite(tensor: torch.Tensor | None) -> bool:
    return tensor is not None and bool(torch.isfinite(tensor).all())


@pytest.mark.parametrize("value", [0.0, 1.0, 0.5])
@pytest.mark.parametrize("variant", ["G", "GEA"])
def test_constant_and_saturated_images_give_finite_outputs_and_gradients(
    value: float, variant: str
) -> None:
    model = build_model(variant, 1, **TINY)
    randomise(model)
    x = torch.full((2, 1, 20, 36), value, requires_grad=True)
    out = model(x)
    assert _finite(out.generator) and _finite(out.enhanced)
    (out.enhanced.square().mean() + out.generator.mean()).backward()
    assert _finite(x.grad)
    for name, parameter in model.named_parameters():
        assert _finite(parameter.grad), name


def test_enhancer_pooling_on_constant_and_tiny_images() -> None:
    enhancer = Enhancer(3, num_filters=4)
    randomise(enhancer)
    for size in [(8, 8), (31, 33), (64, 96)]:
        image = torch.ones(1, 3, *size, requires_grad=True)
        generated = torch.ones(1, 3, *size)
        out = enhancer(generated, image)
        assert out.shape == generated.shape and _finite(out)
        out.sum().backward()
        assert _finite(image.grad)


def test_bf16_autocast_forward_is_finite_and_close() -> None:
    model = build_model("GEA", 1, **TINY)
    randomise(model)
    x = torch.rand(1, 1, 24, 40, generator=torch.Generator().manual_seed(0))
    with torch.inference_mode():
        reference = model(x).enhanced
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low = model(x).enhanced
    assert low.shape == x.shape and _finite(low)
    assert float((low.float() - reference).abs().max()) < 0.1


def test_bf16_weights_forward_is_finite() -> None:
    model = build_model("GE", 3, **TINY)
    randomise(model)
    model = model.to(torch.bfloat16)
    x = torch.full((1, 3, 16, 24), 1.0, dtype=torch.bfloat16)
    with torch.inference_mode():
        out = model(x)
        assert out.enhanced.dtype == torch.bfloat16 and _finite(out.enhanced)
        model = model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        out_cl = model(x.contiguous(memory_format=torch.channels_last))
    assert _finite(out_cl.enhanced)
    assert torch.allclose(out_cl.enhanced.float(), out.enhanced.float(), atol=0.05)


def test_fp32_gan_training_step_without_nan() -> None:
    # what training runs (Trainer.train_step): a saturated image in the batch
    torch.manual_seed(0)
    trainer = Trainer(tiny_config(), torch.device("cpu"))
    x = torch.rand(2, 1, 48, 48)
    x[0] = 1.0  # one saturated image in the batch
    batch = {"input": x, "target": (x * 0.8).clamp(0, 1), "valid": torch.ones(2, 1, 48, 48)}
    for _ in range(2):
        result = trainer.train_step(batch)
        assert not result.skipped
        assert {"loss_g", "loss_d", "adversarial", "fidelity"} <= set(result.losses)
        assert all(math.isfinite(value) for value in result.losses.values())
    for parameter in [*trainer.model.parameters(), *trainer.discriminator.parameters()]:
        assert _finite(parameter)


def _shipped_gea() -> torch.nn.Module:
    # trained weights: an untrained GEA's heads start at zero and hide what its norms do
    return load_model(pretrained_weights(1), "cpu").network.eval()


@pytest.mark.parametrize("value", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("layout", ["channels-last", "bf16 channels-last", "bf16 autocast"])
def test_a_flat_frame_restores_flat_in_every_layout_and_precision(
    value: float, layout: str
) -> None:
    network = _shipped_gea()
    frame = torch.full((1, 1, 96, 128), value)
    with torch.inference_mode():
        reference = network(frame).enhanced  # NCHW fp32: exact zero variance in every norm
        network.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        x = frame.contiguous(memory_format=torch.channels_last)
        if layout == "bf16 channels-last":
            out = network.to(torch.bfloat16)(x.bfloat16()).enhanced.float()
        elif layout == "bf16 autocast":
            with torch.autocast("cpu", dtype=torch.bfloat16):
                out = network(x).enhanced.float()
        else:
            out = network(x).enhanced
    # rounding noise amplified by the norms made a mid-grey frame 10..158 of 255
    inner = out[..., 4:-4, 4:-4]  # the enhancer's zero padding shades the border slightly
    assert float(inner.amax() - inner.amin()) < 2e-3
    assert float((out - reference).abs().amax()) < 8e-3


def _textured_and_flat(
    seed: int, level: float
) -> tuple[torch.nn.Module, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The shipped GEA, a textured and a flat frame, and the textured one restored alone."""
    network = _shipped_gea()
    textured = torch.rand((1, 1, 64, 96), generator=torch.Generator().manual_seed(seed))
    flat = torch.full((1, 1, 64, 96), level)
    with torch.inference_mode():
        alone = network(textured).enhanced
    return network, textured, flat, alone


def test_flat_samples_do_not_change_the_other_samples_of_a_batch() -> None:
    network, textured, flat, alone = _textured_and_flat(seed=3, level=0.3)
    with torch.inference_mode():
        together = network(torch.cat([textured, flat, textured])).enhanced
    torch.testing.assert_close(together[0:1], alone, rtol=0, atol=1e-6)
    torch.testing.assert_close(together[2:3], alone, rtol=0, atol=1e-6)
    assert float(together[1, :, 4:-4, 4:-4].std()) < 1e-3


def test_only_flat_samples_are_marked() -> None:
    texture = torch.rand((2, 3, 16, 20), generator=torch.Generator().manual_seed(1))
    assert flat_keep(texture) is None  # nothing flat: the norms run as they always did
    batch = texture.clone()
    batch[1] = torch.tensor([0.2, 0.5, 0.9]).view(3, 1, 1)  # flat: each channel constant
    batch[1, 0, 3, 4] += 0.4 * FLAT_TOLERANCE  # within the tolerance
    keep = flat_keep(batch.contiguous(memory_format=torch.channels_last))
    assert keep is not None and keep.flatten().tolist() == [1.0, 0.0]
    # one channel varies by little everywhere: nearly flat, by either measure
    bump = torch.where(torch.arange(320).view(16, 20) % 2 == 0, 1.0, -1.0)
    batch[1, 2] += 1.5 * FLAT_TOLERANCE * bump
    for layout in (torch.contiguous_format, torch.channels_last):
        keep = flat_keep(batch.contiguous(memory_format=layout))
        assert keep is not None and keep[0].item() == 1.0 and 0.0 < keep[1].item() < 1.0
    batch[1, 2] += FLAT_RAMP * bump  # varies as much as a camera's noise: not flat
    assert flat_keep(batch) is None


@pytest.mark.parametrize("layout", [torch.contiguous_format, torch.channels_last])
def test_a_noiseless_flat_frame_with_a_speck_counts_as_flat(
    layout: torch.memory_format,
) -> None:
    """Its spread at the speck passed the ramp, but its energy is that of a flat frame: the
    norms scaled the speck up 316x, and 4 codes off mid-grey came out as a blotch of 75."""
    frame = torch.full((1, 3, 64, 96), 0.5)
    for speck in (4.0, 30.0):
        for where in ((32, 48), (0, 0)):  # the corner too: the RMS is about the mean
            specked = frame.clone()
            specked[0, 0, where[0], where[1]] += speck / 255.0
            keep = flat_keep(specked.contiguous(memory_format=layout))
            assert keep is not None and keep.item() == 0.0, (speck, where)
    # a camera's noise of about a code is not flat, whatever its spread
    noise = torch.randn((1, 3, 64, 96), generator=torch.Generator().manual_seed(2))
    assert flat_keep((frame + noise * FLAT_RMS_RAMP * 1.2).contiguous(memory_format=layout)) is None


def test_the_shipped_network_leaves_a_speck_on_a_flat_frame_local() -> None:
    """At most the speck itself changes, as with a camera's noise; a 4-code speck on mid-grey
    made a 75-code blotch about 50 pixels wide."""
    network = _shipped_gea()
    frame = torch.full((1, 1, 96, 128), 0.5)
    specked = frame.clone()
    specked[0, 0, 48, 64] += 4 / 255
    with torch.inference_mode():
        change = (network(specked).enhanced - network(frame).enhanced).abs().clone()
        change[0, 0, 48, 64] = 0.0
    assert float(change.max()) < 1 / 255


def test_the_output_is_continuous_across_the_flat_tolerance() -> None:
    # a white frame with one pixel just past the tolerance came out with a dark blotch,
    # one just within it stayed white: a hard switch between two outputs
    network = load_model(pretrained_weights(1), torch.device("cpu")).network.eval().double()
    outputs = []
    with torch.inference_mode():
        for dip in (0.99 * FLAT_TOLERANCE, 1.01 * FLAT_TOLERANCE):
            frame = torch.ones((1, 1, 48, 64), dtype=torch.float64)
            frame[0, 0, 20, 30] -= dip
            outputs.append(network(frame).enhanced)
    assert float((outputs[0] - outputs[1]).abs().max()) < 1e-3


def test_a_flat_frame_in_one_thread_does_not_mask_another_threads_frames() -> None:
    network, textured, flat, alone = _textured_and_flat(seed=5, level=0.5)
    first_norm = next(m for m in network.modules() if isinstance(m, InstanceNorm))
    events = {name: threading.Event() for name in ("textured in", "flat in", "textured done")}

    def interleave(module: torch.nn.Module, args: tuple[torch.Tensor]) -> None:
        # the textured forward pauses at its first norm until the flat forward has
        # set its mask and paused in turn; then the textured one runs to its end
        if threading.current_thread().name == "textured":
            events["textured in"].set()
            assert events["flat in"].wait(30)
        elif threading.current_thread().name == "flat":
            events["flat in"].set()
            assert events["textured done"].wait(30)

    outputs: dict[str, torch.Tensor] = {}

    def run(name: str, frame: torch.Tensor) -> None:
        with torch.inference_mode():
            outputs[name] = network(frame).enhanced
        if name == "textured":
            events["textured done"].set()

    handle = first_norm.register_forward_pre_hook(interleave)
    threads = [
        threading.Thread(target=run, args=(name, frame), name=name)
        for name, frame in (("textured", textured), ("flat", flat))
    ]
    threads[0].start()
    assert events["textured in"].wait(30)
    threads[1].start()
    for thread in threads:
        thread.join(30)
    handle.remove()
    # a mask shared by the threads (an attribute of the norms) zeroed the
    # textured frame's norms while the flat frame's forward held it
    torch.testing.assert_close(outputs["textured"], alone, rtol=0, atol=1e-6)
    assert float(outputs["flat"][..., 4:-4, 4:-4].std()) < 1e-3
