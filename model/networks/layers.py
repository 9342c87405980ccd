"""Building blocks shared by the generator, aggregation, enhancer and discriminator.

Normalisation is chosen by name from :data:`NORMS`; an unknown name raises
:class:`~lenspair.model.errors.ModelError` listing the valid ones.

Instance normalisation follows pix2pixHD: no affine parameters and no
running statistics (``InstanceNorm2d(affine=False)``), so training and
inference normalise alike and a batch of one behaves like any other batch.
Its ``eps`` (1e-5) sits inside the square root, so a constant (or
saturated) feature map normalises to exactly 0 instead of 0/0, and its
gradient stays finite. A convolution feeding an instance norm has no bias:
the norm subtracts the per-channel mean, which would cancel it.

A *flat* input (every channel constant: a saturated or black frame, a tile
of clear sky) makes every feature map constant, and each norm should give
exactly 0. Kernels that round differently from pixel to pixel
(channels-last, oneDNN, ONNX Runtime) leave noise of about 1e-7 instead,
which each norm multiplies by up to ``1/sqrt(eps)`` = 316: after a few
layers a grey frame came out as blotches from 10 to 158. So the generator
marks flat samples (:func:`flat_samples`: every pixel within
:data:`FLAT_TOLERANCE` of its channel's corner pixel, or an RMS deviation
within :data:`FLAT_RMS_TOLERANCE`: a noiseless flat frame with a speck) and every instance
norm inside it gives them exactly 0, what exact arithmetic gives; other
samples are untouched, and a batch without a flat sample costs one small
reduction.
"""

import math
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lenspair.model.errors import ModelError

PaddingMode = Literal["zeros", "reflect", "replicate", "circular"]
"""Padding modes of ``nn.Conv2d``."""

INSTANCE_NORM_EPS = 1e-5
"""``eps`` of every instance norm: keeps constant feature maps finite (0, not 0/0)."""


FLAT_TOLERANCE = 0.5 / 255.0
"""How far ([0, 1] scale) every pixel of a flat input may be from its channel's corner pixel.

Half an 8-bit code: an 8-bit frame is flat when each channel is constant.
"""

FLAT_RAMP = 4.0 / 255.0
"""Spread ([0, 1] scale) from which a sample is not flat at all (:func:`flat_keep`).

Between :data:`FLAT_TOLERANCE` and this, the norms' outputs are scaled from 0
to 1: a norm makes a 1-code variation as large as any other (up to 316x), so a
hard switch made a white frame with one pixel a 16-bit code darker than the
tolerance come out with a dark blotch, where one a code less dark stayed white.
A camera's noise spreads a real frame far beyond 4 codes.
"""

FLAT_RMS_TOLERANCE = 0.25 / 255.0
"""Root-mean-square deviation ([0, 1] scale, about each channel's mean) at or below which a
sample counts as flat whatever its largest deviation (:func:`flat_keep`).

A noiseless flat frame with one speck (a hot pixel on a black night frame,
a dust speck on a saturated sky, a synthetic render) spreads far past
:data:`FLAT_RAMP` at that pixel, but every feature map's variance stays
below the norms' ``eps``: the norms scaled the speck up to 316x, and a
speck 4 codes off mid-grey came out of the shipped GEA as a blotch of 75
codes about 50 pixels wide. What decides the amplification is the energy
of the deviation over the frame, which the RMS measures; a camera's noise
alone keeps a real frame above :data:`FLAT_RMS_RAMP` (with one code of noise
the same speck changes the output by about 4 codes).
"""

FLAT_RMS_RAMP = 0.75 / 255.0
"""RMS deviation from which a sample is not flat at all by that measure (a ramp between)."""


def exporting() -> bool:
    """Whether the forward is being exported (ONNX, ``torch.export``, a TorchScript trace).

    Layers with a faster eager formulation of the same function give exports
    the plain one, made of the operators that exporters and quantisers know.
    """
    tracing = torch._C._get_tracing_state() is not None  # torch.jit.is_tracing, typed
    return tracing or torch.onnx.is_in_onnx_export() or torch.compiler.is_exporting()


def _traced() -> bool:
    """Whether the forward is being exported or compiled: no data-dependent branch then."""
    return exporting() or torch.compiler.is_compiling()


def flat_keep(x: Tensor) -> Tensor | None:
    """``(N, 1, 1, 1)`` 0 for each flat sample of ``x``, 1 for the others, a ramp between.

    A sample's spread (largest distance of a pixel from its channel's corner
    pixel) at most :data:`FLAT_TOLERANCE` gives 0, at least :data:`FLAT_RAMP`
    gives 1, and linearly between, so that the output is continuous in the input.
    Its RMS deviation from each channel's mean ramps the same way between
    :data:`FLAT_RMS_TOLERANCE` and :data:`FLAT_RMS_RAMP`; the smaller of the
    two ramps is taken, so that a noiseless flat frame with a speck counts as
    flat too.

    Args:
        x: ``(N, C, H, W)`` images in [0, 1] (any memory format).

    Returns:
        The mask, or None when no sample is flat (eager on the CPU; a traced
        or compiled forward, and any on a GPU, always gets the mask, so
        exported models carry it).
    """
    # spread from each channel's corner pixel, reduced over one contiguous row
    # per sample: a per-channel reduction of a 3-channel channels-last image
    # is 15x slower
    difference = x - x[:, :, :1, :1]
    if difference.is_contiguous(memory_format=torch.channels_last):
        difference = difference.permute(0, 2, 3, 1)
    rows = difference.reshape(x.shape[0], -1)
    spread = torch.maximum(rows.amax(dim=1), -rows.amin(dim=1))
    # about each channel's mean (a speck in the corner pixel must not offset the rest),
    # in fp32: a bf16 sum of a frame's squares loses what it measures
    rms = _rms_about_channel_means(x)
    # on the CPU a batch without a (nearly) flat sample skips the masks; on a GPU the
    # test would wait for the device (a training step's overlap lost): it is applied
    nearly_flat = (spread < FLAT_RAMP) | (rms < FLAT_RMS_RAMP)
    if x.device.type == "cpu" and not _traced() and not bool(nearly_flat.any()):
        return None
    keep = torch.minimum(
        ((spread - FLAT_TOLERANCE) / (FLAT_RAMP - FLAT_TOLERANCE)).clamp(0.0, 1.0),
        ((rms - FLAT_RMS_TOLERANCE) / (FLAT_RMS_RAMP - FLAT_RMS_TOLERANCE)).clamp(0.0, 1.0),
    )
    return keep.to(x.dtype).view(-1, 1, 1, 1)


def _rms_about_channel_means(x: Tensor) -> Tensor:
    """``(N,)`` root-mean-square deviation of each sample's pixels from their channel's mean.

    Reduced over ``(N, H*W, C)`` rows when ``x`` is channels-last (its memory
    order), over ``(N, C, H*W)`` otherwise, in fp32 whatever ``x`` is.
    """
    n, c = x.shape[0], x.shape[1]
    if c > 1 and x.is_contiguous(memory_format=torch.channels_last):
        pixels = x.permute(0, 2, 3, 1).reshape(n, -1, c).float()
        centred = pixels - pixels.mean(dim=1, keepdim=True)
    else:
        pixels = x.reshape(n, c, -1).float()
        centred = pixels - pixels.mean(dim=2, keepdim=True)
    norm: Tensor = torch.linalg.vector_norm(centred.reshape(n, -1), dim=1)
    rms: Tensor = norm / math.sqrt(centred[0].numel())
    return rms


_FLAT = threading.local()
"""``keep``: the mask of the generator forward running in this thread, or absent.

Per thread, not an attribute of the norms: two threads may run one network
(a robot's callbacks, ``nn.DataParallel``'s replicas, which share their
modules' attributes), and ``torch.compile`` traces it without a graph break
(a ``ContextVar`` broke the graph at every norm).
"""


@contextmanager
def flat_samples(x: Tensor) -> Iterator[None]:
    """Within the block, this thread's :class:`InstanceNorm` give ``x``'s flat samples 0."""
    before = getattr(_FLAT, "keep", None)
    _FLAT.keep = flat_keep(x)
    try:
        yield
    finally:
        _FLAT.keep = before


class InstanceNorm(nn.Module):
    """Instance normalisation without affine parameters or running statistics.

    Normalises each channel of each sample to zero mean and unit (biased)
    variance: ``(x - mean) / sqrt(var + eps)``; shapes ``(N, C, H, W) -> (N, C,
    H, W)``. Numerically identical to ``nn.InstanceNorm2d(channels,
    affine=False)``, but computed as a group norm with one channel per group,
    whose CPU kernel is about five times faster than ``instance_norm`` (which
    goes through a reshaped batch norm) and also supports channels-last.
    """

    def __init__(self, channels: int, eps: float = INSTANCE_NORM_EPS) -> None:
        """Create the layer.

        Args:
            channels: number of channels ``C``.
            eps: added to the variance; keeps constant maps finite.
        """
        super().__init__()
        self.channels = channels
        self.eps = eps

    def forward(self, x: Tensor) -> Tensor:
        """Normalise ``x`` (``(N, C, H, W)``, floating point); flat samples give 0 (module doc)."""
        keep: Tensor | None = getattr(_FLAT, "keep", None)
        normalised = self._normalise(x)
        return normalised if keep is None else normalised * keep.to(normalised.dtype)

    def _normalise(self, x: Tensor) -> Tensor:
        if torch.onnx.is_in_onnx_export():
            # ONNX has InstanceNormalization. A group norm exports as reshapes, a
            # norm, a scale by one and a shift by zero, which int8 quantisation
            # then wraps in Q/DQ pairs (lenspair.model.evaluation.quantize).
            return F.instance_norm(x, eps=self.eps)
        if x.dtype != torch.float32 and self.channels < 16 and is_channels_last(x):
            # PyTorch's channels-last group norm is ~5x slower than
            # instance_norm for a few bf16/fp16 channels (same result).
            return F.instance_norm(x, eps=self.eps)
        return F.group_norm(x, self.channels, eps=self.eps)

    def extra_repr(self) -> str:
        """Channel count and eps, for ``print(model)``."""
        return f"{self.channels}, eps={self.eps}"


def _instance_norm(channels: int) -> nn.Module:
    return InstanceNorm(channels)


def _no_norm(channels: int) -> nn.Module:
    del channels
    return nn.Identity()


NORMS: dict[str, Callable[[int], nn.Module]] = {
    "instance": _instance_norm,
    "none": _no_norm,
}
"""Normalisation layers by name: each maps a channel count to a module."""


def make_norm(name: str, channels: int) -> nn.Module:
    """Build a normalisation layer by name.

    Args:
        name: a key of :data:`NORMS` (``"instance"`` or ``"none"``).
        channels: number of channels normalised.

    Returns:
        The normalisation module.

    Raises:
        ModelError: if ``name`` is unknown (the message lists the valid names).
    """
    try:
        factory = NORMS[name]
    except KeyError:
        raise ModelError(
            f"unknown normalisation {name!r}; valid names: {', '.join(sorted(NORMS))}"
        ) from None
    return factory(channels)


def scaled_channels(base: int, width: float) -> int:
    """Scale a base filter count by a width multiplier (at least one filter).

    Args:
        base: filter count at width 1.0.
        width: multiplier, > 0.

    Returns:
        ``max(1, round(base * width))``.

    Raises:
        ModelError: if ``width`` is not a finite positive number.
    """
    if not (width > 0 and width < float("inf")):
        raise ModelError(f"width must be a finite positive number, got {width!r}")
    return max(1, round(base * width))


class ConvNormReLU(nn.Sequential):
    """``Conv2d -> norm -> ReLU`` (the pix2pixHD encoder/decoder unit).

    Shapes: ``(N, in_channels, H, W) -> (N, out_channels, H', W')`` with
    ``H' = ceil(H / stride)`` for odd kernels.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int,
        stride: int = 1,
        padding_mode: PaddingMode = "reflect",
        norm: str = "instance",
    ) -> None:
        """Create the unit.

        Args:
            in_channels: input channels.
            out_channels: output channels.
            kernel_size: odd square kernel size.
            stride: convolution stride (1 or 2).
            padding_mode: ``"reflect"`` or ``"zeros"`` (``kernel_size // 2`` pixels).
            norm: a key of :data:`NORMS`.
        """
        norm_layer = make_norm(norm, out_channels)
        super().__init__(
            nn.Conv2d(
                in_channels,
                out_channels,
                kernel_size,
                stride=stride,
                padding=kernel_size // 2,
                padding_mode=padding_mode,
                bias=isinstance(norm_layer, nn.Identity),
            ),
            norm_layer,
            nn.ReLU(inplace=True),
        )


def clamp_unit_straight_through(x: Tensor) -> Tensor:
    """Clamp to [0, 1] in the forward pass, pass gradients through unchanged.

    A plain clamp has zero gradient wherever the value is out of range, so a
    residual that overshoots (say 1.2 where the target is 0.9) could never be
    pulled back. The straight-through form keeps the gradient of the identity.
    Without autograd (inference, export) it is a plain clamp.

    Args:
        x: any tensor.

    Returns:
        Tensor of the same shape and dtype, values in [0, 1].
    """
    clamped = x.clamp(0.0, 1.0)
    if not (torch.is_grad_enabled() and x.requires_grad):
        return clamped
    return x + (clamped - x).detach()


class NarrowConv2d(nn.Conv2d):
    """A ``Conv2d`` for very few output channels (an image head), computed depthwise.

    oneDNN runs a convolution with one output channel at the cost of one with
    sixteen. This layer keeps ``nn.Conv2d``'s parameters and state-dict keys
    but evaluates ``sum_c conv(x_c, w_{o,c})`` as one depthwise convolution
    (``groups = in_channels``, ``out_channels`` filters per group) followed by a
    sum over the input channels: the same multiply-accumulates (and FLOP
    count), 2-3x faster on CPU for one output channel.
    Shapes: ``(N, in_channels, H, W) -> (N, out_channels, H', W')``; only
    ``groups=1`` and ``dilation=1`` are supported.
    """

    def forward(self, x: Tensor) -> Tensor:
        """Apply the convolution (see the class docstring)."""
        if self.padding_mode != "zeros":
            x = F.pad(x, self._reversed_padding_repeated_twice, mode=self.padding_mode)
            padding: int | tuple[int, ...] | str = 0
        else:
            padding = self.padding
        in_channels, out_channels = self.in_channels, self.out_channels
        # A standard-layout depthwise weight: a channels-last model would
        # otherwise hand oneDNN a strided weight to reorder on every call.
        if out_channels == 1:
            # A view, no transpose: its gradient then has exactly the
            # parameter's strides. Through the transpose, the size-1 output
            # dimension came back with another (equivalent) stride, which
            # autograd accepts but DDP's bucket check does not ("grad strides
            # do not match bucket view strides"), costing a copy per step.
            weight = self.weight.reshape(in_channels, 1, *self.kernel_size).contiguous()
        else:
            weight = (
                self.weight.transpose(0, 1)
                .reshape(in_channels * out_channels, 1, *self.kernel_size)
                .contiguous()
            )
        per_input = F.conv2d(x, weight, None, self.stride, padding, groups=in_channels)
        batch, _, height, width = per_input.shape
        out = per_input.reshape(batch, in_channels, out_channels, height, width).sum(dim=1)
        if self.bias is not None:
            out = out + self.bias.view(1, -1, 1, 1)
        return out


def is_channels_last(x: Tensor) -> bool:
    """Whether a 4-D tensor is stored channels-last (and not also plain contiguous)."""
    return (
        x.ndim == 4 and x.is_contiguous(memory_format=torch.channels_last) and not x.is_contiguous()
    )


def cat_channels(tensors: Sequence[Tensor]) -> Tensor:
    """``torch.cat(tensors, dim=1)``, fast for channels-last tensors.

    When any input is channels-last, the concatenation runs on the ``NHWC``
    views (innermost dimension) and the result is channels-last: PyTorch's
    own channel concatenation of channels-last tensors is often several times
    slower, and mixing in a strided single-channel map would make it return
    an ``NCHW`` tensor that the next (channels-last) convolution must reorder.
    The values are identical either way.

    Args:
        tensors: ``(N, C_i, H, W)`` tensors, same ``N, H, W`` and dtype.

    Returns:
        ``(N, sum C_i, H, W)``.
    """
    if any(is_channels_last(t) for t in tensors):
        return torch.cat([t.permute(0, 2, 3, 1) for t in tensors], dim=3).permute(0, 3, 1, 2)
    return torch.cat(list(tensors), dim=1)


def init_weights(module: nn.Module, std: float = 0.02) -> None:
    """pix2pix/pix2pixHD initialisation: conv weights ~ N(0, std), biases 0.

    Args:
        module: module whose ``Conv2d``/``ConvTranspose2d`` children are initialised.
        std: standard deviation of the weights.
    """
    for child in module.modules():
        if isinstance(child, nn.Conv2d | nn.ConvTranspose2d):
            nn.init.normal_(child.weight, 0.0, std)
            if child.bias is not None:
                nn.init.zeros_(child.bias)


def zero_init(conv: nn.Conv2d) -> None:
    """Zero a convolution's weights and bias (a residual head then starts as identity).

    Args:
        conv: the convolution to reset.
    """
    nn.init.zeros_(conv.weight)
    if conv.bias is not None:
        nn.init.zeros_(conv.bias)
