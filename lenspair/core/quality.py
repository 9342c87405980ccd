"""Image-quality figures shared by ``capture-ingest`` and ``dataset-build``.

Both stages describe the clean view of a pair with the same numbers
(``pairs.jsonl`` records them, the curation rules read them), so they are
computed in one place:

* :func:`to_grey` - grey ``float32`` in ``[0, 1]`` (Rec. 601 weights for RGB);
* :func:`exposure_fractions` - fractions of saturated and black pixels;
* :func:`laplacian_variance` - variance of the 3x3 Laplacian on the 8-bit
  scale, the usual motion-blur / defocus figure;
* :func:`is_blank` - a nearly uniform frame (black, saturated, lens cap),
  which carries no evidence about the glass.
"""

import cv2
import numpy as np

from lenspair.core.imageio import max_value

BLANK_STD = 1.0 / 255.0
"""Luma standard deviation (``[0, 1]`` scale) below which a frame is blank."""


def to_grey(image: np.ndarray) -> np.ndarray:
    """``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)`` RGB -> grey ``float32`` in ``[0, 1]``."""
    grey = image.astype(np.float32) * np.float32(1.0 / max_value(image.dtype))
    if grey.ndim == 3:
        return np.asarray(cv2.cvtColor(grey, cv2.COLOR_RGB2GRAY))
    return grey


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
