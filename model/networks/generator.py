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

from collections.abc import Iterable
from typing import cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lenspair.model.errors import ModelError
from lenspair.model.networks.aggregation import Aggregation
from lenspair.model.networks.flat_frames import flat_samples
from lenspair.model.networks.layers import (
    ConvNormReLU,
    NarrowConv2d,
    clamp_unit_straight_through,
    is_channels_last,
    make_norm,
    zero_init,
)
from lenspair.model.networks.tracing import exporting

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

    def add_to_padded(self, stream: Tensor, inner: Tensor) -> None:
        """Apply the block in place to the interior of ``stream`` (no autograd).

        ``stream`` holds the block's input ``x`` inside a one-pixel border,
        ``inner`` (same shape) is scratch for the inner activation; the
        interior of ``stream`` becomes the block's output. The borders are
        filled here by reflection, so the convolutions pad nothing
        (:meth:`Generator._residual_features`).
        """
        first_unit = cast(ConvNormReLU, self.body[0])
        first_conv, first_norm = cast(nn.Conv2d, first_unit[0]), first_unit[1]
        second_conv, second_norm = cast(nn.Conv2d, self.body[1]), self.body[2]
        _reflect_border(stream)
        first = first_norm(F.conv2d(stream, first_conv.weight, first_conv.bias))
        torch.clamp_min(first, 0.0, out=inner[..., 1:-1, 1:-1])
        _reflect_border(inner)
        second = second_norm(F.conv2d(inner, second_conv.weight, second_conv.bias))
        stream[..., 1:-1, 1:-1] += second


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
        with flat_samples(x):  # a flat frame: every norm gives 0 (flat_frames module docstring)
            stem = self.stem(x)
            half = self.down1(stem)
            if self.agg1 is not None:
                half = self.agg1(stem, half)
            quarter = self.down2(half)
            if self.agg2 is not None:
                quarter = self.agg2(half, quarter)
            features = self._residual_features(quarter)
            up = self.up1(features)
            up = self.skip1(half, up) if self.skip1 is not None else up + half
            up = self.up2(up)
            up = self.skip0(stem, up) if self.skip0 is not None else up + stem
        return clamp_unit_straight_through(x + self.head(up))

    def _residual_features(self, quarter: Tensor) -> Tensor:
        """``blocks(expand(quarter))``; without autograd, with the reflection pads in place.

        Each residual block reflect-pads its input and its inner activation:
        two copies of a 64-channel map per block. Without autograd (inference)
        the residual stream and the inner activation instead live inside two
        buffers one pixel larger on every side: the ReLU and the residual sum
        write into their interiors and only the one-pixel border is filled,
        by reflection. The same values, bit for bit, about 2 ms less of a
        100 ms forward at 540x360 on a 2-core CPU. Training, exports, autocast
        (whose sums may change dtype from block to block) and ``torch.compile``
        run the layers as written: inductor fuses the pads itself, and with
        freezing it turned the in-place form of a channels-last model into NaN
        (torch 2.13).
        """
        if (
            torch.is_grad_enabled()
            or exporting()
            or torch.compiler.is_compiling()
            or torch.is_autocast_enabled(quarter.device.type)
            or len(self.blocks) == 0
            or min(quarter.shape[-2:]) < 2  # reflection needs two pixels: the layers refuse
        ):
            return cast(Tensor, self.blocks(self.expand(quarter)))
        expand_conv, expand_norm, _ = self.expand
        expanded = expand_norm(expand_conv(quarter))
        batch, channels, height, width = expanded.shape
        memory_format = (
            torch.channels_last if is_channels_last(expanded) else torch.contiguous_format
        )
        stream = torch.empty(
            (batch, channels, height + 2, width + 2),
            dtype=expanded.dtype,
            device=expanded.device,
            memory_format=memory_format,
        )
        inner = torch.empty_like(stream)
        torch.clamp_min(expanded, 0.0, out=stream[..., 1:-1, 1:-1])  # expand's ReLU
        for block in cast(Iterable[ResidualBlock], self.blocks):
            block.add_to_padded(stream, inner)
        return stream[..., 1:-1, 1:-1]


def _reflect_border(padded: Tensor) -> None:
    """Fill the one-pixel border of ``padded`` as ``F.pad(interior, 1, mode="reflect")`` would."""
    padded[..., 0, 1:-1] = padded[..., 2, 1:-1]
    padded[..., -1, 1:-1] = padded[..., -3, 1:-1]
    padded[..., :, 0] = padded[..., :, 2]  # columns last: the corners reflect both ways
    padded[..., :, -1] = padded[..., :, -3]


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
