"""Hard cases stay finite: constant and saturated images, bf16, a full GAN training step."""

import pytest
import torch

from lenspair.model.networks.enhancer import Enhancer
from lenspair.model.networks.variants import build_discriminator, build_model
from lenspair.model.training.losses import LossWeights, discriminator_loss, generator_loss

TINY = {"width": 0.25, "num_blocks": 2}


def _randomise(model: torch.nn.Module, seed: int = 1) -> None:
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.copy_(0.1 * torch.randn(parameter.shape, generator=generator))


def _finite(tensor: torch.Tensor | None) -> bool:
    return tensor is not None and bool(torch.isfinite(tensor).all())


@pytest.mark.parametrize("value", [0.0, 1.0, 0.5])
@pytest.mark.parametrize("variant", ["G", "GEA"])
def test_constant_and_saturated_images_give_finite_outputs_and_gradients(
    value: float, variant: str
) -> None:
    model = build_model(variant, 1, **TINY)
    _randomise(model)
    x = torch.full((2, 1, 20, 36), value, requires_grad=True)
    out = model(x)
    assert _finite(out.generator) and _finite(out.enhanced)
    (out.enhanced.square().mean() + out.generator.mean()).backward()
    assert _finite(x.grad)
    for name, parameter in model.named_parameters():
        assert _finite(parameter.grad), name


def test_enhancer_pooling_on_constant_and_tiny_images() -> None:
    enhancer = Enhancer(3, num_filters=4)
    _randomise(enhancer)
    for size in [(8, 8), (31, 33), (64, 96)]:
        image = torch.ones(1, 3, *size, requires_grad=True)
        generated = torch.ones(1, 3, *size)
        out = enhancer(generated, image)
        assert out.shape == generated.shape and _finite(out)
        out.sum().backward()
        assert _finite(image.grad)


def test_bf16_autocast_forward_is_finite_and_close() -> None:
    model = build_model("GEA", 1, **TINY)
    _randomise(model)
    x = torch.rand(1, 1, 24, 40, generator=torch.Generator().manual_seed(0))
    with torch.inference_mode():
        reference = model(x).enhanced
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low = model(x).enhanced
    assert low.shape == x.shape and _finite(low)
    assert float((low.float() - reference).abs().max()) < 0.1


def test_bf16_weights_forward_is_finite() -> None:
    model = build_model("GE", 3, **TINY)
    _randomise(model)
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
    torch.manual_seed(0)
    model = build_model("GEA", 1, **TINY)
    discriminator = build_discriminator(1, width=0.125)
    optimizer_g = torch.optim.Adam(model.parameters(), lr=2e-4, betas=(0.5, 0.999))
    optimizer_d = torch.optim.Adam(discriminator.parameters(), lr=2e-4, betas=(0.5, 0.999))
    x = torch.rand(2, 1, 48, 48)
    x[0] = 1.0  # one saturated image in the batch
    target = (x * 0.8).clamp(0, 1)
    for _ in range(2):
        out = model(x)
        fake = discriminator(torch.cat([x, out.generator], dim=1))
        with torch.no_grad():
            real = discriminator(torch.cat([x, target], dim=1))
        terms = generator_loss(fake, real, out.enhanced, target, LossWeights(), perceptual=None)
        optimizer_g.zero_grad()
        terms["total"].backward()
        optimizer_g.step()
        real_logits = discriminator(torch.cat([x, target], dim=1))[-1]
        fake_logits = discriminator(torch.cat([x, out.generator.detach()], dim=1))[-1]
        loss_d = discriminator_loss(real_logits, fake_logits)
        optimizer_d.zero_grad()
        loss_d.backward()
        optimizer_d.step()
        assert all(_finite(value) for value in terms.values()) and _finite(loss_d)
    for parameter in [*model.parameters(), *discriminator.parameters()]:
        assert _finite(parameter)
