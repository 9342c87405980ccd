"""LSGAN, feature matching, perceptual and fidelity losses."""

import pytest
import torch

from lenspair.model.errors import ModelError
from lenspair.model.networks.vgg import VGG19Features
from lenspair.model.training.losses import (
    VGG_LAYER_WEIGHTS,
    LossWeights,
    PerceptualLoss,
    discriminator_loss,
    feature_matching_loss,
    fidelity_loss,
    generator_loss,
    lsgan_loss,
)


def test_lsgan_targets() -> None:
    logits = torch.tensor([[0.0, 1.0], [2.0, -1.0]])
    assert float(lsgan_loss(logits, True)) == pytest.approx((1 + 0 + 1 + 4) / 4)
    assert float(lsgan_loss(logits, False)) == pytest.approx((0 + 1 + 4 + 1) / 4)
    assert float(discriminator_loss(torch.ones(3), torch.zeros(3))) == 0.0
    assert float(lsgan_loss(torch.ones(2, 1, 3, 3, dtype=torch.bfloat16), True)) == 0.0


def test_feature_matching_skips_logits_and_detaches_real() -> None:
    fake = [
        torch.ones(1, 2, 4, 4, requires_grad=True),
        torch.zeros(1, 3, 2, 2),
        torch.zeros(1, 1, 1, 1),
    ]
    real = [
        torch.zeros(1, 2, 4, 4, requires_grad=True),
        torch.zeros(1, 3, 2, 2),
        torch.ones(1, 1, 1, 1),
    ]
    loss = feature_matching_loss(fake, real)
    # Two intermediate layers, weight 4 / 2 each; the logits (last) differ but do not count.
    assert loss.item() == pytest.approx(2.0)
    loss.backward()
    assert fake[0].grad is not None and real[0].grad is None
    with pytest.raises(ModelError, match="equally long"):
        feature_matching_loss(fake, real[:2])
    with pytest.raises(ModelError, match="shapes differ"):
        feature_matching_loss(
            [torch.zeros(1, 2), torch.zeros(1)], [torch.zeros(1, 3), torch.zeros(1)]
        )


def test_fidelity_is_mse() -> None:
    a = torch.zeros(1, 1, 2, 2)
    b = torch.tensor([[[[1.0, 0.0], [0.0, 1.0]]]])
    assert float(fidelity_loss(a, b)) == pytest.approx(0.5)
    with pytest.raises(ModelError, match="shapes differ"):
        fidelity_loss(a, torch.zeros(1, 1, 2, 3))


def test_perceptual_loss_weights_and_gradients() -> None:
    torch.manual_seed(0)
    vgg = VGG19Features()
    loss_fn = PerceptualLoss(vgg)
    assert loss_fn.layer_weights == VGG_LAYER_WEIGHTS
    target = torch.rand(1, 1, 16, 16)
    output = target.clone().requires_grad_(True)
    assert loss_fn(output, target).item() == 0.0
    output = torch.rand(1, 1, 16, 16, requires_grad=True)
    loss = loss_fn(output, target)
    loss.backward()
    assert loss.item() > 0 and output.grad is not None and float(output.grad.abs().sum()) > 0
    assert all(p.grad is None for p in vgg.parameters())
    with pytest.raises(ModelError, match="expected 5 layer weights"):
        PerceptualLoss(vgg, layer_weights=(1.0, 1.0))


def test_generator_loss_terms() -> None:
    features = [torch.rand(2, 4, 4, 4), torch.rand(2, 1, 2, 2)]
    enhanced = torch.rand(2, 1, 16, 16)
    target = torch.rand(2, 1, 16, 16)
    weights = LossWeights(adversarial=2.0, feature_matching=3.0, perceptual=4.0, fidelity=5.0)
    terms = generator_loss(features, features, enhanced, target, weights, perceptual=None)
    assert set(terms) == {"adversarial", "feature_matching", "fidelity", "total"}
    assert float(terms["feature_matching"]) == 0.0
    assert float(terms["fidelity"]) == pytest.approx(5.0 * float(((enhanced - target) ** 2).mean()))
    assert float(terms["total"]) == pytest.approx(
        float(terms["adversarial"] + terms["feature_matching"] + terms["fidelity"])
    )
    with_vgg = generator_loss(
        features, features, enhanced, target, weights, perceptual=PerceptualLoss(VGG19Features())
    )
    assert "perceptual" in with_vgg and float(with_vgg["perceptual"]) > 0
