"""The generator G: a pix2pixHD global generator, made much lighter.

Layer table at width 1.0 for ``C`` image channels (``H x W`` is already a
multiple of 4, see :mod:`lenspair.model.networks.padding`); IN is instance norm
(``affine=False``, ``eps=1e-5``), as in pix2pixHD:

========  ==========================================================  =====  =====
name      layers                                                      out    scale
========  ==========================================================  =====  =====
stem      reflect-pad 3, conv 7x7, IN, ReLU                           8      1
down1     conv 3x3 stride 2 (zero pad 1), IN, ReLU                    16     1/2
agg1 [A]  cat(avg-pool2(stem), down1), conv 3x3, IN, ReLU             16     1/2
down2     conv 3x3 stride 2 (zero pad 1), IN, ReLU                    32     1/2->1/4
agg2 [A]  cat(avg-pool2(agg1), down2), conv 3x3, IN, ReLU             32     1/4
expand    conv 1x1, IN, ReLU                                          64     1/4
res x9    x + IN(conv3x3(ReLU(IN(conv3x3(x)))))  (reflect pad 1)      64     1/4
up1       conv-transpose 3x3 stride 2 (pad 1, out-pad 1), IN, ReLU    16     1/2
skip1     [A] cat(agg1, up1), conv 3x3, IN, ReLU; else up1 + down1    16     1/2
up2       conv-transpose 3x3 stride 2, IN, ReLU                       8      1
skip0     [A] cat(stem, up2), conv 3x3, IN, ReLU; else up2 + stem     8      1
head      reflect-pad 3, conv 7x7 (bias, zero-initialised)            C      1
output    clamp01(x + head)  (straight-through clamp)                 C      1
========  ==========================================================  =====  =====

The head is a :class:`~lenspair.model.networks.layers.NarrowConv2d` (an ``nn.Conv2d`` computed
depthwise, faster for one or three output channels). Rows marked ``[A]``
exist only with aggregation (variant ``GEA``); without it the decoder's skip
connections are additive, as in pix2pixHD's local
enhancer. Filter counts scale with the width multiplier
(:func:`lenspair.model.networks.layers.scaled_channels`).

Output range: the network predicts a residual that is added to the input
image, then clamped to [0, 1] with a straight-through gradient
(:func:`lenspair.model.networks.layers.clamp_unit_straight_through`). A residual fits image
restoration (most pixels are already right), starts as the identity because
the head is zero-initialised, and unlike pix2pixHD's ``tanh`` output never
saturates the gradient.
"""

from torch import Tensor, nn

from lenspair.model.errors import ModelError
from lenspair.model.networks.aggregation import Aggregation
from lenspair.model.networks.layers import (
    ConvNormReLU,
    NarrowConv2d,
    clamp_unit_straight_through,
    flat_samples,
    make_norm,
    zero_init,
)

DOWNSAMPLING_FACTOR = 4
"""Input height and width must be multiples of this (two stride-2 stages)."""


class ResidualBlock(nn.Module):
    """pix2pixHD residual block: ``x + IN(conv3x3(ReLU(IN(conv3x3(x)))))``.

    Shapes: ``(N, channels, H, W) -> (N, channels, H, W)``, with ``H, W >= 2``.
    """

    def __init__(self, channels: int, norm: str = "instance") -> None:
        """Create the block.

        Args:
            channels: input and output channels.
            norm: a key of :data:`lenspair.model.networks.layers.NORMS`.
        """
        super().__init__()
        second_norm = make_norm(norm, channels)
        self.body = nn.Sequential(
            ConvNormReLU(channels, channels, kernel_size=3, norm=norm),
            nn.Conv2d(
                channels,
                channels,
                3,
                padding=1,
                padding_mode="reflect",
                bias=isinstance(second_norm, nn.Identity),
            ),
            second_norm,
        )

    def forward(self, x: Tensor) -> Tensor:
        """Apply the block (see the class docstring for shapes)."""
        residual: Tensor = self.body(x)
        return x + residual


class Generator(nn.Module):
    """The light pix2pixHD generator (see the module docstring for the layer table).

    Forward contract: ``(N, C, H, W)`` float in [0, 1] with ``H`` and ``W``
    multiples of :data:`DOWNSAMPLING_FACTOR` -> ``(N, C, H, W)`` in [0, 1].
    """

    def __init__(
        self,
        channels: int,
        stem_filters: int = 8,
        down_filters: tuple[int, int] = (16, 32),
        residual_filters: int = 64,
        num_blocks: int = 9,
        aggregation: bool = False,
        norm: str = "instance",
    ) -> None:
        """Create the generator.

        Args:
            channels: image channels (input and output).
            stem_filters: filters of the full-resolution stem (and of ``up2``).
            down_filters: filters of the two stride-2 stages (``up1`` mirrors the first).
            residual_filters: filters of the residual blocks at 1/4 scale.
            num_blocks: number of residual blocks (>= 0).
            aggregation: use aggregation blocks (variant ``GEA``) instead of
                additive skips.
            norm: a key of :data:`lenspair.model.networks.layers.NORMS`.

        Raises:
            ModelError: on a non-positive filter or channel count or a negative
                ``num_blocks``.
        """
        super().__init__()
        counts = (channels, stem_filters, *down_filters, residual_filters)
        if min(counts) < 1:
            raise ModelError(f"channel and filter counts must be positive, got {counts}")
        if num_blocks < 0:
            raise ModelError(f"num_blocks must be >= 0, got {num_blocks}")
        first, second = down_filters
        self.aggregation = aggregation
        self.stem = ConvNormReLU(channels, stem_filters, kernel_size=7, norm=norm)
        self.down1 = ConvNormReLU(
            stem_filters, first, kernel_size=3, stride=2, padding_mode="zeros", norm=norm
        )
        self.down2 = ConvNormReLU(
            first, second, kernel_size=3, stride=2, padding_mode="zeros", norm=norm
        )
        self.agg1: Aggregation | None = None
        self.agg2: Aggregation | None = None
        self.skip1: Aggregation | None = None
        self.skip0: Aggregation | None = None
        if aggregation:
            self.agg1 = Aggregation(stem_filters, first, first, downsample_first=True, norm=norm)
            self.agg2 = Aggregation(first, second, second, downsample_first=True, norm=norm)
            self.skip1 = Aggregation(first, first, first, downsample_first=False, norm=norm)
            self.skip0 = Aggregation(
                stem_filters, stem_filters, stem_filters, downsample_first=False, norm=norm
            )
        self.expand = ConvNormReLU(second, residual_filters, kernel_size=1, norm=norm)
        self.blocks = nn.Sequential(
            *(ResidualBlock(residual_filters, norm=norm) for _ in range(num_blocks))
        )
        self.up1 = _upsample(residual_filters, first, norm)
        self.up2 = _upsample(first, stem_filters, norm)
        self.head = NarrowConv2d(stem_filters, channels, 7, padding=3, padding_mode="reflect")
        zero_init(self.head)

    def forward(self, x: Tensor) -> Tensor:
        """Restore a batch whose sides are multiples of :data:`DOWNSAMPLING_FACTOR`.

        Args:
            x: ``(N, C, H, W)`` float in [0, 1].

        Returns:
            ``(N, C, H, W)`` in [0, 1], same dtype as the residual sum.
        """
        with flat_samples(x):  # a flat frame: every norm gives 0 (layers module docstring)
            stem = self.stem(x)
            half = self.down1(stem)
            if self.agg1 is not None:
                half = self.agg1(stem, half)
            quarter = self.down2(half)
            if self.agg2 is not None:
                quarter = self.agg2(half, quarter)
            features = self.blocks(self.expand(quarter))
            up = self.up1(features)
            up = self.skip1(half, up) if self.skip1 is not None else up + half
            up = self.up2(up)
            up = self.skip0(stem, up) if self.skip0 is not None else up + stem
        return clamp_unit_straight_through(x + self.head(up))


def _upsample(in_channels: int, out_channels: int, norm: str) -> nn.Sequential:
    """pix2pixHD upsampling unit: conv-transpose 3x3 stride 2, norm, ReLU (doubles H, W)."""
    norm_layer = make_norm(norm, out_channels)
    return nn.Sequential(
        nn.ConvTranspose2d(
            in_channels,
            out_channels,
            3,
            stride=2,
            padding=1,
            output_padding=1,
            bias=isinstance(norm_layer, nn.Identity),
        ),
        norm_layer,
        nn.ReLU(inplace=True),
    )
