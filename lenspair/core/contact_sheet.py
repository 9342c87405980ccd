"""Contact sheets: a labelled grid of images for people to look at.

Used for ``qa.png`` of an ingested recording, ``contact_<split>.png`` of a
dataset and the sample grids of training and evaluation. Images of any
convention can be mixed on one sheet: ``uint8``, ``uint16`` (scaled by
1/257), ``float`` in [0, 1] (clipped), ``bool`` masks (0/255), mono ``(H, W)``
or ``(H, W, 1)``, RGB ``(H, W, 3)`` or RGBA (alpha dropped). Each is fitted
into a cell of fixed size, keeping its aspect ratio, with its label drawn in
a band above it. The result depends only on the inputs (byte-identical PNGs).
"""

from collections.abc import Sequence

import cv2
import numpy as np

_FONT = cv2.FONT_HERSHEY_SIMPLEX


def to_display(image: np.ndarray, stretch: bool = False) -> np.ndarray:
    """Convert one image to ``uint8`` RGB ``(H, W, 3)`` for display.

    Args:
        image: ``bool``, integer or float array, ``(H, W)``, ``(H, W, 1)``,
            ``(H, W, 3)`` or ``(H, W, 4)``. Floats are read as [0, 1];
            ``uint16`` as full-scale 16 bit; other integer types are
            stretched from their minimum to their maximum.
        stretch: stretch the 0.5-99.5 percentile range to full scale (for
            dark 10/12-bit data stored as 16 bit, or residual maps).

    Raises:
        ValueError: an unsupported shape.
    """
    array = np.asarray(image)
    if array.ndim == 3 and array.shape[2] in (1, 3, 4):
        array = array[:, :, 0] if array.shape[2] == 1 else array[:, :, :3]
    elif array.ndim != 2:
        raise ValueError(f"expected (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got {array.shape}")
    values = _to_unit(array)
    if stretch and values.size:
        low, high = np.percentile(values, [0.5, 99.5])
        values = (values - low) / max(float(high - low), 1e-6)
    out = np.rint(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8)
    if out.ndim == 2:
        out = np.repeat(out[:, :, None], 3, axis=2)
    return np.ascontiguousarray(out)


def _to_unit(array: np.ndarray) -> np.ndarray:
    if array.dtype == np.bool_:
        return array.astype(np.float32)
    if array.dtype == np.uint8:
        return array.astype(np.float32) / np.float32(255.0)
    if array.dtype == np.uint16:
        return array.astype(np.float32) / np.float32(65535.0)
    if np.issubdtype(array.dtype, np.floating):
        return np.nan_to_num(array.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    if np.issubdtype(array.dtype, np.integer):
        values = array.astype(np.float64)
        low, high = (float(values.min()), float(values.max())) if values.size else (0.0, 1.0)
        return ((values - low) / max(high - low, 1.0)).astype(np.float32)
    raise ValueError(f"unsupported image dtype {array.dtype}")


def fit_into(image: np.ndarray, width: int, height: int, background: int = 0) -> np.ndarray:
    """Fit a ``uint8`` RGB image into ``(height, width)``, centred, aspect kept.

    Shrinking averages pixels (``INTER_AREA``); enlarging repeats them
    (``INTER_NEAREST``) so that small masks and thumbnails stay crisp.
    """
    canvas = np.full((height, width, 3), background, np.uint8)
    h, w = image.shape[:2]
    if h == 0 or w == 0:
        return canvas
    scale = min(width / w, height / h)
    new_w, new_h = max(1, round(w * scale)), max(1, round(h * scale))
    interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_NEAREST
    resized = cv2.resize(image, (new_w, new_h), interpolation=interpolation)
    top, left = (height - new_h) // 2, (width - new_w) // 2
    canvas[top : top + new_h, left : left + new_w] = resized
    return canvas


ASPECT_RANGE = (0.25, 2.0)
"""Height over width of a default cell: a frame of another shape is fitted in, not the sheet."""


def make_contact_sheet(
    rows: Sequence[Sequence[np.ndarray | None]],
    labels: Sequence[Sequence[str]] | None = None,
    *,
    title: str | None = None,
    cell_width: int = 240,
    cell_height: int | None = None,
    padding: int = 4,
    font_scale: float = 0.4,
    background: int = 24,
    stretch: bool = False,
) -> np.ndarray:
    """Lay images out in a labelled grid.

    Args:
        rows: one sequence of images per row (rows may differ in length;
            ``None`` leaves a cell empty). Any convention of :func:`to_display`.
        labels: text per cell, same nesting as ``rows`` (missing entries are
            blank); drawn in a band above each image, cut to fit the cell.
        title: optional line of text across the top of the sheet.
        cell_width: width of a cell in pixels.
        cell_height: height of a cell; default: the median image's aspect,
            within :data:`ASPECT_RANGE` (each image is fitted into its cell).
        padding: pixels between cells and around the sheet.
        font_scale: OpenCV Hershey font scale (0.4 is about 9 px high).
        background: grey level of the background and empty cells.
        stretch: percentile-stretch every image (see :func:`to_display`).

    Returns:
        ``uint8`` RGB ``(H, W, 3)`` sheet.

    Raises:
        ValueError: no images, a non-positive cell size, or an unsupported image.
    """
    images = [image for row in rows for image in row if image is not None]
    if not images:
        raise ValueError("make_contact_sheet: no images given")
    if cell_height is None:
        # the median image's shape: a strip listed first (11x12420) made a 980x542034 sheet,
        # and a wide one shrank every other frame to a few pixels
        aspects = sorted(np.shape(image)[0] / max(1, np.shape(image)[1]) for image in images)
        aspect = min(max(aspects[len(aspects) // 2], ASPECT_RANGE[0]), ASPECT_RANGE[1])
        cell_height = max(1, round(cell_width * aspect))
    if cell_width < 1 or cell_height < 1:
        raise ValueError(f"cell size must be positive, got {cell_width}x{cell_height}")
    (_, text_h), baseline = cv2.getTextSize("Ag", _FONT, font_scale, 1)
    band = text_h + baseline + 4 if labels is not None else 0
    title_band = text_h + baseline + 8 if title else 0
    columns = max(len(row) for row in rows)
    width = padding + columns * (cell_width + padding)
    height = padding + title_band + len(rows) * (band + cell_height + padding)
    sheet = np.full((height, width, 3), background, np.uint8)
    if title:
        _put_text(sheet, title, padding, padding + text_h + 2, width - 2 * padding, font_scale)
    for r, row in enumerate(rows):
        top = padding + title_band + r * (band + cell_height + padding)
        for c, image in enumerate(row):
            left = padding + c * (cell_width + padding)
            if image is not None:
                cell = fit_into(to_display(image, stretch), cell_width, cell_height, background)
                sheet[top + band : top + band + cell_height, left : left + cell_width] = cell
            text = _label(labels, r, c)
            if text:
                _put_text(sheet, text, left, top + text_h + 1, cell_width, font_scale)
    return sheet


def _label(labels: Sequence[Sequence[str]] | None, row: int, column: int) -> str:
    if labels is None or row >= len(labels) or column >= len(labels[row]):
        return ""
    return str(labels[row][column])


def _put_text(sheet: np.ndarray, text: str, x: int, y: int, width: int, scale: float) -> None:
    """Draw ``text`` (cut with an ellipsis to fit ``width``) with its baseline at ``y``."""
    text = text.replace("\n", " ")
    while text and cv2.getTextSize(text, _FONT, scale, 1)[0][0] > width:
        text = text[:-2] + "~" if len(text) > 2 else ""
    if text:
        cv2.putText(sheet, text, (x, y), _FONT, scale, (235, 235, 235), 1, cv2.LINE_AA)
