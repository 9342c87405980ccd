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

A *flat* input makes every feature map constant, and each norm should give
exactly 0; the generator marks such samples and every :class:`InstanceNorm`
inside it gives them 0 (:mod:`lenspair.model.networks.flat_frames`).
"""

from collections.abc import Callable, Sequence
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lenspair.model.errors import ModelError
from lenspair.model.networks.flat_frames import current_keep

PaddingMode = Literal["zeros", "reflect", "replicate", "circular"]
"""Padding modes of ``nn.Conv2d``."""

INSTANCE_NORM_EPS = 1e-5
"""``eps`` of every instance norm: keeps constant feature maps finite (0, not 0/0)."""


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
        keep = current_keep()
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
    # x - x.detach() is exactly 0 with the identity's gradient; the textbook
    # x + (clamped - x).detach() rounded 1 - x away from about 2**24 on (1.7e7 gave 0)
    return clamped.detach() + (x - x.detach())


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
