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
Outside exports, the pyramid and the fuse convolution run as matrix products and
shifted sums of single-channel planes, the same function without
concatenating the full-resolution features (``Enhancer._head_by_taps``); exports
(ONNX, ``torch.export``, TorchScript traces) get the layers as this table
reads them, which is what exporters and quantisers know.

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

from collections.abc import Iterator
from typing import Any, cast

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
from lenspair.model.networks.tracing import exporting

Window = tuple[slice, slice]

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
        features = self.activation(self.refine1(cat_channels([generated, image])))
        features = self.activation(self.refine2(features))
        head = self._head_by_layers if exporting() else self._head_by_taps
        residual = head(features)
        return clamp_unit_straight_through(generated + residual)

    def _levels(self, projected: Tensor) -> list[Tensor]:
        """The pyramid's maps, ``(N, 1, H, W)`` each, from the 1x1 projections ``(N, S, H, W)``.

        ``projected`` holds one plane per scale (contiguous planes: one channel of
        a channels-last tensor is a strided view, which avg_pool2d walks about 5x
        slower).
        """
        height, width = projected.shape[-2:]
        levels = []
        for index, scale in enumerate(self.scales):
            pooled = F.avg_pool2d(
                projected[:, index : index + 1], kernel_size=scale, stride=scale, ceil_mode=True
            )
            level = F.interpolate(
                self.activation(pooled), scale_factor=float(scale), mode="nearest"
            )
            levels.append(level[..., :height, :width])
        return levels

    def _pyramid_weights(self) -> tuple[Tensor, Tensor]:
        """The scales' 1x1 convolutions stacked: weight ``(S, F)`` and bias ``(S,)``."""
        convs = cast(list[nn.Conv2d], list(self.pyramid))
        weight = torch.cat([conv.weight.flatten(1) for conv in convs], dim=0)
        bias = torch.cat([conv.bias for conv in convs if conv.bias is not None], dim=0)
        return weight, bias

    def _head_by_layers(self, features: Tensor) -> Tensor:
        """Pyramid and fuse as the layer table reads: what exports and quantisers see.

        Average pooling and a 1x1 convolution are both linear and commute
        exactly (also for ceil-mode partial windows: the bias is constant), so
        all scales' 1x1 convolutions run once at full resolution, stacked, and
        only single-channel maps are pooled: EPDN's result, a fraction of the
        memory traffic.
        """
        weight, bias = self._pyramid_weights()
        weight = weight[..., None, None]
        if features.is_contiguous(memory_format=torch.channels_last):
            weight = weight.contiguous(memory_format=torch.channels_last)
        projected = F.conv2d(features, weight, bias).contiguous()
        return cast(Tensor, self.fuse(cat_channels([*self._levels(projected), features])))

    def _head_by_taps(self, features: Tensor) -> Tensor:
        """The same pyramid and fuse convolution, computed as matrix products and shifts.

        The fuse convolution (3x3, zero padding, a few output channels) is
        linear, so ``fuse(cat(levels, features))`` is, for each of its nine
        taps ``(dy, dx)``, a per-pixel product ``W_tap @ [levels; features]``
        shifted by ``(dy, dx)``, summed. One matrix product gives, from the
        features, all nine taps of every output channel and the pyramid's four
        1x1 projections; a second, small one adds the levels' taps; eight
        shifted additions of single-channel planes finish the convolution.
        This reads the 16-channel features once and concatenates no features: on
        a 2-core CPU the head took 3.3 ms at 540x360 against 7.0 ms through
        the concatenation and a depthwise convolution, and a training step
        through it (batch 8, crop 256) 66 ms against 109. The result equals
        :meth:`_head_by_layers` up to float rounding (tested).
        """
        batch, filters, height, width = features.shape
        scales = len(self.scales)
        channels = self.fuse.out_channels
        fuse_weight = self.fuse.weight  # (C, S + F, 3, 3): levels first, as concatenated
        # tap-major rows: row t * C + c is output channel c's weights of tap t
        tap_weight = fuse_weight.permute(2, 3, 0, 1).reshape(9 * channels, scales + filters)
        pyramid_weight, pyramid_bias = self._pyramid_weights()
        stacked = torch.cat([tap_weight[:, scales:], pyramid_weight], dim=0)
        # (N, F, H*W) as a view of either memory format; bmm reads it strided
        flat = features.flatten(2)
        # bmm's output is contiguous: planes (matmul may return a transposed view)
        products = torch.bmm(stacked.expand(batch, -1, -1), flat)  # (N, 9C + S, H*W)
        taps = products[:, : 9 * channels]
        projected = products[:, 9 * channels :].view(batch, scales, height, width)
        projected = projected + pyramid_bias.view(1, scales, 1, 1)
        levels = torch.cat(self._levels(projected), dim=1).flatten(2)  # (N, S, H*W)
        # in place: no second 9C-plane tensor (bmm's backward keeps its inputs, not this)
        level_weight = tap_weight[:, :scales].to(taps.dtype).expand(batch, -1, -1)
        taps = taps.baddbmm_(level_weight, levels.to(taps.dtype))
        taps = taps.view(batch, 3, 3, channels, height, width)
        # summed in at least fp32 and rounded once, as a convolution does
        summed = _ShiftedTapSum.apply(taps, torch.promote_types(taps.dtype, torch.float32))
        out = cast(Tensor, summed)
        result_dtype = taps.dtype
        if self.fuse.bias is not None:
            out += self.fuse.bias.view(1, -1, 1, 1)
            # the convolution's output dtype: its bias promotes (fp32 bias under autocast)
            result_dtype = torch.promote_types(result_dtype, self.fuse.bias.dtype)
        return out.to(result_dtype)


def _tap_windows(height: int, width: int) -> Iterator[tuple[int, int, Window, Window]]:
    """``(dy, dx, target, source)`` of the eight off-centre taps of a 3x3 kernel.

    ``out[target] += tap(dy, dx)[source]``: ``out[y, x]`` reads ``tap[y + dy, x + dx]``
    where that pixel exists (zero padding). Windows are ``(rows, columns)`` slices.
    """
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == dx == 0:
                continue
            target = (
                slice(max(0, -dy), height - max(0, dy)),
                slice(max(0, -dx), width - max(0, dx)),
            )
            source = (
                slice(max(0, dy), height - max(0, -dy)),
                slice(max(0, dx), width - max(0, -dx)),
            )
            yield dy, dx, target, source


class _ShiftedTapSum(torch.autograd.Function):
    """``sum over (dy, dx) of taps[:, dy + 1, dx + 1]`` shifted by ``(dy, dx)``, zero-padded.

    ``taps`` is ``(N, 3, 3, C, H, W)``; the result ``(N, C, H, W)`` in ``dtype``. Written
    out as slices, autograd's backward built, for each of the eight shifted taps,
    a zero tensor of all nine taps' size and added the nine up: in a training step
    (batch 8, crop 256, one thread) filling them took 0.57 s, about 5 % of the
    step. This backward writes the one gradient tensor once.
    """

    @staticmethod
    def forward(ctx: Any, taps: Tensor, dtype: torch.dtype) -> Tensor:
        out = taps[:, 1, 1].to(dtype, copy=True)
        height, width = taps.shape[-2:]
        for dy, dx, (rows, cols), (src_rows, src_cols) in _tap_windows(height, width):
            out[..., rows, cols] += taps[:, dy + 1, dx + 1, :, src_rows, src_cols]
        ctx.taps_dtype = taps.dtype
        return out

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None]:
        batch, channels, height, width = grad.shape
        grad_taps = grad.new_zeros((batch, 3, 3, channels, height, width), dtype=ctx.taps_dtype)
        grad_taps[:, 1, 1] = grad
        for dy, dx, (rows, cols), (src_rows, src_cols) in _tap_windows(height, width):
            grad_taps[:, dy + 1, dx + 1, :, src_rows, src_cols] = grad[..., rows, cols]
        return grad_taps, None
