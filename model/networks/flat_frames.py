"""Flat frames: every instance norm gives exactly 0 for them, as exact arithmetic does.

A *flat* input (every channel constant: a saturated or black frame, a tile
of clear sky) makes every feature map constant, and each norm should give
exactly 0. Kernels that round differently from pixel to pixel
(channels-last, oneDNN, ONNX Runtime) leave noise of about 1e-7 instead,
which each norm multiplies by up to ``1/sqrt(eps)`` = 316: after a few
layers a grey frame came out as blotches from 10 to 158. So the generator
marks flat samples (:func:`flat_samples`: every pixel within
:data:`FLAT_TOLERANCE` of its channel's corner pixel, or an RMS deviation
within :data:`FLAT_RMS_TOLERANCE`: a noiseless flat frame with a speck) and
every :class:`~lenspair.model.networks.layers.InstanceNorm` inside it gives
them exactly 0 (:func:`current_keep`); other samples are untouched, and a
batch without a flat sample costs one small reduction.
"""

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import torch
from torch import Tensor

from lenspair.model.networks.tracing import traced

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

_MEAN_SQUARE_FLOOR = 1e-20
"""Least mean square :func:`_rms_about_channel_means` takes (an RMS of 1e-10, far below any
tolerance): the square root's gradient at 0 is infinite, and a flat frame's input gradient NaN."""


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
    # about each channel's mean (a speck in the corner pixel must not offset the rest),
    # in fp32: a bf16 sum of a frame's squares loses what it measures
    exact = difference if difference.dtype == torch.float32 else x.float() - x[:, :, :1, :1].float()
    rms = _rms_about_channel_means(exact)
    if difference.is_contiguous(memory_format=torch.channels_last):
        difference = difference.permute(0, 2, 3, 1)
    rows = difference.reshape(x.shape[0], -1)
    spread = torch.maximum(rows.amax(dim=1), -rows.amin(dim=1))
    # on the CPU a batch without a (nearly) flat sample skips the masks; on a GPU the
    # test would wait for the device (a training step's overlap lost): it is applied
    nearly_flat = (spread < FLAT_RAMP) | (rms < FLAT_RMS_RAMP)
    if x.device.type == "cpu" and not traced() and not bool(nearly_flat.any()):
        return None
    keep = torch.minimum(
        ((spread - FLAT_TOLERANCE) / (FLAT_RAMP - FLAT_TOLERANCE)).clamp(0.0, 1.0),
        ((rms - FLAT_RMS_TOLERANCE) / (FLAT_RMS_RAMP - FLAT_RMS_TOLERANCE)).clamp(0.0, 1.0),
    )
    return keep.to(x.dtype).view(-1, 1, 1, 1)


def _rms_about_channel_means(difference: Tensor) -> Tensor:
    """``(N,)`` root-mean-square deviation of each sample's pixels from their channel's mean.

    ``difference`` is the images less each channel's corner pixel, ``float32``:
    the deviations are the same, and values near 0 keep a frame's fp32 sums
    exact (ONNX Runtime's mean of 2 M pixels near 0.5 was off by 0.4 codes, a
    residual above the flat tolerance). Means over the pixels, not a norm
    divided by a pixel count: a count taken from the shape is a constant in
    an export, which then judged every other size by the traced one (a 1080p
    frame with a speck read 3.3x its RMS: no longer flat, and blotched).
    Reduced over ``(N, H*W, C)`` rows when channels-last (its memory order),
    over ``(N, C, H*W)`` otherwise.
    """
    n, c = difference.shape[0], difference.shape[1]
    if c > 1 and difference.is_contiguous(memory_format=torch.channels_last):
        pixels = difference.permute(0, 2, 3, 1).reshape(n, -1, c)
        centred = pixels - pixels.mean(dim=1, keepdim=True)
    else:
        pixels = difference.reshape(n, c, -1)
        centred = pixels - pixels.mean(dim=2, keepdim=True)
    # floored below anything measured: sqrt's gradient at an exactly flat frame is infinite
    rms: Tensor = centred.square().mean(dim=(1, 2)).clamp_min(_MEAN_SQUARE_FLOOR).sqrt()
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


def current_keep() -> Tensor | None:
    """The mask of the generator forward running in this thread (:func:`flat_samples`), or None."""
    keep: Tensor | None = getattr(_FLAT, "keep", None)
    return keep
