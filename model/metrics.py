"""PSNR and SSIM in torch, matching scikit-image, under two named conventions.

Every table that reports these metrics names its :class:`MetricConvention`:

``skimage-gaussian`` (the reference; Wang et al. 2004)
    ``skimage.metrics.peak_signal_noise_ratio(target, output, data_range=1)``
    and ``structural_similarity(..., gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1, channel_axis=-1 for RGB)`` on
    the float images: an 11-tap Gaussian window (truncate 3.5, radius 5),
    population covariances, ``K1=0.01``, ``K2=0.03``, RGB as the mean of the
    per-channel SSIMs, PSNR over all pixels and channels together.

``deraindrop-y`` (DeRaindrop's published evaluation, Qian et al. CVPR 2018)
    Their ``metrics.py`` converts uint8 BGR images with OpenCV's
    ``cvtColor(COLOR_BGR2YCR_CB)`` and scores channel 0 with skimage's
    ``compare_psnr``/``compare_ssim`` defaults. Reproduced here: quantise to
    uint8 (``round(clip(x, 0, 1) * 255)``), take the ITU-R BT.601 *full-range*
    luma with OpenCV's fixed-point arithmetic, ``Y = (4899 R + 9617 G + 1868 B
    + 8192) >> 14`` (``0.299 R + 0.587 G + 0.114 B``, no 16..235 offset; not
    MATLAB's ``rgb2ycbcr``, which DeRaindrop did not use); mono images are
    their own Y. PSNR with ``data_range=255``; SSIM with skimage's defaults
    for uint8: 7x7 uniform window, *sample* covariance (``N/(N-1)``),
    ``data_range=255``. One divergence: DeRaindrop's ``predict.py`` cast the
    float output to uint8 by truncation (``np.array(x, dtype='uint8')``),
    which biases the output by -0.5 grey level; we round, as writing the
    output to a PNG would. Pass uint8-exact tensors to reproduce their numbers
    bit for bit.

Border handling follows skimage: the SSIM map is averaged after cropping
``(win_size - 1) // 2`` pixels on every side. Those are exactly the pixels
whose window leaves the image, so the filters here are *valid* convolutions
and skimage's reflect-mode padding never matters. Both SSIM paths compute in
float64, as skimage does for uint8 input (and within 1e-6 of its float32
path), and agree with skimage to 1e-4 or better (see the tests).

Untrustworthy pixels (a dataset's ``mask/``: misregistration, parallax)
are left out when a ``valid`` map is given, as training leaves them out of
its loss: PSNR is the MSE over the valid pixels (skimage's
``peak_signal_noise_ratio(target[valid], output[valid])``), SSIM the mean of
skimage's SSIM map over the windows that lie wholly on valid pixels (a
window touching an untrustworthy pixel carries its error into the local
statistics). A pair with no valid pixel, or no such window, is an error.

Edge cases, never NaN: identical images give PSNR ``+inf`` (skimage too);
:func:`mean_psnr` caps each value at :data:`PSNR_CAP_DB` before averaging
so one perfect frame cannot turn a mean into ``inf``. Constant images keep
SSIM finite through ``C1``/``C2`` (two equal constant images score 1).
Non-finite inputs are rejected, and so are images on another scale than the
convention's (:func:`image_metrics`: integer codes, 0-255 floats).
"""

import enum
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from lenspair.model.errors import ModelError

PSNR_CAP_DB = 100.0
"""PSNR of a single image is capped at this value (dB) when averaged."""

GAUSSIAN_SIGMA = 1.5
GAUSSIAN_TRUNCATE = 3.5
UNIFORM_WIN_SIZE = 7
K1 = 0.01
K2 = 0.03


class MetricConvention(enum.StrEnum):
    """How PSNR/SSIM are computed; print its value beside every table."""

    SKIMAGE_GAUSSIAN = "skimage-gaussian"
    DERAINDROP_Y = "deraindrop-y"


def parse_metric_convention(name: str) -> MetricConvention:
    """Look up a convention by name.

    Args:
        name: ``"skimage-gaussian"`` or ``"deraindrop-y"``.

    Returns:
        The convention.

    Raises:
        ModelError: for an unknown name (the message lists the valid ones).
    """
    try:
        return MetricConvention(name)
    except ValueError:
        valid = ", ".join(c.value for c in MetricConvention)
        raise ModelError(f"unknown metric convention {name!r}; valid: {valid}") from None


@dataclass(frozen=True)
class ImageMetrics:
    """Per-image metrics of a batch.

    Attributes:
        psnr: ``(N,)`` float64, dB; ``+inf`` for identical images.
        ssim: ``(N,)`` float64, at most 1.
        convention: how they were computed.
    """

    psnr: Tensor
    ssim: Tensor
    convention: MetricConvention


def _check_pair(output: Tensor, target: Tensor) -> None:
    if output.shape != target.shape:
        raise ModelError(
            f"metrics: shapes differ, output {tuple(output.shape)} vs target {tuple(target.shape)}"
        )
    if output.ndim != 4:
        raise ModelError(f"metrics: expected (N, C, H, W) batches, got {tuple(output.shape)}")
    if output.numel() == 0:  # its mean is NaN, its minimum a torch traceback
        raise ModelError(f"metrics: empty images (N, C, H, W) = {tuple(output.shape)}")
    for name, tensor in (("output", output), ("target", target)):
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ModelError(f"metrics: {name} holds NaN or infinite values")


SCALE_SLACK = 0.05
"""How far outside ``[0, 1]`` :func:`image_metrics` lets float values stray (rounding, int8)."""


def _check_scale(output: Tensor, target: Tensor, convention: "MetricConvention") -> None:
    """Refuse images that are not ``[0, 1]`` floats (or, for ``deraindrop-y``, uint8).

    A 0-255 or integer tensor scored with ``data_range=1`` gave a PSNR such as
    -5.9 dB where 42 dB was right, and clamping 0-255 floats to ``[0, 1]``
    binarised them: wrong numbers, silently.
    """
    for name, tensor in (("output", output), ("target", target)):
        if tensor.dtype == torch.uint8 and convention is MetricConvention.DERAINDROP_Y:
            continue
        if not tensor.is_floating_point():
            allowed = "floats in [0, 1]"
            if convention is MetricConvention.DERAINDROP_Y:
                allowed += " or uint8"
            raise ModelError(
                f"metrics: {name} is {tensor.dtype}; expected {allowed} "
                "(divide uint8 images by 255, uint16 by 65535)"
            )
        low, high = float(tensor.min()), float(tensor.max())
        if low < -SCALE_SLACK or high > 1.0 + SCALE_SLACK:
            raise ModelError(
                f"metrics: {name} values span [{low:g}, {high:g}]; expected [0, 1] "
                "(divide 0-255 values by 255)"
            )


def _check_valid(valid: Tensor | None, output: Tensor) -> Tensor | None:
    """``valid`` as ``(N, 1, H, W)`` float64 of 0/1 on ``output``'s device, or None."""
    if valid is None:
        return None
    batch, _, height, width = output.shape
    if valid.ndim != 4 or tuple(valid.shape) != (batch, 1, height, width):
        raise ModelError(
            f"metrics: valid map {tuple(valid.shape)} does not match the images "
            f"{(batch, 1, height, width)}"
        )
    return (valid.to(output.device) > 0).to(torch.float64)


def _data_range(output: Tensor, target: Tensor, data_range: float | None, what: str) -> float:
    """The peak-to-peak range to score with: ``data_range``, else as skimage takes it.

    None gives 1.0 for floats and, for integers, what skimage's ``dtype_range``
    gives (uint8 scored as if in [0, 1] gave -9.5 dB where 38.6 dB was right):
    ``ssim`` the dtype's span (255 for uint8, 65535 for int16), as
    ``structural_similarity``; ``psnr``, as ``peak_signal_noise_ratio``, reads
    the target: the dtype's maximum when it has no negative value, else the span
    (and 2 for floats with negative values, their range being [-1, 1]).
    """
    if data_range is not None:
        if not (math.isfinite(data_range) and data_range > 0):
            raise ModelError(
                f"{what}: data_range must be a finite positive number, got {data_range}"
            )
        return float(data_range)
    both_float = output.is_floating_point() and target.is_floating_point()
    if what == "ssim" and output.dtype != target.dtype and not both_float:
        raise ModelError(
            f"ssim: output is {output.dtype} and target {target.dtype}; give data_range"
        )
    negative = what == "psnr" and bool((target < 0).any())
    if target.is_floating_point():
        return 2.0 if negative else 1.0
    info = torch.iinfo(target.dtype)
    return float(info.max - info.min) if what == "ssim" or negative else float(info.max)


def psnr(
    output: Tensor, target: Tensor, data_range: float | None = None, valid: Tensor | None = None
) -> Tensor:
    """Peak signal-to-noise ratio per image, as ``skimage.metrics.peak_signal_noise_ratio``.

    Args:
        output: ``(N, C, H, W)`` restored images.
        target: ``(N, C, H, W)`` reference images.
        data_range: peak-to-peak range; None: as skimage's
            ``peak_signal_noise_ratio`` takes it from the target (1.0 for
            floats in [0, 1], 255 for uint8; :func:`_data_range`).
        valid: ``(N, 1, H, W)``, non-zero where a pixel is trustworthy; None: all are.

    Returns:
        ``(N,)`` float64 ``10 log10(data_range**2 / MSE)`` in dB, MSE over all
        channels and the valid pixels; ``+inf`` where those are identical.

    Raises:
        ModelError: on mismatched shapes, non-finite values, an image with
            no valid pixel, or a data range that is not a positive number.
    """
    _check_pair(output, target)
    data_range = _data_range(output, target, data_range, "psnr")
    difference = output.to(torch.float64) - target.to(torch.float64)
    weights = _check_valid(valid, output)
    if weights is None:
        mse = difference.square().flatten(1).mean(dim=1)
    else:
        counted = weights.flatten(1).sum(dim=1) * output.shape[1]
        if bool((counted == 0).any()):
            raise ModelError("psnr: an image has no trustworthy pixel to score (mask/ covers it)")
        mse = (difference.square() * weights).flatten(1).sum(dim=1) / counted
    return 10.0 * torch.log10(data_range**2 / mse)


def gaussian_window(sigma: float = GAUSSIAN_SIGMA, truncate: float = GAUSSIAN_TRUNCATE) -> Tensor:
    """1-D Gaussian taps as ``scipy.ndimage.gaussian_filter1d`` builds them.

    Args:
        sigma: standard deviation in pixels.
        truncate: radius in standard deviations (``radius = int(truncate * sigma + 0.5)``).

    Returns:
        ``(2 * radius + 1,)`` float64 taps summing to 1 (11 taps for the defaults).
    """
    radius = int(truncate * sigma + 0.5)
    positions = torch.arange(-radius, radius + 1, dtype=torch.float64)
    taps = torch.exp(-0.5 * (positions / sigma) ** 2)
    return taps / taps.sum()


def ssim(
    output: Tensor,
    target: Tensor,
    data_range: float | None = None,
    gaussian_weights: bool = True,
    win_size: int | None = None,
    sample_covariance: bool = False,
    valid: Tensor | None = None,
) -> Tensor:
    """Mean SSIM per image, as ``skimage.metrics.structural_similarity``.

    Channels are scored separately and averaged (skimage's ``channel_axis``).

    Args:
        output: ``(N, C, H, W)`` restored images (float or integer).
        target: ``(N, C, H, W)`` reference images.
        data_range: peak-to-peak range; None: 1.0 for floats, the dtype's span
            for integers (255 for uint8), as skimage's ``structural_similarity``.
        gaussian_weights: Gaussian window (sigma 1.5, 11 taps) if True, else a
            uniform ``win_size`` window.
        win_size: uniform window side (odd); default 7. Ignored (11) with
            Gaussian weights.
        sample_covariance: normalise covariances by ``N - 1`` instead of ``N``
            (skimage's default; ``False`` matches Wang et al.).
        valid: ``(N, 1, H, W)``, non-zero where a pixel is trustworthy: the
            map is averaged over the windows lying wholly on such pixels.

    Returns:
        ``(N,)`` float64 mean SSIM.

    Raises:
        ModelError: on mismatched shapes, non-finite values, an even window,
            a one-pixel window with ``sample_covariance``, images smaller than
            the window, no window wholly valid, or a data range that is not a
            positive number.
    """
    _check_pair(output, target)
    data_range = _data_range(output, target, data_range, "ssim")
    if gaussian_weights:
        taps = gaussian_window()
    else:
        size = UNIFORM_WIN_SIZE if win_size is None else win_size
        if size < 1 or size % 2 == 0:
            raise ModelError(f"ssim: win_size must be odd and positive, got {size}")
        taps = torch.full((size,), 1.0 / size, dtype=torch.float64)
    size = taps.numel()
    if sample_covariance and size == 1:
        raise ModelError("ssim: sample_covariance needs a window of more than one pixel")
    if min(output.shape[-2:]) < size:
        raise ModelError(
            f"ssim: images of {tuple(output.shape[-2:])} are smaller than the {size}x{size} window"
        )
    batch, channels = output.shape[:2]
    taps = taps.to(output.device)
    x = output.to(torch.float64).reshape(batch * channels, 1, *output.shape[-2:])
    y = target.to(torch.float64).reshape(batch * channels, 1, *target.shape[-2:])
    # One pass over the five statistics, each filtered separably and "valid".
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    stack = F.conv2d(stack, taps.view(1, 1, size, 1).expand(5, 1, size, 1), groups=5)
    stack = F.conv2d(stack, taps.view(1, 1, 1, size).expand(5, 1, 1, size), groups=5)
    mean_x, mean_y, mean_xx, mean_yy, mean_xy = stack.unbind(dim=1)
    count = size * size
    cov_norm = count / (count - 1) if sample_covariance else 1.0
    var_x = cov_norm * (mean_xx - mean_x * mean_x)
    var_y = cov_norm * (mean_yy - mean_y * mean_y)
    cov_xy = cov_norm * (mean_xy - mean_x * mean_y)
    c1 = (K1 * data_range) ** 2
    c2 = (K2 * data_range) ** 2
    numerator = (2 * mean_x * mean_y + c1) * (2 * cov_xy + c2)
    denominator = (mean_x * mean_x + mean_y * mean_y + c1) * (var_x + var_y + c2)
    ssim_map = numerator / denominator
    weights = _check_valid(valid, output)
    if weights is None:
        return ssim_map.reshape(batch, -1).mean(dim=1)
    # a window counts when every pixel under it is valid (a "valid" box sum of the map)
    box = torch.ones(1, 1, size, size, dtype=torch.float64, device=weights.device)
    whole = (F.conv2d(weights, box) > count - 0.5).to(torch.float64)  # (N, 1, H', W')
    windows = whole.flatten(1).sum(dim=1)
    if bool((windows == 0).any()):
        raise ModelError(
            f"ssim: an image has no {size}x{size} window wholly on trustworthy pixels "
            "(mask/ covers too much of it)"
        )
    per_channel = ssim_map.reshape(batch, channels, *ssim_map.shape[-2:]) * whole
    return per_channel.flatten(1).sum(dim=1) / (windows * channels)


def quantize_uint8(images: Tensor) -> Tensor:
    """Quantise [0, 1] floats to uint8 grey levels (round half to even, clipped).

    Args:
        images: float tensor in [0, 1] (values outside are clipped), or a
            uint8 tensor (returned unchanged).

    Returns:
        uint8 tensor of the same shape.
    """
    if images.dtype == torch.uint8:
        return images
    return torch.round(images.to(torch.float64).clamp(0.0, 1.0) * 255.0).to(torch.uint8)


def luma_uint8(images: Tensor) -> Tensor:
    """Full-range BT.601 luma of uint8 RGB images, bit-exact with OpenCV.

    ``Y = (4899 R + 9617 G + 1868 B + 8192) >> 14``: OpenCV's fixed-point
    ``COLOR_RGB2YCrCb`` (``COLOR_BGR2YCR_CB`` on BGR) channel 0.

    Args:
        images: ``(N, 3, H, W)`` uint8 RGB, or ``(N, 1, H, W)`` uint8 mono
            (returned unchanged).

    Returns:
        ``(N, 1, H, W)`` uint8.

    Raises:
        ModelError: for other channel counts or dtypes.
    """
    if images.dtype != torch.uint8 or images.ndim != 4 or images.shape[1] not in (1, 3):
        raise ModelError(
            f"luma: expected (N, 1 or 3, H, W) uint8, got {tuple(images.shape)} {images.dtype}"
        )
    if images.shape[1] == 1:
        return images
    rgb = images.to(torch.int32)
    luma = (4899 * rgb[:, 0:1] + 9617 * rgb[:, 1:2] + 1868 * rgb[:, 2:3] + 8192) >> 14
    return luma.to(torch.uint8)


def image_metrics(
    output: Tensor, target: Tensor, convention: MetricConvention, valid: Tensor | None = None
) -> ImageMetrics:
    """PSNR and SSIM of each image pair under a convention.

    Args:
        output: ``(N, C, H, W)`` restored images, float in [0, 1] (``C`` 1 or 3);
            ``deraindrop-y`` also takes uint8.
        target: ``(N, C, H, W)`` clean images, the same.
        convention: see the module docstring.
        valid: ``(N, 1, H, W)``, non-zero where a pixel is trustworthy (the
            module docstring); None: every pixel is.

    Returns:
        Per-image :class:`ImageMetrics`.

    Raises:
        ModelError: on mismatched or too small images, non-finite values,
            or images on another scale (integer codes, 0-255 floats).
    """
    convention = parse_metric_convention(str(convention))
    _check_pair(output, target)
    _check_scale(output, target, convention)
    if convention is MetricConvention.SKIMAGE_GAUSSIAN:
        return ImageMetrics(
            psnr=psnr(output, target, data_range=1.0, valid=valid),
            ssim=ssim(output, target, data_range=1.0, gaussian_weights=True, valid=valid),
            convention=convention,
        )
    output_y = luma_uint8(quantize_uint8(output))
    target_y = luma_uint8(quantize_uint8(target))
    return ImageMetrics(
        psnr=psnr(output_y, target_y, data_range=255.0, valid=valid),
        ssim=ssim(
            output_y,
            target_y,
            data_range=255.0,
            gaussian_weights=False,
            win_size=UNIFORM_WIN_SIZE,
            sample_covariance=True,
            valid=valid,
        ),
        convention=convention,
    )


def mean_psnr(values: Tensor, cap_db: float = PSNR_CAP_DB) -> float:
    """Average per-image PSNRs, capping each at ``cap_db`` first (``inf`` -> cap).

    Args:
        values: ``(N,)`` PSNRs in dB, possibly ``+inf``; ``N >= 1``.
        cap_db: the cap.

    Returns:
        The mean in dB, always finite.

    Raises:
        ModelError: if ``values`` is empty or holds NaN.
    """
    if values.numel() == 0:
        raise ModelError("mean_psnr: no values")
    if bool(torch.isnan(values).any()):
        raise ModelError("mean_psnr: NaN among the values")
    return float(values.to(torch.float64).clamp(max=cap_db).mean())
