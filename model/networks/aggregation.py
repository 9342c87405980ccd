"""Aggregation blocks (the "A" of the paper's G/GE/GEA ablation).

An aggregation block merges two feature maps of the same resolution by
concatenation followed by a 3x3 convolution (zero padding), instance norm
and ReLU:

* in the encoder, after each stride-2 downsampling stage, it merges the
  stage's *input* (average-pooled by 2 to the stage's output resolution) with
  the stage's *output*, so the stage keeps a cheap, aliasing-free view of
  what it was given;
* in the decoder, it merges the skip connection from the encoder with the
  upsampled decoder features (no resampling: both are at the same scale).

Without aggregation (variants ``G`` and ``GE``) the generator uses plain
additive skips instead (see :mod:`lenspair.model.networks.generator`).
"""

import torch.nn.functional as F
from torch import Tensor, nn

from lenspair.model.networks.layers import ConvNormReLU, cat_channels


class Aggregation(nn.Module):
    """``ReLU(IN(conv3x3(cat(resample(first), second))))``.

    Shapes: ``first`` is ``(N, first_channels, H, W)`` (or ``(N, first_channels,
    2H, 2W)`` when ``downsample_first``), ``second`` is ``(N, second_channels,
    H, W)``; the output is ``(N, out_channels, H, W)``.
    """

    def __init__(
        self,
        first_channels: int,
        second_channels: int,
        out_channels: int,
        downsample_first: bool,
        norm: str = "instance",
    ) -> None:
        """Create the block.

        Args:
            first_channels: channels of the first input (stage input or skip).
            second_channels: channels of the second input (stage output or
                upsampled decoder features).
            out_channels: channels of the merged output.
            downsample_first: average-pool ``first`` by 2 before merging
                (encoder side); its height and width must then be even.
            norm: a key of :data:`lenspair.model.networks.layers.NORMS`.
        """
        super().__init__()
        self.downsample_first = downsample_first
        # Zero padding: the block is not part of pix2pixHD, and a reflection
        # pad would cost an extra copy of the concatenated full-size tensor.
        self.merge = ConvNormReLU(
            first_channels + second_channels,
            out_channels,
            kernel_size=3,
            padding_mode="zeros",
            norm=norm,
        )

    def forward(self, first: Tensor, second: Tensor) -> Tensor:
        """Merge ``first`` into ``second``.

        Args:
            first: stage input (encoder) or skip features (decoder).
            second: stage output (encoder) or upsampled features (decoder).

        Returns:
            The merged features, at the resolution of ``second``.
        """
        if self.downsample_first:
            first = F.avg_pool2d(first, kernel_size=2)
        merged: Tensor = self.merge(cat_channels([first, second]))
        return merged
