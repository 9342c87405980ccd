"""Image-quality figures shared by ``capture-ingest`` and ``dataset-build``.

Both stages describe the clean view of a pair with the same numbers
(``pairs.jsonl`` records them, the curation rules read them), so they are
computed in one place:

* :func:`to_grey` - grey ``float32`` in ``[0, 1]`` (Rec. 601 weights for RGB);
* :func:`exposure_fractions` - fractions of saturated and black pixels;
* :func:`laplacian_variance` - variance of the 3x3 Laplacian on the 8-bit
  scale, the usual motion-blur / defocus figure;
* :func:`is_blank` - a nearly uniform frame (black, saturated, lens cap),
  which carries no evidence about the glass;
* :func:`anomaly_cells` - where the obstructed and clean views differ, at
  1/4 resolution: ``dataset-build`` counts them (a pair without any is
  ``clean``) and training centres crops on them.
"""

import cv2
import numpy as np

from lenspair.core.pixels import max_value

BLANK_STD = 1.0 / 255.0
"""Luma standard deviation (``[0, 1]`` scale) below which a frame is blank."""

ANOMALY_SCALE = 4
"""Side in pixels of the cells :func:`anomaly_cells` compares."""


REC601 = (0.299, 0.587, 0.114)
"""Luma weights of R, G and B (ITU-R BT.601), as OpenCV's ``RGB2GRAY``."""


def to_grey(image: np.ndarray) -> np.ndarray:
    """``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)`` RGB -> grey ``float32`` in ``[0, 1]``.

    Divided, not multiplied by a rounded reciprocal: an 8-bit image and its
    16-bit copy (``x * 257``) give exactly the same grey (the quotients are
    equal and IEEE division rounds them alike), so a pair that differs only
    in bit depth compares as identical. RGB is weighted (Rec. 601) in
    float64: an RGB image of three equal channels gives exactly its grey
    image's values (OpenCV's float32 conversion moved 49 of the 256 levels,
    and a grey copy of a frame then read as a changed one).
    """
    top = max_value(image.dtype)
    if image.ndim == 3:
        grey: np.ndarray = image.astype(np.float64) @ np.array(REC601) / top
        return grey.astype(np.float32)
    return image.astype(np.float32) / np.float32(top)


def exposure_fractions(image: np.ndarray) -> tuple[float, float]:
    """Fractions of pixels at full scale (any channel) and at zero (every channel).

    Args:
        image: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)``.

    Returns:
        ``(saturated, black)``, each in ``[0, 1]``.
    """
    pixels = image.reshape(image.shape[0], image.shape[1], -1)
    top = max_value(image.dtype)
    return float((pixels >= top).any(axis=2).mean()), float((pixels == 0).all(axis=2).mean())


def laplacian_variance(grey: np.ndarray) -> float:
    """Variance of the 3x3 Laplacian of a grey ``[0, 1]`` image, on the 8-bit scale."""
    laplacian = cv2.Laplacian(grey * np.float32(255.0), cv2.CV_32F, ksize=1)
    return float(np.var(laplacian, dtype=np.float64))


def is_blank(image: np.ndarray) -> bool:
    """Whether ``image`` (``uint8``/``uint16``, grey or RGB) is nearly uniform.

    Its luma's standard deviation is below :data:`BLANK_STD`.
    """
    return float(to_grey(image).std()) < BLANK_STD


def anomaly_cells(
    input_grey: np.ndarray, target_grey: np.ndarray, valid: np.ndarray | None, delta: float
) -> tuple[np.ndarray, np.ndarray]:
    """Cells of :data:`ANOMALY_SCALE` pixels where the two views differ by more than ``delta``.

    Compared at 1/4 resolution (area average), so that sensor noise and
    one-pixel registration error along edges do not count, after removing
    the median difference (a gain or exposure offset between the cameras).

    Args:
        input_grey: ``float32`` ``(H, W)`` in [0, 1].
        target_grey: same.
        valid: ``bool`` ``(H, W)``, True where trustworthy; None for all.
        delta: threshold in [0, 1].

    Returns:
        ``(anomalous, trusted)``: ``bool`` maps of ``(H // 4, W // 4)`` cells
        (at least 1x1); a cell is trusted when most of its pixels are valid
        (every cell, when none is). Anomalous cells are trusted ones.
    """
    height, width = input_grey.shape
    size = (max(1, width // ANOMALY_SCALE), max(1, height // ANOMALY_SCALE))
    diff = cv2.resize(input_grey - target_grey, size, interpolation=cv2.INTER_AREA)
    trusted = np.ones(diff.shape, bool)
    if valid is not None:
        small = cv2.resize(valid.astype(np.float32), size, interpolation=cv2.INTER_AREA)
        if np.any(small > 0.5):
            trusted = small > 0.5
    offset = np.float32(np.median(diff[trusted]))
    return (np.abs(diff - offset) > delta) & trusted, trusted


EXPOSURE_LEVELS = (0.05, 0.95)
"""Grey levels (``[0, 1]``) between which a pixel tells the two views' exposure apart.

Near black a ratio is the sensors' noise, and near full scale the light was
clipped: neither says anything of a gain.
"""


def exposure_ratio(
    grey_input: np.ndarray, grey_target: np.ndarray, untrusted: np.ndarray | None = None
) -> float | None:
    """Median ratio of the target's grey levels to the input's, as stored (not linear light).

    Over the pixels both views hold within :data:`EXPOSURE_LEVELS` and that
    ``untrusted`` (parallax, misregistration) leaves; None when fewer than 1 %
    of the pixels qualify (a dark or clipped frame). 1 when the cameras expose
    alike and the glass changes little; a gain or exposure difference
    between the cameras moves it, and so do the anomaly's veil and
    brightened drops, which no single pair tells apart from a gain.
    """
    low, high = EXPOSURE_LEVELS
    usable = (grey_input > low) & (grey_input < high) & (grey_target > low) & (grey_target < high)
    if untrusted is not None:
        usable &= ~untrusted
    if np.count_nonzero(usable) < 0.01 * usable.size:
        return None
    return float(np.median(grey_target[usable] / grey_input[usable]))
