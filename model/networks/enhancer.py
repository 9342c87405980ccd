"""The enhancer E, after the enhancing block of EPDN (Qu et al., CVPR 2019).

E refines the generator's output with multi-scale context:

=======  ===============================================================  ==========
name     layers                                                           out
=======  ===============================================================  ==========
input    cat(generator output, input image)                               2C
refine1  conv 3x3, LeakyReLU(0.2)                                         16
refine2  conv 3x3, LeakyReLU(0.2)                                         16
pyramid  per scale s in (4, 8, 16, 32): avg-pool s x s (stride s,         4 x 1
         ceil mode), conv 1x1 -> 1 channel, LeakyReLU(0.2), nearest
         upsampling by s, crop to H x W (computed as 1x1 conv, then
         pool: the two commute, see ``forward``)
fuse     cat(pyramid, refine2), conv 3x3 (bias, zero-initialised)         C
output   clamp01(generator output + fuse)  (straight-through clamp)       C
=======  ===============================================================  ==========

As in EPDN there is no normalisation and the 3x3 convolutions zero-pad.
EPDN uses 20 refinement filters; we use 16, a multiple of the 16 fp32 lanes
of an AVX-512 register (oneDNN blocks channels by 8/16): on the benchmark
CPU a full-resolution 20->20 convolution measured about twice as slow as a
16->16 one, for only 1.6x the FLOPs. Filter counts scale with the width multiplier. The
fuse convolution, with one output channel for mono, is a
:class:`~lenspair.model.networks.layers.NarrowConv2d` (same parameters, faster on CPU).

Any size works, not only multiples of 32: pooling uses ``ceil_mode=True``,
so a partial window at the bottom/right border averages only the pixels it
covers (PyTorch divides by the clipped window area when ``padding=0``), and
the pooled map is upsampled by exactly ``s`` (nearest) and cropped back, so
every output pixel reads the cell that contains it. A constant or saturated
image gives constant pyramid maps and finite outputs and gradients (no
division by a variance anywhere).

Output range: like the generator, E predicts a residual (here on top of the
generator's output) clamped to [0, 1] with a straight-through gradient; its
zero-initialised head makes it start as the identity on G's output.
"""

from typing import cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lenspair.model.errors import ModelError
from lenspair.model.networks.layers import (
    NarrowConv2d,
    cat_channels,
    clamp_unit_straight_through,
    zero_init,
)

PYRAMID_SCALES: tuple[int, ...] = (4, 8, 16, 32)
"""Pooling factors of the pyramid (1/4, 1/8, 1/16 and 1/32 of the resolution)."""


class Enhancer(nn.Module):
    """EPDN-style enhancing block (see the module docstring for the layer table).

    Forward contract: ``generated`` and ``image`` are ``(N, C, H, W)`` float in
    [0, 1], any ``H, W >= 1``; the output is ``(N, C, H, W)`` in [0, 1].
    """

    def __init__(
        self,
        channels: int,
        num_filters: int = 16,
        scales: tuple[int, ...] = PYRAMID_SCALES,
    ) -> None:
        """Create the enhancer.

        Args:
            channels: image channels ``C`` (E reads ``2C``: output and input).
            num_filters: filters of the two 3x3 refinement convolutions.
            scales: pooling factors of the pyramid, each >= 1.

        Raises:
            ModelError: on a non-positive channel/filter count or scale.
        """
        super().__init__()
        if channels < 1 or num_filters < 1:
            raise ModelError(
                f"channels and num_filters must be positive, got {channels}, {num_filters}"
            )
        if not scales or min(scales) < 1:
            raise ModelError(f"pyramid scales must be positive integers, got {scales}")
        self.scales = tuple(scales)
        self.activation = nn.LeakyReLU(0.2, inplace=True)
        self.refine1 = nn.Conv2d(2 * channels, num_filters, 3, padding=1)
        self.refine2 = nn.Conv2d(num_filters, num_filters, 3, padding=1)
        self.pyramid = nn.ModuleList(nn.Conv2d(num_filters, 1, 1) for _ in self.scales)
        self.fuse = NarrowConv2d(num_filters + len(self.scales), channels, 3, padding=1)
        zero_init(self.fuse)

    def forward(self, generated: Tensor, image: Tensor) -> Tensor:
        """Refine ``generated`` using the original ``image`` as extra input.

        Args:
            generated: ``(N, C, H, W)`` generator output in [0, 1].
            image: ``(N, C, H, W)`` obstructed input image in [0, 1].

        Returns:
            ``(N, C, H, W)`` refined image in [0, 1].
        """
        height, width = generated.shape[-2:]
        features = self.activation(self.refine1(cat_channels([generated, image])))
        features = self.activation(self.refine2(features))
        # Average pooling and a 1x1 convolution are both linear and commute
        # exactly (also for ceil-mode partial windows: the bias is constant),
        # so all scales' 1x1 convolutions run once at full resolution, stacked,
        # and only single-channel maps are pooled: EPDN's result, a fraction
        # of the memory traffic.
        convs = cast(list[nn.Conv2d], list(self.pyramid))
        weight = torch.cat([conv.weight for conv in convs], dim=0)
        if features.is_contiguous(memory_format=torch.channels_last):
            weight = weight.contiguous(memory_format=torch.channels_last)
        bias = torch.cat([conv.bias for conv in convs if conv.bias is not None], dim=0)
        # One channel of a channels-last tensor is a strided view, which
        # avg_pool2d walks about 5x slower than a contiguous plane: the four
        # single-channel maps are laid out as planes first (exact, a copy of
        # four maps, not of the features).
        projected = F.conv2d(features, weight, bias).contiguous()
        levels = []
        for index, scale in enumerate(self.scales):
            pooled = F.avg_pool2d(
                projected[:, index : index + 1], kernel_size=scale, stride=scale, ceil_mode=True
            )
            level = F.interpolate(
                self.activation(pooled), scale_factor=float(scale), mode="nearest"
            )
            levels.append(level[..., :height, :width])
        residual = self.fuse(cat_channels([*levels, features]))
        return clamp_unit_straight_through(generated + residual)
