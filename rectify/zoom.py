"""The zoom of ``alpha = 0``: the largest rectangle of the output's shape inside both valid regions.

On the rectified image plane (normalised coordinates ``x/z, y/z``) each raw
image covers the region inside its border's image, a curved quadrilateral
that a roll between the cameras turns and distortion bends. ``alpha = 0``
asks for the smallest focal length (the least zoom) whose output rectangle
lies inside both regions, with the principal point placed where that
rectangle fits best. Bounding boxes of each raw edge (the extreme x of the
left edge, ...) are only right while the edges stay nearly axis-aligned: a
roll of 30 deg zoomed 3.3 times more than needed and 40 deg with distortion
found no region at all.

So the choice is made in three steps:

1. :func:`inscribed_centre`: both border polygons are filled into one mask
   (``cv2.fillPoly``) on a grid whose cells have the output's aspect ratio,
   so that the output rectangle becomes a square; ``cv2.distanceTransform``
   with the chessboard metric gives, in every cell, the half side of the
   largest square centred there. The middle of its maximal cells is the
   centre.
2. :func:`smallest_valid_focal`: at a centre, a bisection on the focal
   length against the exact test (every pixel of the output's border has a
   source inside its raw image). Larger focal lengths shrink the rectangle
   about the centre, so the test is monotonic; a valid border means a valid
   interior, as the rays of a valid border lie in each camera's convex cone
   of valid rays and the raw image is convex.
3. :func:`refine_centre`: the grid placed the centre to a cell; golden-section
   searches of step 2 along each axis, within two cells, place it to a
   sixteenth of one.

A rectified frame takes about a tenth of a second to choose this way (the
bounding boxes took milliseconds); it is chosen once per recording.
"""

from collections.abc import Callable, Sequence

import cv2
import numpy as np

from lenspair.rectify.errors import RectifyError

GRID_CELLS = 1024
"""Cells across the larger side of the search window: the centre is placed to 1/1024 of it."""
_SHIFT = 4  # fractional bits of cv2.fillPoly's vertices
_PAD = 2  # empty cells around the search window
_NO_REGION = (
    "rectification: the two views have no common valid region (their fields of view do "
    "not overlap once rectified): check the rig's calibration, T_cn_cnm1 above all"
)


def camera_matrix(f: float, centre: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Rectified ``K``, ``(3, 3)`` float64, of focal length ``f`` (px), ``centre`` mid-image.

    ``centre`` is in normalised coordinates; the image middle is
    ``((width - 1) / 2, (height - 1) / 2)``, pixel centres at integers.
    """
    cx = (size[0] - 1) / 2 - f * centre[0]
    cy = (size[1] - 1) / 2 - f * centre[1]
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def border_pixels(size: tuple[int, int]) -> np.ndarray:
    """Centres of the outermost pixels of a ``(width, height)`` image, ``(N, 2)`` float64."""
    width, height = size
    xs, ys = np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)
    return np.concatenate(
        [
            np.column_stack([xs, np.zeros(width)]),
            np.column_stack([xs, np.full(width, height - 1.0)]),
            np.column_stack([np.zeros(height), ys]),
            np.column_stack([np.full(height, width - 1.0), ys]),
        ]
    )


def inscribed_centre(
    outlines: Sequence[np.ndarray], aspect: float
) -> tuple[np.ndarray, np.ndarray]:
    """Centre of the largest rectangle of width/height ``aspect`` inside every outline.

    Args:
        outlines: per view, its raw border on the rectified plane: ``(N, 2)``
            float64 normalised coordinates in order around the image (a
            closed polygon; consecutive points close together).
        aspect: width / height of the rectangle (the output image's).

    Returns:
        ``(2,)`` float64 normalised coordinates of the centre, and ``(2,)`` the
        size of the grid's cells there: how far the centre may be off.

    Raises:
        RectifyError: the outlines have no common interior.

    """
    scale = np.array([1.0 / aspect, 1.0])  # the rectangle becomes a square
    squares = [np.asarray(o, dtype=np.float64) * scale for o in outlines]
    low = np.max([s.min(axis=0) for s in squares], axis=0)
    high = np.min([s.max(axis=0) for s in squares], axis=0)
    if np.any(high <= low):
        raise RectifyError(_NO_REGION)
    cell = float(np.max(high - low)) / GRID_CELLS
    # empty cells all round: cv2.distanceTransform counts no zero beyond the image's edge,
    # and cv2.fillPoly fills the cells its edges touch, one more than the window
    width, height = (np.ceil((high - low) / cell).astype(int) + 2 * _PAD).tolist()
    mask = np.zeros((height, width), np.uint8)
    mask[_PAD:-_PAD, _PAD:-_PAD] = 1
    for square in squares:
        grid = (square - low) / cell + _PAD - 0.5  # mask pixel k: (k - PAD + 0.5) cells past low
        # far points (a fisheye's rim) would overflow fillPoly's fixed point; past a few
        # windows away they only need to stay outside it
        grid = np.clip(grid, -4.0 * max(width, height), 5.0 * max(width, height))
        vertices = np.round(grid * (1 << _SHIFT)).astype(np.int32).reshape(-1, 1, 2)
        fill = np.zeros_like(mask)
        cv2.fillPoly(fill, [vertices], 1, cv2.LINE_8, _SHIFT)
        mask &= fill
    distance = cv2.distanceTransform(mask, cv2.DIST_C, 3)
    best = float(distance.max())
    if best < 1.0:
        raise RectifyError(_NO_REGION)
    # the largest square often fits along a ridge (room to spare one way): its middle,
    # as a centred crop would choose, snapped back onto the ridge if the ridge bends
    rows, columns = np.nonzero(distance >= best)
    middle = np.array([columns.mean(), rows.mean()])
    nearest = np.argmin((columns - middle[0]) ** 2 + (rows - middle[1]) ** 2)
    index = np.array([columns[nearest], rows[nearest]], dtype=np.float64)
    centre = np.asarray((index - _PAD + 0.5) * cell + low, dtype=np.float64) / scale
    return centre, cell / scale


_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def _lowest_end(
    value: Callable[[float], float], low: float, high: float, tol: float, left: bool
) -> float:
    """Golden-section search of ``value`` on ``[low, high]`` to ``tol``.

    On a flat bottom it ends at the bottom's end towards ``low`` (``left``) or ``high``.
    """
    inner = (high - _GOLDEN * (high - low), low + _GOLDEN * (high - low))
    values = (value(inner[0]), value(inner[1]))
    while high - low > tol:
        if values[0] < values[1] or (left and values[0] == values[1]):
            high = inner[1]
            inner = (high - _GOLDEN * (high - low), inner[0])
            values = (value(inner[0]), values[0])
        else:
            low = inner[0]
            inner = (inner[1], low + _GOLDEN * (high - low))
            values = (values[1], value(inner[1]))
    return float(inner[int(np.argmin(values))])


def _along(
    least_focal: Callable[[np.ndarray], float], centre: np.ndarray, axis: int, unit: float
) -> Callable[[float], float]:
    """``least_focal`` with ``centre`` moved along ``axis``, in ``unit`` to five decimals.

    Rounded so that the searches' own precision makes no difference: a flat stretch stays flat.
    """

    def value(position: float) -> float:
        trial = centre.copy()
        trial[axis] = position
        return float(np.round(least_focal(trial) / unit, 5))

    return value


def refine_centre(
    least_focal: Callable[[np.ndarray], float], centre: np.ndarray, cell: np.ndarray
) -> tuple[np.ndarray, float]:
    """Move ``centre`` within two grid cells each way to lower ``least_focal``, one axis at a time.

    The grid of :func:`inscribed_centre` places the centre to a cell, which
    with a fisheye's wide outline is a few tenths of a per cent of zoom. Along
    each axis a golden-section search finds the lowest focal length; where it
    is flat (room to spare along that axis, for now or for good) the centre
    goes to the middle of the flat stretch: a centred crop, and the room the
    other axis needs to improve next round (the focal length is the larger of
    what two sides need). Rounds repeat while the focal length drops.

    Args:
        least_focal: the smallest valid focal length (px) at a centre, to a
            relative precision well under ``1e-5``.
        centre: ``(2,)`` normalised starting point.
        cell: ``(2,)`` grid cell size, normalised.

    Returns:
        The centre and its focal length.

    """
    best_centre, best = np.array(centre, dtype=np.float64), least_focal(centre)
    for _ in range(2):
        start = best
        for axis in (1, 0):
            value = _along(least_focal, best_centre, axis, start)
            span = (best_centre[axis] - 2 * cell[axis], best_centre[axis] + 2 * cell[axis])
            ends = [_lowest_end(value, *span, cell[axis] / 16, left) for left in (True, False)]
            middle = best_centre.copy()
            middle[axis] = (ends[0] + ends[1]) / 2
            focal = least_focal(middle)
            if focal <= best * (1.0 + 1e-6):  # no worse: centred, or lower
                best_centre, best = middle, focal
        if best > start * (1.0 - 1e-5):
            break
    return best_centre, best


def smallest_valid_focal(
    valid: Callable[[float], bool],
    guess: float,
    tolerance: float = 1e-6,
    step: float = 1.1,
    ceiling: float | None = None,
) -> float:
    """Smallest focal length for which ``valid`` holds, assuming it holds for all larger ones.

    Args:
        valid: the test, monotonic in the focal length (pixels).
        guess: a starting value, pixels, > 0.
        tolerance: relative precision of the result.
        step: factor by which the bracket grows from ``guess`` (small for a close guess).
        ceiling: the largest focal length worth an answer, pixels; None: a
            million times ``guess``, and none valid up to it is an error.

    Returns:
        A focal length, pixels, for which ``valid`` holds, within ``tolerance``
        of the smallest such; ``inf`` where none up to a given ``ceiling`` is.

    Raises:
        RectifyError: no ``ceiling`` given, and no focal length up to a million
            times ``guess`` is valid.

    """
    top = guess * 1e6 if ceiling is None else ceiling
    high = min(guess, top)
    while not valid(high):
        if high >= top:
            if ceiling is None:
                raise RectifyError(_NO_REGION)
            return float("inf")
        high = min(high * step, top)
    low = high / step
    for _ in range(1000):  # a small enough focal length shows more than either image holds
        if not valid(low):
            break
        high, low = low, low / step
    while high / low - 1.0 > tolerance:
        middle = np.sqrt(high * low)
        high, low = (middle, low) if valid(middle) else (high, middle)
    return float(high)
