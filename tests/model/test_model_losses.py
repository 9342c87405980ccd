"""LSGAN, feature matching, perceptual and fidelity losses."""

from dataclasses import replace

import pytest
import torch

from lenspair.model.errors import ModelError
from lenspair.model.networks.vgg import VGG19Features
from lenspair.model.training.losses import (
    VGG_LAYER_WEIGHTS,
    PerceptualLoss,
    discriminator_loss,
    feature_matching_loss,
    fidelity_loss,
    lsgan_loss,
)
from lenspair.model.training.step import Trainer
from tests.model.train_fixtures import tiny_config


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


def test_training_weights_each_term_by_its_config_weight() -> None:
    # what training runs: Trainer.generator_terms, weights from the run config's loss section
    # (a test-only generator_loss had stood for it, so a slip in training went unseen)
    config = tiny_config()
    config = replace(
        config, loss=replace(config.loss, adversarial=2.0, feature_matching=3.0, fidelity=5.0)
    )
    trainer = Trainer(config, torch.device("cpu"))
    generator = torch.Generator().manual_seed(0)
    x, target = torch.rand(2, 1, 32, 32, generator=generator), torch.rand(2, 1, 32, 32)
    valid = torch.ones(2, 1, 32, 32)
    with torch.no_grad():
        total, terms, _ = trainer.generator_terms(x, target, valid)
        enhanced = trainer.network(x)[1]
    assert set(terms) == {"adversarial", "feature_matching", "fidelity"}  # no VGG weights here
    weighted = (
        2.0 * terms["adversarial"] + 3.0 * terms["feature_matching"] + 5.0 * terms["fidelity"]
    )
    assert float(total) == pytest.approx(float(weighted))
    assert float(terms["fidelity"]) == pytest.approx(float(((enhanced - target) ** 2).mean()))


def test_fidelity_is_the_mean_over_trusted_pixels() -> None:
    enhanced, target = torch.zeros(1, 1, 2, 4), torch.ones(1, 1, 2, 4)
    target[..., :2] = 3.0  # the untrusted half: an error of 9 that must not count
    valid = torch.ones(1, 1, 2, 4)
    valid[..., :2] = 0
    assert float(fidelity_loss(enhanced, target, valid)) == pytest.approx(1.0)
    assert float(fidelity_loss(enhanced, target)) == pytest.approx(5.0)
    assert float(fidelity_loss(enhanced, target, torch.zeros(1, 1, 2, 4))) == 0.0  # all untrusted
