"""Choosing the output crop inside the region that both registered views cover.

The crop is an axis-aligned ``width x height`` rectangle (540x360 by default)
in *rectified obstructed* pixels. It must lie entirely in the intersection of

* the rectified obstructed view's valid region (rectified pixels whose source
  lies inside the raw obstructed image), and
* the clean view's valid region after the homography (rectified obstructed
  pixels whose clean source, through the homography and the clean
  rectification, lies inside the raw clean image).

Among all placements that fit, the one whose centre is closest to the
centroid of that intersection is chosen (ties: smallest ``y``, then ``x``),
so the crop is centred in the valid intersection whenever it can be. When no
placement fits, :class:`CropError` says by how much the valid region falls
short, in sizes of crops that do fit, e.g. ``valid region too small; need
720x540: 392 px too narrow at full height (328x540 px fits) or 4 px too short
at full width (720x536 px fits); the largest crop of that shape that fits is
714x536 px``.
"""

from dataclasses import dataclass

import numpy as np

from lenspair.rectify.errors import CropError


@dataclass(frozen=True)
class Crop:
    """An axis-aligned rectangle in rectified obstructed pixels.

    Attributes:
        x: left column of the crop (inclusive).
        y: top row of the crop (inclusive).
        width: columns.
        height: rows.

    """

    x: int
    y: int
    width: int
    height: int

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"crop size must be positive, got {self.width}x{self.height}")

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return (self.width, self.height)

    def as_tuple(self) -> tuple[int, int, int, int]:
        """``(x, y, width, height)``, as ``report.json`` stores it."""
        return (self.x, self.y, self.width, self.height)


def _run_lengths_down(valid: np.ndarray) -> np.ndarray:
    """Per pixel: number of consecutive valid pixels ending here, counting downwards."""
    runs = np.zeros(valid.shape, dtype=np.int32)
    previous = np.zeros(valid.shape[1], dtype=np.int32)
    for row in range(valid.shape[0]):
        previous = np.where(valid[row], previous + 1, 0).astype(np.int32)
        runs[row] = previous
    return runs


def _max_width_at_height(valid: np.ndarray, height: int) -> int:
    """Widest all-valid rectangle of exactly ``height`` rows (0 when none)."""
    if height <= 0 or height > valid.shape[0]:
        return 0
    tall_enough = _run_lengths_down(valid) >= height
    return int(_run_lengths_down(tall_enough.T).max(initial=0))


def _max_height_at_width(valid: np.ndarray, width: int) -> int:
    """Tallest all-valid rectangle of exactly ``width`` columns (0 when none)."""
    return _max_width_at_height(valid.T, width)


def _largest_of_shape(valid: np.ndarray, width: int, height: int) -> tuple[int, int]:
    """The largest all-valid rectangle of the shape ``width`` x ``height`` (scaled down)."""
    low, high = 0, min(height, valid.shape[0])  # a height that fits, one that may not
    while low < high:
        middle = (low + high + 1) // 2
        if _max_width_at_height(valid, middle) >= middle * width // height:
            low = middle
        else:
            high = middle - 1
    return low * width // height, low


def _shortfall_message(valid: np.ndarray, width: int, height: int) -> str:
    """Why no ``width`` x ``height`` crop fits ``valid``, in sizes of crops that do fit.

    A rectified region is not a rectangle: at the requested height it may be
    far narrower than at a few rows less, so one "valid region is WxH" figure
    contradicted the crop it advised. The shortfall is said at the full
    height and at the full width, each with the crop that fits there, then
    the largest crop of the requested shape (:func:`_largest_of_shape`).
    """
    wide = _max_width_at_height(valid, height)  # widest crop of the full height; 0: none
    tall = _max_height_at_width(valid, width)  # tallest crop of the full width; 0: none
    if wide and tall:  # each side fits alone, not both together
        shortfall = (
            f"{width - wide} px too narrow at full height ({wide}x{height} px fits) or "
            f"{height - tall} px too short at full width ({width}x{tall} px fits)"
        )
    elif wide:
        shortfall = (
            f"{width - wide} px too narrow ({wide}x{height} px fits; no crop {width} px wide does)"
        )
    elif tall:
        shortfall = (
            f"{height - tall} px too short ({width}x{tall} px fits; no crop {height} px tall does)"
        )
    elif valid.any():
        widest = _max_width_at_height(valid, 1)
        tallest = _max_height_at_width(valid, 1)
        shortfall = (
            f"{width - widest} px too narrow and {height - tallest} px too short (no crop "
            f"wider than {widest} px or taller than {tallest} px fits)"
        )
    else:
        return f"need {width}x{height}: the valid region is empty (the views share no pixel)"
    message = f"valid region too small; need {width}x{height}: {shortfall}"
    scaled = _largest_of_shape(valid, width, height)
    if scaled[0] > 0:
        message += f"; the largest crop of that shape that fits is {scaled[0]}x{scaled[1]} px"
    return message


def choose_crop(valid: np.ndarray, size: tuple[int, int]) -> Crop:
    """Place a ``size`` crop in the valid region, centred as well as it can be.

    Args:
        valid: ``(H, W)`` bool, True where both registered views have data
            (rectified obstructed pixel grid).
        size: ``(width, height)`` of the crop in pixels.

    Returns:
        The crop whose centre is closest to the centroid of ``valid``.

    Raises:
        CropError: no placement fits; the message gives the shortfall and
            the crops that fit.
        ValueError: ``valid`` is not a 2-D array, or a side of ``size`` is under 1.

    """
    valid = np.asarray(valid, dtype=bool)
    if valid.ndim != 2:
        raise ValueError(f"valid: expected shape (H, W), got {valid.shape}")
    width, height = size
    if width < 1 or height < 1:
        raise ValueError(f"crop size: expected at least 1x1 pixels, got {width}x{height}")
    rows, cols = valid.shape
    if width > cols or height > rows or not valid.any():
        raise CropError(_shortfall_message(valid, width, height))
    integral = np.zeros((rows + 1, cols + 1), dtype=np.int64)
    integral[1:, 1:] = valid.cumsum(axis=0).cumsum(axis=1)
    window = (
        integral[height:, width:]
        - integral[:-height, width:]
        - integral[height:, :-width]
        + integral[:-height, :-width]
    )
    fits = window == width * height
    if not fits.any():
        raise CropError(_shortfall_message(valid, width, height))
    ys, xs = np.nonzero(valid)
    centre_x, centre_y = float(xs.mean()), float(ys.mean())
    top, left = np.nonzero(fits)  # row-major order: ties resolve to smallest y, then x
    distance = (left + (width - 1) / 2 - centre_x) ** 2 + (top + (height - 1) / 2 - centre_y) ** 2
    best = int(np.argmin(distance))
    return Crop(int(left[best]), int(top[best]), width, height)
