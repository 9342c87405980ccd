"""A small camera-anomaly detector: is the glass obstructed, by what, and where.

One grey image in, three answers out (:class:`DetectorOutput`): the logits of
the anomaly kind (:data:`KINDS`: ``clean``, ``rain``, ``dust``, ``dirt``), the
probability that the glass is obstructed (``1 - p(clean)``, so the two heads
never disagree), and a coarse map of tile logits at 1/8 of the input
resolution.

Frames are judged at half the dataset resolution (``input_size`` 270 x 180
for 540 x 360 frames; :func:`lenspair.model.detection.judge.judge` resizes),
which keeps drops of 4 px radius visible and costs a quarter of the work; the
map then has 23 x 34 tiles, 1/16 of a 540 x 360 frame. The trunk is three
stride-2 3x3 convolutions (1/8 resolution) and three dilated 3x3
convolutions that widen the receptive field of each tile to about 130 input
pixels, so that a tile sees the smooth edge of a dust blob or a drop's rim.
The map head is a 1x1 convolution; the kind head pools the trunk (mean and
max, so both a frame-wide veil and a single drop count) and a linear layer.
With the default widths the network has about 84 thousand parameters.

The input is ``(N, 1, H, W)`` float32 luma in ``[0, 1]``. Each image is
normalised by its own mean and standard deviation first, so a darker or
brighter exposure of a clean scene is not evidence of an obstruction: the
network must look at structure (blur, lens-like drops, low-frequency
attenuation patterns), not brightness. No device is chosen here.
"""

from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import nn

KINDS: tuple[str, ...] = ("clean", "rain", "dust", "dirt")
"""Anomaly kinds, in the order of the kind logits; index 0 is ``clean``."""

TILE_STRIDE = 8
"""Input pixels per map tile along each axis (16 pixels of the full-size frame)."""


MAX_INPUT_SIDE = 1920
"""The largest input side (``train-detector --input-size`` allows no more): a full-HD
frame's width; the detector scales every frame down to its input size."""


@dataclass(frozen=True)
class DetectorSpec:
    """Architecture of :class:`AnomalyDetector` (saved in its checkpoint).

    Attributes:
        widths: channels of the three stride-2 stages.
        context_dilations: dilations of the 3x3 convolutions at 1/8 resolution.
        input_size: ``(height, width)`` images are resized to before judging,
            pixels; the map has ``ceil(size / 8)`` tiles per axis.
    """

    widths: tuple[int, int, int] = (16, 32, 48)
    context_dilations: tuple[int, ...] = (2, 4, 8)
    input_size: tuple[int, int] = (180, 270)

    def __post_init__(self) -> None:
        # a checkpoint's spec comes from a file: a hand-edited or other version's value
        # failed deep in torch (non-positive dilation) or in OpenCV (out of memory)
        numbers = (*self.widths, *self.context_dilations, *self.input_size)
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in numbers):
            raise ValueError(f"expected whole numbers, got {self}")
        if len(self.widths) != 3 or min(self.widths) < 1:
            raise ValueError(f"widths: expected 3 positive channel counts, got {self.widths}")
        if not self.context_dilations or min(self.context_dilations) < 1:
            raise ValueError(
                f"context_dilations: expected positive dilations, got {self.context_dilations}"
            )
        if len(self.input_size) != 2 or min(self.input_size) < TILE_STRIDE:
            raise ValueError(f"input_size: expected at least 8x8, got {self.input_size}")
        if max(self.input_size) > MAX_INPUT_SIDE:
            raise ValueError(
                f"input_size: expected sides up to {MAX_INPUT_SIDE}, got {self.input_size}"
            )

    @property
    def grid(self) -> tuple[int, int]:
        """``(rows, cols)`` of the tile map for ``input_size``."""
        height, width = self.input_size
        return -(-height // TILE_STRIDE), -(-width // TILE_STRIDE)


class DetectorOutput(NamedTuple):
    """What :class:`AnomalyDetector` returns for a batch of ``N`` images.

    Attributes:
        kind_logits: ``(N, len(KINDS))`` float32.
        obstructed: ``(N,)`` probability in ``[0, 1]`` that the glass is obstructed.
        tile_logits: ``(N, rows, cols)`` float32; ``sigmoid`` gives the
            probability that a tile is covered.
    """

    kind_logits: torch.Tensor
    obstructed: torch.Tensor
    tile_logits: torch.Tensor


def _stage(in_channels: int, out_channels: int, stride: int, dilation: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(
            in_channels,
            out_channels,
            3,
            stride=stride,
            padding=dilation,
            dilation=dilation,
            bias=False,
        ),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


def normalise(images: torch.Tensor) -> torch.Tensor:
    """Per-image standardisation: ``(x - mean) / (std + 0.02)``, shapes kept."""
    mean = images.mean(dim=(1, 2, 3), keepdim=True)
    std = images.std(dim=(1, 2, 3), keepdim=True)
    return (images - mean) / (std + 0.02)


class AnomalyDetector(nn.Module):
    """The detector network; see the module docstring.

    Args:
        spec: the architecture.
    """

    def __init__(self, spec: DetectorSpec | None = None) -> None:
        super().__init__()
        self.spec = spec or DetectorSpec()
        widths = self.spec.widths
        layers = [_stage(2, widths[0], 2)]
        layers += [_stage(widths[i], widths[i + 1], 2) for i in range(2)]
        layers += [_stage(widths[2], widths[2], 1, d) for d in self.spec.context_dilations]
        self.trunk = nn.Sequential(*layers)
        self.map_head = nn.Conv2d(widths[2], 1, 1)
        self.kind_head = nn.Linear(2 * widths[2], len(KINDS))

    def forward(self, images: torch.Tensor) -> DetectorOutput:
        """Judge a batch.

        Args:
            images: ``(N, 1, H, W)`` float32 luma in ``[0, 1]``.

        Returns:
            The :class:`DetectorOutput`; the map has ``ceil(H/8) x ceil(W/8)`` tiles.
        """
        if images.ndim != 4 or images.shape[1] != 1:
            raise ValueError(f"images: expected (N, 1, H, W), got {tuple(images.shape)}")
        # The raw level rides along as a second channel so that a black or
        # saturated frame (whose standardised version is all zeros) is still seen.
        features = self.trunk(torch.cat([normalise(images), images], dim=1))
        pooled = torch.cat([features.mean(dim=(2, 3)), features.amax(dim=(2, 3))], dim=1)
        kind_logits = self.kind_head(pooled)
        obstructed = 1.0 - torch.softmax(kind_logits, dim=1)[:, 0]
        return DetectorOutput(kind_logits, obstructed, self.map_head(features)[:, 0])


def count_parameters(network: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in network.parameters() if p.requires_grad)
