"""Sprites: the pixels that drops and dirt blobs cover on the glass layer.

Drops and blobs are rasterised only inside their bounding boxes, and only
the pixels they cover (coverage ``alpha > 0``) are kept, as flat lists
ordered by sprite (a later sprite lies on top of an earlier one).
Coordinates are image pixels (``x`` right, ``y`` down, pixel centres at
integers); sprites may reach ``pad`` pixels beyond the image so that a
defocused drop cut by the border still bleeds into the frame correctly.

The glass layer is a premultiplied ``float32`` canvas of shape
``(H + 2 * margin, W + 2 * margin, C + 1)``: colour channels then coverage,
with image pixel ``(y, x)`` at canvas index ``(y + margin, x + margin)``.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Sprites:
    """The covered pixels of the sprites of one effect.

    Attributes:
        boxes: ``int64`` ``(N, 4)`` rows ``(y0, y1, x0, x1)``, half-open
            bounding boxes in image coordinates (may reach beyond the image
            by the pad; may be empty).
        ys: ``int64`` ``(M,)`` row of each covered pixel.
        xs: ``int64`` ``(M,)`` column of each covered pixel.
        owner: ``int64`` ``(M,)`` sprite index of each pixel, non-decreasing.
        alpha: ``float32`` ``(M,)`` coverage in ``(0, 1]``.

    """

    boxes: np.ndarray
    ys: np.ndarray
    xs: np.ndarray
    owner: np.ndarray
    alpha: np.ndarray

    @property
    def count(self) -> int:
        """Number of sprites."""
        return int(self.boxes.shape[0])

    def keep(self, covered: np.ndarray) -> "Sprites":
        """The same sprites restricted to the pixels where ``covered`` is true."""
        index = np.flatnonzero(covered)
        return Sprites(
            self.boxes,
            np.take(self.ys, index),
            np.take(self.xs, index),
            np.take(self.owner, index),
            np.take(self.alpha, index),
        )


def clip_boxes(
    center_x: np.ndarray,
    center_y: np.ndarray,
    extent_x: np.ndarray,
    extent_y: np.ndarray,
    shape: tuple[int, int],
    pad: int,
) -> np.ndarray:
    """Pixel boxes holding ``center -/+ extent``, clipped to the padded image.

    Args:
        center_x: ``(N,)`` centres, pixels.
        center_y: ``(N,)`` centres, pixels.
        extent_x: ``(N,)`` half widths, pixels (include any anti-aliasing margin).
        extent_y: ``(N,)`` half heights, pixels.
        shape: image ``(H, W)``.
        pad: how far boxes may reach beyond the image, pixels.

    Returns:
        ``int64`` ``(N, 4)`` half-open boxes ``(y0, y1, x0, x1)`` with
        ``y0 <= y1`` and ``x0 <= x1`` (empty when outside the padded image).

    """
    height, width = shape
    top = np.clip(np.floor(center_y - extent_y), -pad, height + pad)
    bottom = np.clip(np.ceil(center_y + extent_y) + 1, -pad, height + pad)
    left = np.clip(np.floor(center_x - extent_x), -pad, width + pad)
    right = np.clip(np.ceil(center_x + extent_x) + 1, -pad, width + pad)
    boxes = np.stack([top, np.maximum(bottom, top), left, np.maximum(right, left)], axis=1)
    return boxes.astype(np.int64).reshape(-1, 4)


def box_grid(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pixel of every box, concatenated in row-major order of each box.

    Args:
        boxes: ``int64`` ``(N, 4)`` from :func:`clip_boxes`.

    Returns:
        ``(ys, xs, owner)``: ``int64`` ``(M,)`` coordinates and box index.

    """
    heights = boxes[:, 1] - boxes[:, 0]
    widths = boxes[:, 3] - boxes[:, 2]
    sizes = heights * widths
    owner = np.repeat(np.arange(len(boxes)), sizes)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    local = np.arange(owner.shape[0], dtype=np.int64) - starts[owner]
    safe_widths = np.maximum(widths, 1)[owner]
    ys = boxes[owner, 0] + local // safe_widths
    xs = boxes[owner, 2] + local % safe_widths
    return ys, xs, owner


@dataclass(frozen=True, eq=False)
class Placement:
    """Where the pixels of some sprites land on a canvas, in compositing rounds.

    Attributes:
        canvas_index: ``int64`` ``(M,)`` flat canvas index of each pixel.
        rounds: pixel indices grouped so that no canvas index repeats within
            a round and the ``r``-th sprite covering a canvas pixel is in
            round ``r``; compositing the rounds in order is "later sprites
            on top".

    """

    canvas_index: np.ndarray
    rounds: tuple[np.ndarray, ...]


def place(sprites: Sprites, shape: tuple[int, int], margin: int) -> Placement:
    """Canvas positions and overlap rounds of the sprites' pixels.

    Args:
        sprites: the sprites; they must lie within ``margin`` of the image.
        shape: image ``(H, W)``.
        margin: canvas margin, pixels.

    """
    width = shape[1] + 2 * margin
    canvas_index = (sprites.ys + margin) * width + (sprites.xs + margin)
    order = np.argsort(canvas_index, kind="stable")  # keeps sprite order within a pixel
    ordered = canvas_index[order]
    first = np.ones(ordered.shape[0], bool)
    first[1:] = ordered[1:] != ordered[:-1]
    positions = np.arange(ordered.shape[0])
    rank = np.empty_like(positions)
    rank[order] = positions - np.maximum.accumulate(np.where(first, positions, 0))
    depth = int(rank.max(initial=-1)) + 1
    return Placement(canvas_index, tuple(np.flatnonzero(rank == r) for r in range(depth)))


def composite_over(
    canvas: np.ndarray,
    placement: Placement,
    premultiplied: np.ndarray,
    alpha: np.ndarray,
    empty: bool = False,
) -> None:
    """Composite sprite pixels over ``canvas`` in order (later sprites on top), in place.

    Args:
        canvas: ``float32`` ``(H + 2m, W + 2m, C + 1)`` premultiplied layer.
        placement: from :func:`place` for the same canvas.
        premultiplied: ``float32`` ``(M, C)`` colour times coverage, per pixel.
        alpha: ``float32`` ``(M,)`` coverage.
        empty: the canvas is still all zero (the first round is then a copy).

    """
    flat = canvas.reshape(-1, canvas.shape[2])
    channels = premultiplied.shape[1]
    for round_index, pixels in enumerate(placement.rounds):
        target = placement.canvas_index[pixels]
        top = np.empty((pixels.shape[0], channels + 1), np.float32)
        top[:, :channels] = premultiplied[pixels]
        top[:, channels] = alpha[pixels]
        if not (empty and round_index == 0):
            top += (1.0 - top[:, channels:]) * np.take(flat, target, axis=0)
        flat[target] = top


def support_mask(placement: Placement, canvas_shape: tuple[int, int]) -> np.ndarray:
    """``uint8`` canvas-sized mask, 255 at every placed pixel."""
    mask = np.zeros(canvas_shape, np.uint8)
    mask.reshape(-1)[placement.canvas_index] = 255
    return mask
