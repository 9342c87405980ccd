"""Image batches in and out of the networks: validation, padding to a multiple, cropping.

Image convention of the ``model`` package: ``NCHW``, ``float32`` (or
``bfloat16``/``float16`` under autocast), range [0, 1], 1 (mono) or 3 (RGB)
channels. The generator downsamples twice by 2, so it works on sizes that are
a multiple of 4; any other size is reflection-padded up to the next multiple
and the output is cropped back, so outputs always have the input's size.
"""

import torch.nn.functional as F
from torch import Tensor

from lenspair.model.errors import ModelError

MIN_SIDE = 8
"""Smallest accepted height/width: the residual blocks at 1/4 scale need 2 pixels."""


def check_image_batch(x: Tensor, channels: int | None = None, name: str = "images") -> None:
    """Check that ``x`` is a floating-point ``NCHW`` batch the networks accept.

    The range [0, 1] is the convention but is not checked (it would cost a
    pass over the data on every call).

    Args:
        x: tensor to check.
        channels: expected channel count, or ``None`` for any.
        name: what to call ``x`` in error messages.

    Raises:
        ModelError: on a wrong rank, dtype, channel count or a side below
            :data:`MIN_SIDE` (the message shows the expected and actual shape).
    """
    if x.ndim != 4:
        raise ModelError(f"{name}: expected shape (N, C, H, W), got {tuple(x.shape)}")
    if not x.is_floating_point():
        raise ModelError(f"{name}: expected a floating-point tensor in [0, 1], got {x.dtype}")
    if channels is not None and x.shape[1] != channels:
        raise ModelError(
            f"{name}: expected {channels} channel(s), shape (N, {channels}, H, W), "
            f"got {tuple(x.shape)}"
        )
    if x.shape[2] < MIN_SIDE or x.shape[3] < MIN_SIDE:
        raise ModelError(
            f"{name}: height and width must be at least {MIN_SIDE}, got {tuple(x.shape)}"
        )


def pad_to_multiple(x: Tensor, multiple: int) -> Tensor:
    """Reflection-pad the bottom and right of ``x`` up to a multiple of ``multiple``.

    Padding only at the bottom/right keeps pixel (0, 0) in place, so cropping
    back is a plain slice. There is no branch on the size (a zero pad is a
    cheap copy of the image), so ``torch.export`` keeps H and W dynamic: the
    ONNX file of ``lenspair export`` takes any size
    (:mod:`lenspair.model.evaluation.export`).

    Args:
        x: ``(N, C, H, W)`` batch with ``H, W >= multiple`` (reflection needs
            the pad to be smaller than the side).
        multiple: positive integer.

    Returns:
        ``(N, C, H', W')`` with ``H' = ceil(H / multiple) * multiple`` (same for W).
    """
    height, width = x.shape[-2:]
    return F.pad(x, (0, -width % multiple, 0, -height % multiple), mode="reflect")


def crop_to(x: Tensor, height: int, width: int) -> Tensor:
    """Crop the top-left ``height x width`` region (undoes :func:`pad_to_multiple`).

    Args:
        x: ``(N, C, H', W')`` batch with ``H' >= height`` and ``W' >= width``.
        height: output height.
        width: output width.

    Returns:
        ``(N, C, height, width)`` view of ``x``.
    """
    return x[..., :height, :width]
