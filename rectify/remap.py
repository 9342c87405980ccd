"""One ``cv2.remap`` per view: rectification, homography and crop composed into one map.

Each output image is interpolated exactly once, from the *raw* camera image:

* input (obstructed): ``out(u, v) = raw_obstructed(r_o(u + x0, v + y0))``
* target (clean):     ``out(u, v) = raw_clean(r_c(H^-1 (u + x0, v + y0)))``

where ``r_o``/``r_c`` map rectified pixel coordinates to raw pixel
coordinates (the rectification, distortion included), ``H`` maps rectified
clean pixels to rectified obstructed pixels (the registration) and
``(x0, y0)`` is the crop's corner. Coordinates are pixel centres (OpenCV's
convention: pixel ``(0, 0)`` is centred at ``(0.0, 0.0)``). A view that the
map reduces by about 2x or more (the clean camera of a rig whose cameras
differ in resolution) is first low-pass filtered and halved by
``cv2.pyrDown`` (:attr:`RemapGrid.levels`), as bicubic sampling alone would
alias its fine detail.

The target map is built with a margin of spare pixels around the crop so
that a small per-frame translation (the refinement of
:mod:`lenspair.rectify.registration`) is applied by resampling the *map*, which is
smooth, never the image: the image is still interpolated once.
"""

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from lenspair.rectify.crop import Crop
from lenspair.rectify.rectification import OUTSIDE

PointMap = Callable[[np.ndarray], np.ndarray]
"""``(N, 2)`` float64 rectified pixel coordinates -> ``(N, 2)`` float64 raw pixel coordinates."""


INTERPOLATION = cv2.INTER_CUBIC
"""Kernel used for every output image (bicubic: sharper than bilinear, same cost class)."""


@dataclass(frozen=True)
class RemapGrid:
    """A sampling map for ``cv2.remap``.

    Attributes:
        map_x: ``(H, W)`` float32 source column for each output pixel.
        map_y: ``(H, W)`` float32 source row for each output pixel.
        margin: spare pixels on every side beyond the output size (see
            :func:`shifted`); 0 for a map that is used as is.
        levels: ``cv2.pyrDown`` steps the image takes before the map samples
            it (the map's coordinates are in that level's pixels): a view
            reduced by about 2x or more (a camera of higher resolution than
            the obstructed one) is low-pass filtered first, not aliased.
        step: raw pixels per output pixel (the median over the map, at
            level 0): above 1 the view is reduced, below 1 enlarged.

    """

    map_x: np.ndarray
    map_y: np.ndarray
    margin: int = 0
    levels: int = 0
    step: float = 1.0

    def __post_init__(self) -> None:
        if self.map_x.shape != self.map_y.shape or self.map_x.ndim != 2:
            raise ValueError(
                f"map_x and map_y must be equal 2-D shapes, got {self.map_x.shape} "
                f"and {self.map_y.shape}"
            )

    @property
    def output_size(self) -> tuple[int, int]:
        """``(width, height)`` of the images this map produces (margin excluded)."""
        rows, cols = self.map_x.shape
        return (cols - 2 * self.margin, rows - 2 * self.margin)


def pixel_grid(x0: float, y0: float, width: int, height: int) -> np.ndarray:
    """Pixel-centre coordinates of a ``width x height`` block starting at ``(x0, y0)``.

    Returns:
        ``(height * width, 2)`` float64 ``(x, y)`` points, row-major.

    """
    xs, ys = np.meshgrid(
        np.arange(width, dtype=np.float64) + x0, np.arange(height, dtype=np.float64) + y0
    )
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


def apply_homography(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 3x3 homography to ``(N, 2)`` points (float64)."""
    matrix = np.asarray(matrix, dtype=np.float64)
    homogeneous = points @ matrix[:, :2].T + matrix[:, 2]
    return np.asarray(homogeneous[:, :2] / homogeneous[:, 2:3])


def sampling_step(points: np.ndarray, shape: tuple[int, int]) -> float:
    """Raw pixels per output pixel of a map's ``(rows * cols, 2)`` points (median; 1 if none).

    The geometric mean of the steps along rows and columns, so that a view
    reduced 2x each way has step 2.
    """
    grid = points.reshape(*shape, 2)
    along_u = np.linalg.norm(np.diff(grid, axis=1)[:-1], axis=2)
    along_v = np.linalg.norm(np.diff(grid, axis=0)[:, :-1], axis=2)
    steps = np.sqrt(along_u * along_v)
    steps = steps[np.isfinite(steps) & (steps > 0)]
    return float(np.median(steps)) if steps.size else 1.0


def _grid_from_points(points: np.ndarray, width: int, height: int, margin: int) -> RemapGrid:
    shape = (height + 2 * margin, width + 2 * margin)
    step = sampling_step(points, shape)
    # pyramid steps leave a reduction of at most sqrt(2) to the bicubic kernel, which
    # then aliases little; cv2.pyrDown's pixel i is centred on pixel 2i of its source
    levels = max(0, int(np.floor(np.log2(step) + 0.5)))
    points = np.where(np.isfinite(points), points / 2.0**levels, OUTSIDE)
    map_x = np.ascontiguousarray(points[:, 0].reshape(shape), dtype=np.float32)
    map_y = np.ascontiguousarray(points[:, 1].reshape(shape), dtype=np.float32)
    return RemapGrid(map_x, map_y, margin, levels, step)


def input_map(rectified_to_raw: PointMap, crop: Crop) -> RemapGrid:
    """Map for the obstructed view: raw -> rectified -> cropped, in one step."""
    points = pixel_grid(crop.x, crop.y, crop.width, crop.height)
    return _grid_from_points(rectified_to_raw(points), crop.width, crop.height, 0)


def target_map(
    rectified_to_raw: PointMap, homography: np.ndarray, crop: Crop, margin: int = 0
) -> RemapGrid:
    """Map for the clean view: raw -> rectified -> homography -> cropped, in one step.

    Args:
        rectified_to_raw: the clean camera's rectified -> raw point map.
        homography: 3x3, rectified clean pixels -> rectified obstructed pixels.
        crop: the output crop in rectified obstructed pixels.
        margin: spare pixels on every side, for per-frame shifts.

    """
    points = pixel_grid(
        crop.x - margin, crop.y - margin, crop.width + 2 * margin, crop.height + 2 * margin
    )
    clean_rectified = apply_homography(np.linalg.inv(homography), points)
    raw = rectified_to_raw(clean_rectified)
    return _grid_from_points(raw, crop.width, crop.height, margin)


def shifted(grid: RemapGrid, dx: float, dy: float) -> RemapGrid:
    """The map's inner (output-size) part, sampled at ``(u + dx, v + dy)``.

    The map itself is smooth (a distortion model composed with a
    homography), so sampling it bilinearly is exact to well under 0.01 px;
    the image is still interpolated only once, by :func:`apply`.

    Args:
        grid: a map with a margin of more than ``max(|dx|, |dy|) + 1`` px.
        dx: shift along columns, pixels.
        dy: shift along rows, pixels.

    Raises:
        ValueError: the shift exceeds the map's margin.

    """
    if max(abs(dx), abs(dy)) > grid.margin - 1 and (dx, dy) != (0.0, 0.0):
        raise ValueError(f"shift ({dx:.2f}, {dy:.2f}) px exceeds the map margin {grid.margin} px")
    width, height = grid.output_size
    m = grid.margin
    if dx == 0.0 and dy == 0.0:
        return RemapGrid(
            np.ascontiguousarray(grid.map_x[m : m + height, m : m + width]),
            np.ascontiguousarray(grid.map_y[m : m + height, m : m + width]),
            levels=grid.levels,
            step=grid.step,
        )
    # A constant shift: bilinear weights are the same everywhere, so the map is
    # interpolated exactly in float64 instead of with remap's 1/32-px weights.
    ix, iy = int(np.floor(dx)), int(np.floor(dy))
    fx, fy = dx - ix, dy - iy
    top, left = m + iy, m + ix

    def sample(values: np.ndarray) -> np.ndarray:
        v = values.astype(np.float64)
        a = v[top : top + height, left : left + width]
        b = v[top : top + height, left + 1 : left + 1 + width]
        c = v[top + 1 : top + 1 + height, left : left + width]
        d = v[top + 1 : top + 1 + height, left + 1 : left + 1 + width]
        mixed = (1 - fy) * ((1 - fx) * a + fx * b) + fy * ((1 - fx) * c + fx * d)
        return np.ascontiguousarray(mixed, dtype=np.float32)

    map_x, map_y = sample(grid.map_x), sample(grid.map_y)
    return RemapGrid(map_x, map_y, levels=grid.levels, step=grid.step)


def apply(image: np.ndarray, grid: RemapGrid) -> np.ndarray:
    """Resample ``image`` through ``grid`` (bicubic, constant black border).

    Args:
        image: ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)``, raw camera pixels.
        grid: a map without margin (see :func:`shifted` for maps with one).

    Returns:
        Same dtype and channels, ``grid.output_size``.

    """
    if grid.margin:
        grid = shifted(grid, 0.0, 0.0)
    for _ in range(grid.levels):
        image = np.asarray(cv2.pyrDown(image))
    return np.asarray(
        cv2.remap(image, grid.map_x, grid.map_y, INTERPOLATION, borderMode=cv2.BORDER_CONSTANT)
    )


def inside(points: np.ndarray, size: tuple[int, int], border: float = 1.0) -> np.ndarray:
    """Which ``(N, 2)`` points lie at least ``border`` px inside a ``(width, height)`` image.

    Bicubic sampling reads one pixel before and two after the sample point,
    so ``border=1`` keeps every tap inside the image up to the last pixel.
    Non-finite points are outside.
    """
    width, height = size
    x, y = points[:, 0], points[:, 1]
    with np.errstate(invalid="ignore"):
        return np.asarray(
            np.isfinite(x)
            & np.isfinite(y)
            & (x >= border)
            & (x <= width - 1 - border)
            & (y >= border)
            & (y <= height - 1 - border)
        )


def valid_region(
    obstructed_to_raw: PointMap,
    clean_to_raw: PointMap,
    homography: np.ndarray,
    rectified_size: tuple[int, int],
    obstructed_raw_size: tuple[int, int],
    clean_raw_size: tuple[int, int],
) -> np.ndarray:
    """Where both registered views have data, on the rectified obstructed grid.

    Args:
        obstructed_to_raw: rectified -> raw point map of the obstructed camera.
        clean_to_raw: rectified -> raw point map of the clean camera.
        homography: rectified clean -> rectified obstructed pixels.
        rectified_size: ``(width, height)`` of the rectified obstructed grid.
        obstructed_raw_size: ``(width, height)`` of the raw obstructed images.
        clean_raw_size: ``(width, height)`` of the raw clean images.

    Returns:
        ``(height, width)`` bool.

    """
    width, height = rectified_size
    points = pixel_grid(0, 0, width, height)
    valid = inside(obstructed_to_raw(points), obstructed_raw_size)
    clean_points = apply_homography(np.linalg.inv(homography), points)
    valid &= inside(clean_to_raw(clean_points), clean_raw_size)
    return valid.reshape(height, width)
