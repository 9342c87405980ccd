"""Training losses of the shallow GAN (pix2pixHD's recipe plus an L2 fidelity term).

* LSGAN adversarial loss (Mao et al.): the discriminator regresses its patch
  logits to 1 for real and 0 for fake pairs; the generator pushes fake
  logits towards 1. Least squares instead of cross-entropy: no saturation,
  stabler training (pix2pixHD's choice).
* Feature matching (pix2pixHD): L1 distance between the discriminator's
  intermediate features of the fake and the real pair, real side detached,
  each layer weighted ``4 / (num_layers + 1)``.
* VGG19 perceptual loss (pix2pixHD's ``VGGLoss``): L1 distance between
  ``relu1_1 ... relu5_1`` features with weights 1/32, 1/16, 1/8, 1/4, 1,
  target side detached.
* L2 fidelity: mean squared error between the enhanced output and the clean
  target.

Where each term applies (``Trainer.generator_terms`` in
:mod:`lenspair.model.training.step`, weights from ``LossConfig``): the adversarial and
feature-matching terms to G's output (the discriminator judges
``cat(input, generated)``), the perceptual and fidelity terms to the enhanced,
final output (for variant ``G`` both outputs are the same tensor).

All losses are scalar tensors averaged over the batch (mean reductions).
Images are ``(N, C, H, W)`` float in [0, 1].
"""

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lenspair.model.errors import ModelError
from lenspair.model.networks.vgg import VGG19Features

VGG_LAYER_WEIGHTS: tuple[float, ...] = (1 / 32, 1 / 16, 1 / 8, 1 / 4, 1.0)
"""Weights of relu1_1 ... relu5_1 in the perceptual loss (pix2pixHD)."""


def lsgan_loss(logits: Tensor, target_is_real: bool) -> Tensor:
    """LSGAN loss: mean squared distance of patch logits to 1 (real) or 0 (fake).

    Args:
        logits: raw patch logits, any shape (the discriminator's last output).
        target_is_real: regress towards 1 if True, 0 otherwise.

    Returns:
        Scalar loss (float32 even under autocast).
    """
    logits = logits.float()
    target = torch.ones_like(logits) if target_is_real else torch.zeros_like(logits)
    return F.mse_loss(logits, target)


def discriminator_loss(real_logits: Tensor, fake_logits: Tensor) -> Tensor:
    """LSGAN discriminator loss ``(mse(real, 1) + mse(fake, 0)) / 2`` (pix2pixHD halves it).

    Args:
        real_logits: D's logits for ``cat(input, target)``.
        fake_logits: D's logits for ``cat(input, generated.detach())``.

    Returns:
        Scalar loss.
    """
    return 0.5 * (lsgan_loss(real_logits, True) + lsgan_loss(fake_logits, False))


def feature_matching_loss(
    fake_features: Sequence[Tensor], real_features: Sequence[Tensor]
) -> Tensor:
    """pix2pixHD feature matching over the discriminator's intermediate features.

    Args:
        fake_features: D's outputs for the generated pair (gradients flow to G).
        real_features: D's outputs for the real pair (detached here).

    Returns:
        ``sum_i L1(fake_i, real_i) * 4 / (num_layers + 1)`` over every output
        but the last (the logits), with ``num_layers = len(features) - 2``.

    Raises:
        ModelError: if the two lists differ in length or shapes, or hold
            fewer than two entries.
    """
    if len(fake_features) != len(real_features) or len(fake_features) < 2:
        raise ModelError(
            "feature matching: expected two equally long feature lists with at least two "
            f"entries, got {len(fake_features)} and {len(real_features)}"
        )
    weight = 4.0 / (len(fake_features) - 1)
    total = fake_features[0].new_zeros((), dtype=torch.float32)
    for fake, real in zip(fake_features[:-1], real_features[:-1], strict=True):
        if fake.shape != real.shape:
            raise ModelError(
                f"feature matching: shapes differ, {tuple(fake.shape)} vs {tuple(real.shape)}"
            )
        total = total + weight * F.l1_loss(fake.float(), real.detach().float())
    return total


def fidelity_loss(enhanced: Tensor, target: Tensor, valid: Tensor | None = None) -> Tensor:
    """L2 fidelity: mean squared error between the restored and the clean image.

    Args:
        enhanced: ``(N, C, H, W)`` restored image in [0, 1].
        target: ``(N, C, H, W)`` clean image in [0, 1].
        valid: ``(N, 1, H, W)``, 1 where the target is trusted and 0 where a
            mask marks it untrustworthy; the mean is over the trusted pixels
            (``None``: all).

    Returns:
        Scalar loss, fp32.

    Raises:
        ModelError: if the shapes differ.
    """
    if enhanced.shape != target.shape:
        raise ModelError(
            f"fidelity loss: shapes differ, {tuple(enhanced.shape)} vs {tuple(target.shape)}"
        )
    if valid is None:
        return F.mse_loss(enhanced.float(), target.float())
    error = (enhanced.float() - target.float()) ** 2 * valid
    return error.sum() / (valid.sum() * enhanced.shape[1]).clamp_min(1.0)


class PerceptualLoss(nn.Module):
    """pix2pixHD ``VGGLoss``: weighted L1 between VGG19 ``relu*_1`` features.

    Forward contract: ``(N, C, H, W)`` output and target in [0, 1], ``C`` in
    {1, 3}, ``H, W >= 16`` (four max-pools) -> scalar loss.
    """

    def __init__(
        self, vgg: VGG19Features, layer_weights: Sequence[float] = VGG_LAYER_WEIGHTS
    ) -> None:
        """Create the loss around a loaded (frozen) VGG19.

        Args:
            vgg: features from :func:`lenspair.model.networks.vgg.load_vgg19`.
            layer_weights: one weight per tapped layer (five).

        Raises:
            ModelError: if there are not five weights.
        """
        super().__init__()
        if len(layer_weights) != len(VGG_LAYER_WEIGHTS):
            raise ModelError(
                f"perceptual loss: expected {len(VGG_LAYER_WEIGHTS)} layer weights, "
                f"got {len(layer_weights)}"
            )
        self.vgg = vgg
        self.layer_weights = tuple(float(w) for w in layer_weights)

    def forward(self, output: Tensor, target: Tensor) -> Tensor:
        """Compute the loss (target features are detached).

        Args:
            output: restored image, ``(N, C, H, W)`` in [0, 1].
            target: clean image, same shape.

        Returns:
            Scalar loss.
        """
        if output.shape != target.shape:
            raise ModelError(
                f"perceptual loss: shapes differ, {tuple(output.shape)} vs {tuple(target.shape)}"
            )
        output_features = self.vgg(output)
        with torch.no_grad():
            target_features = self.vgg(target)
        total = output.new_zeros((), dtype=torch.float32)
        for weight, out, ref in zip(
            self.layer_weights, output_features, target_features, strict=True
        ):
            total = total + weight * F.l1_loss(out.float(), ref.float())
        return total
