"""The paper's ablation variants G, GE and GEA behind one top-level module.

=======  ===========================================================
variant  networks
=======  ===========================================================
``G``    generator only (additive skip connections)
``GE``   generator + enhancer
``GEA``  generator with aggregation blocks + enhancer (the full model)
=======  ===========================================================

Image convention, inputs and outputs: ``NCHW``, ``float32`` (or bf16/fp16
under autocast), range [0, 1], ``C`` = 1 (mono, as the paper's rig records)
or 3 (RGB), any ``H, W >= 8``. The generator needs multiples of 4: the input
is reflection-padded at the bottom/right and the outputs are cropped back, so
every output has the input's size. Outputs are in [0, 1] by construction
(residual on the input, straight-through clamp; see :mod:`lenspair.model.networks.generator`).

Width multiplies every filter count (G: 8/16/32/64, E: 16; D: 64), rounded
and at least 1.
"""

from dataclasses import dataclass
from typing import NamedTuple

from torch import Tensor, nn

from lenspair.model.errors import ModelError
from lenspair.model.networks.discriminator import PatchDiscriminator
from lenspair.model.networks.enhancer import Enhancer
from lenspair.model.networks.generator import DOWNSAMPLING_FACTOR, Generator
from lenspair.model.networks.layers import init_weights, scaled_channels
from lenspair.model.networks.padding import check_image_batch, crop_to, pad_to_multiple

SUPPORTED_CHANNELS = (1, 3)
"""Image channel counts the models accept (mono and RGB)."""


@dataclass(frozen=True)
class VariantSpec:
    """What one ablation variant contains.

    Attributes:
        enhancer: whether the EPDN-style enhancer E refines G's output.
        aggregation: whether G uses aggregation blocks (A) instead of additive skips.
        description: one line for tables and logs.
    """

    enhancer: bool
    aggregation: bool
    description: str


VARIANTS: dict[str, VariantSpec] = {
    "G": VariantSpec(enhancer=False, aggregation=False, description="generator only"),
    "GE": VariantSpec(enhancer=True, aggregation=False, description="generator + enhancer"),
    "GEA": VariantSpec(
        enhancer=True, aggregation=True, description="generator + enhancer + aggregation"
    ),
}
"""The ablation variants by name."""


def variant_spec(name: str) -> VariantSpec:
    """Look up a variant by name.

    Args:
        name: ``"G"``, ``"GE"`` or ``"GEA"``.

    Returns:
        Its :class:`VariantSpec`.

    Raises:
        ModelError: for an unknown name (the message lists the valid ones).
    """
    try:
        return VARIANTS[name]
    except KeyError:
        raise ModelError(
            f"unknown model variant {name!r}; valid variants: {', '.join(VARIANTS)}"
        ) from None


class MitigatorOutput(NamedTuple):
    """What :class:`AnomalyMitigator` returns; both ``(N, C, H, W)`` in [0, 1].

    Attributes:
        generator: G's output (adversarial and feature-matching losses apply here).
        enhanced: E's refinement of it, the final restored image (the L2
            fidelity loss applies here). For variant ``G`` this is the very
            same tensor as ``generator``.
    """

    generator: Tensor
    enhanced: Tensor


class AnomalyMitigator(nn.Module):
    """The restoration network of Fumagalli et al.: G, plus E and A per variant.

    Forward contract: ``(N, C, H, W)`` float in [0, 1], any ``H, W >= 8`` ->
    :class:`MitigatorOutput` of two ``(N, C, H, W)`` tensors in [0, 1].
    """

    def __init__(
        self, variant: str, channels: int, width: float = 1.0, num_blocks: int = 9
    ) -> None:
        """Create the network (pix2pix initialisation, zero-initialised residual heads).

        Args:
            variant: ``"G"``, ``"GE"`` or ``"GEA"`` (see :data:`VARIANTS`).
            channels: 1 (mono) or 3 (RGB).
            width: multiplier of every filter count, > 0.
            num_blocks: residual blocks in G (9 in the paper), >= 0.

        Raises:
            ModelError: on an unknown variant, unsupported channel count,
                non-positive width or negative ``num_blocks``.
        """
        super().__init__()
        spec = variant_spec(variant)
        if channels not in SUPPORTED_CHANNELS:
            raise ModelError(f"channels must be 1 (mono) or 3 (RGB), got {channels}")
        self.variant = variant
        self.channels = channels
        self.width = width
        self.num_blocks = num_blocks
        self.generator = Generator(
            channels,
            stem_filters=scaled_channels(8, width),
            down_filters=(scaled_channels(16, width), scaled_channels(32, width)),
            residual_filters=scaled_channels(64, width),
            num_blocks=num_blocks,
            aggregation=spec.aggregation,
        )
        self.enhancer: Enhancer | None = (
            Enhancer(channels, num_filters=scaled_channels(16, width)) if spec.enhancer else None
        )
        init_weights(self)
        # init_weights overwrote the residual heads; make them start as identity again.
        nn.init.zeros_(self.generator.head.weight)
        if self.enhancer is not None:
            nn.init.zeros_(self.enhancer.fuse.weight)

    def forward(self, x: Tensor) -> MitigatorOutput:
        """Restore a batch of obstructed images.

        Args:
            x: ``(N, C, H, W)`` float in [0, 1], ``H, W >= 8``.

        Returns:
            :class:`MitigatorOutput` (generator output, enhanced output), both
            ``(N, C, H, W)`` in [0, 1].

        Raises:
            ModelError: if ``x`` is not such a batch.
        """
        check_image_batch(x, self.channels, name="model input")
        height, width = x.shape[-2:]
        generated = crop_to(self.generator(pad_to_multiple(x, DOWNSAMPLING_FACTOR)), height, width)
        if self.enhancer is None:
            return MitigatorOutput(generated, generated)
        return MitigatorOutput(generated, self.enhancer(generated, x))

    def restore(self, x: Tensor) -> Tensor:
        """Return only the final restored image (``forward(x).enhanced``).

        Args:
            x: ``(N, C, H, W)`` float in [0, 1], ``H, W >= 8``.

        Returns:
            ``(N, C, H, W)`` in [0, 1].
        """
        return self.forward(x).enhanced


def build_model(
    variant: str, channels: int, width: float = 1.0, num_blocks: int = 9
) -> AnomalyMitigator:
    """Build a restoration network by variant name.

    Args:
        variant: ``"G"``, ``"GE"`` or ``"GEA"``.
        channels: 1 (mono) or 3 (RGB).
        width: multiplier of every filter count, > 0.
        num_blocks: residual blocks in G, >= 0.

    Returns:
        The network on the CPU; move it with ``.to(device)``.

    Raises:
        ModelError: on an unknown variant (listing the valid ones) or bad arguments.
    """
    return AnomalyMitigator(variant, channels, width=width, num_blocks=num_blocks)


def build_discriminator(
    channels: int, width: float = 1.0, num_layers: int = 3, norm: str = "instance"
) -> PatchDiscriminator:
    """Build the conditional PatchGAN discriminator for ``channels``-channel images.

    It reads ``cat([obstructed_input, image], dim=1)`` (``2 * channels`` channels).

    Args:
        channels: 1 (mono) or 3 (RGB).
        width: multiplier of the 64 base filters, > 0.
        num_layers: stride-2 layers (3: the 70x70 PatchGAN).
        norm: ``"instance"`` (pix2pixHD) or ``"none"``.

    Returns:
        The initialised discriminator.

    Raises:
        ModelError: on an unsupported channel count or bad arguments.
    """
    if channels not in SUPPORTED_CHANNELS:
        raise ModelError(f"channels must be 1 (mono) or 3 (RGB), got {channels}")
    discriminator = PatchDiscriminator(
        2 * channels, num_filters=scaled_channels(64, width), num_layers=num_layers, norm=norm
    )
    init_weights(discriminator)
    return discriminator
