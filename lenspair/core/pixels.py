"""The pixel conventions of lenspair, and conversions between them.

Conventions (stated once, checked where data enters):

* **On disk / in arrays between stages**: ``uint8`` or ``uint16``, shape
  ``(H, W)`` for mono or ``(H, W, 3)`` for RGB, sRGB-encoded as cameras and
  PNG viewers expect. Bit depth is preserved end to end.
* **Inside renderers and metrics**: ``float32`` in ``[0, 1]``; blending
  happens in *linear* light (:func:`to_linear` / :func:`from_linear`).

Image files are read and written in these conventions by
:mod:`lenspair.core.imageio` and :mod:`lenspair.core.imagewrite`.
"""

import numpy as np

_DTYPES = frozenset({np.dtype(np.uint8), np.dtype(np.uint16)})
"""The dtypes of images between stages: 8- and 16-bit codes."""


def check_image(image: np.ndarray, name: str = "image") -> None:
    """Raise ``ValueError`` unless ``image`` is uint8/uint16 (H, W) or (H, W, 3), H, W >= 1."""
    if image.dtype not in _DTYPES:
        if image.dtype.newbyteorder("=") in _DTYPES:  # a mono16 message with is_bigendian
            raise ValueError(
                f"{name}: {image.dtype} is uint16 in the other byte order; convert it first "
                "(frame.astype(np.uint16))"
            )
        raise ValueError(f"{name}: expected dtype uint8 or uint16, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ValueError(f"{name}: expected shape (H, W) or (H, W, 3), got {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"{name}: an empty image, shape {image.shape}")


def is_one_frame(images: np.ndarray) -> bool:
    """Whether an array given for a list of frames is one frame: ``(H, W)`` or ``(H, W, 3)``.

    Iterated, it would be a list of its rows, each taken for a frame (a stack
    of mono frames, ``(N, H, W)``, is a list; one of frames 3 pixels wide is not).
    """
    return images.ndim == 2 or (images.ndim == 3 and images.shape[2] == 3)


def max_value(dtype: np.dtype | type) -> float:
    """Largest code value of an integer image dtype (255 or 65535)."""
    return float(np.iinfo(np.dtype(dtype)).max)


def to_float(image: np.ndarray) -> np.ndarray:
    """Integer image to ``float32`` in ``[0, 1]`` (still sRGB-encoded)."""
    check_image(image)
    return image.astype(np.float32) / np.float32(max_value(image.dtype))


def from_float(image: np.ndarray, dtype: np.dtype | type) -> np.ndarray:
    """``float32`` image in ``[0, 1]`` to integer codes, clipping once, rounding."""
    scale = np.float32(max_value(dtype))
    scaled = np.clip(np.nan_to_num(image, nan=0.0), 0.0, 1.0) * scale
    return np.asarray(np.rint(scaled).astype(dtype))


def to_linear(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded ``[0, 1]`` float32 to linear light (IEC 61966-2-1)."""
    x = np.asarray(encoded, dtype=np.float32)
    low = x / np.float32(12.92)
    high = np.power((np.maximum(x, 0.04045) + np.float32(0.055)) / np.float32(1.055), 2.4)
    return np.where(x <= 0.04045, low, high).astype(np.float32)


def from_linear(linear: np.ndarray) -> np.ndarray:
    """Linear-light float32 to sRGB-encoded ``[0, 1]`` float32 (input clipped to >= 0)."""
    x = np.maximum(np.asarray(linear, dtype=np.float32), 0.0)
    low = x * np.float32(12.92)
    high = np.float32(1.055) * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - np.float32(0.055)
    return np.where(x <= 0.0031308, low, high).astype(np.float32)
