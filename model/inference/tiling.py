"""Running a backend on whole images or on overlapping tiles blended without seams.

Array convention: batches ``(N, C, H, W)`` ``float32`` in [0, 1]. Frames
enter as the :mod:`lenspair.core.pixels` convention (``uint8``/``uint16``,
``(H, W)`` or ``(H, W, 3)`` RGB) and leave in the same dtype and shape
(:func:`to_batch`, :func:`from_batch`).

Tiling (``--tile N``, or forced by an ONNX model of a fixed size, which
:class:`~lenspair.model.inference.backends.ForcedTiles` warns of once and
records): the image is covered by ``N x N`` tiles placed every
``N - overlap`` pixels (:func:`tile_starts`), the last one flush with the
border, so that no tile reaches past the image. Each tile's output is
weighted by a linear ramp that rises across the pixels it shares with its
neighbour on that side (sides on the image border keep weight 1), and the
weighted sum is divided by the summed weights, so every pixel is a convex
blend and no seam appears. The network normalises each tile by its own
statistics (instance norm), so a tiled result is close to, not equal to, the
whole-image one (tests/model/test_inference.py states the tolerance). A
``--tile`` longer than a side is cut to it; only a model of a fixed size
gets a side shorter than its tile, which is reflected up to the tile's and
cropped back.
"""

from collections.abc import Sequence

import numpy as np

from lenspair.core.bitdepth import narrow, widen
from lenspair.core.pixels import max_value
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import Backend, memory_error
from lenspair.model.inference.options import DEFAULT_OVERLAP, MIN_TILE

ALIGN = 32
"""Tile steps are multiples of this when possible: the enhancer pools 4..32 px cells."""

CHUNK_PIXELS = 512 * 512
"""Most pixels (over all tiles and frames) handed to the network in one call
(:func:`run_tiled`), unless one tile of the batch holds more: the network's working
memory grows with them (about 330 MB per megapixel at fp32 on the CPU), so a call
of eight 1024-px tiles took more memory than the 3-megapixel frame they tiled."""


def check_tile(tile: int | None) -> None:
    """Refuse a tile side below :data:`MIN_TILE` (None: whole images).

    Raises:
        ModelError: naming ``--tile``.
    """
    if tile is not None and tile < MIN_TILE:
        raise ModelError(f"--tile: expected at least {MIN_TILE} pixels, got {tile}")


def to_batch(images: list[np.ndarray]) -> np.ndarray:
    """Same-shape, same-dtype integer images -> ``(N, C, H, W)`` float32 in [0, 1].

    Raises:
        ModelError: no images, or images of different shapes or bit depths
            (a uint8 frame batched with uint16 ones was scaled by theirs, and
            :func:`from_batch` gives every output one dtype).
    """
    if not images:
        raise ModelError("to_batch: no images")
    shapes = {image.shape for image in images}
    if len(shapes) > 1:
        raise ModelError(f"to_batch: images of different shapes {sorted(shapes)}")
    dtypes = {image.dtype.name for image in images}
    if len(dtypes) > 1:
        raise ModelError(f"to_batch: images of different bit depths ({', '.join(sorted(dtypes))})")
    scale = np.float32(max_value(images[0].dtype))
    stacked = np.stack([image if image.ndim == 3 else image[:, :, None] for image in images])
    return np.ascontiguousarray(stacked.transpose(0, 3, 1, 2), dtype=np.float32) / scale


def from_batch(batch: np.ndarray, dtype: np.dtype, mono: bool) -> list[np.ndarray]:
    """``(N, C, H, W)`` float in [0, 1] -> integer images, rounded once, clipped."""
    scale = np.float32(max_value(dtype))
    codes = np.rint(np.clip(batch, 0.0, 1.0) * scale).astype(dtype)
    return [np.ascontiguousarray(image[0] if mono else image.transpose(1, 2, 0)) for image in codes]


def tile_starts(length: int, tile: int, overlap: int, align: int = ALIGN) -> list[int]:
    """Start offsets of tiles of ``tile`` pixels covering ``length``, overlapping.

    The step between tiles is ``tile - overlap`` rounded down to a multiple of
    ``align`` when that leaves a step of at least ``align`` (so every tile but
    the last sees the enhancer's pooling cells where the whole image does).
    The last tile is flush with the end (it starts at ``length - tile``), so
    its last step may be shorter: a tile reaching past the image saw a mirror
    image there, which the norms took for content (about 1.4x the mean error
    against the whole frame, at 752x480 in tiles of 540x360). A ``length``
    up to ``tile`` is one tile at 0 (the caller pads a shorter one).

    Raises:
        ModelError: ``overlap`` not in ``[0, tile)``.
    """
    if not 0 <= overlap < tile:
        raise ModelError(f"tile overlap must be in [0, {tile}), got {overlap}")
    if length <= tile:
        return [0]
    step = tile - overlap
    if step >= align:
        step -= step % align
    starts = [0]
    while starts[-1] + tile < length:
        starts.append(min(starts[-1] + step, length - tile))
    return starts


def ramp(tile: int, overlap_start: int, overlap_end: int) -> np.ndarray:
    """1-D blending weight of a tile: linear ramps across the pixels shared with each neighbour.

    Args:
        tile: the tile's side.
        overlap_start: pixels shared with the tile before it (0: none, the image border).
        overlap_end: pixels shared with the tile after it (0: none).

    Returns:
        ``(tile,)`` float32 in (0, 1].
    """
    weight = np.ones(tile, dtype=np.float32)
    position = np.arange(tile, dtype=np.float32)
    if overlap_start > 0:
        weight = np.minimum(weight, (position + 1) / np.float32(overlap_start + 1))
    if overlap_end > 0:
        weight = np.minimum(weight, (tile - position) / np.float32(overlap_end + 1))
    return weight


def _shared(starts: list[int], tile: int) -> list[tuple[int, int]]:
    """Per tile of ``starts``: pixels shared with the tile before it and the one after it."""
    last = len(starts) - 1
    return [
        (
            starts[i - 1] + tile - start if i > 0 else 0,
            start + tile - starts[i + 1] if i < last else 0,
        )
        for i, start in enumerate(starts)
    ]


def run_tiled(
    backend: Backend,
    batch: np.ndarray,
    tile: tuple[int, int],
    overlap: int = DEFAULT_OVERLAP,
    max_tiles: int = 8,
) -> np.ndarray:
    """Restore ``batch`` tile by tile and blend the tiles (see the module docstring).

    Args:
        backend: the network.
        batch: ``(N, C, H, W)`` float32 in [0, 1].
        tile: ``(tile_height, tile_width)``.
        overlap: pixels shared by neighbouring tiles (capped below the tile).
        max_tiles: most tiles per backend call (small ones; see :data:`CHUNK_PIXELS`).

    Returns:
        ``(N, C, H, W)`` float32 in [0, 1].
    """
    n, c, height, width = batch.shape
    tile_h, tile_w = tile
    frames = max(1, CHUNK_PIXELS // (tile_h * tile_w))
    if n > frames:  # a tile of every frame of a batch of 4 was 4 tiles' memory a call
        parts = [batch[i : i + frames] for i in range(0, n, frames)]
        return np.concatenate([run_tiled(backend, p, tile, overlap, max_tiles) for p in parts])
    rows = tile_starts(height, tile_h, min(overlap, tile_h - 1))
    cols = tile_starts(width, tile_w, min(overlap, tile_w - 1))
    full_h, full_w = max(height, tile_h), max(width, tile_w)
    padded = batch
    if (full_h, full_w) != (height, width):  # a side shorter than the tile (a fixed-size model)
        pad = ((0, 0), (0, 0), (0, full_h - height), (0, full_w - width))
        padded = np.pad(batch, pad, mode="symmetric")
    row_ramps = [ramp(tile_h, *shared) for shared in _shared(rows, tile_h)]
    col_ramps = [ramp(tile_w, *shared) for shared in _shared(cols, tile_w)]
    total = np.zeros((n, c, full_h, full_w), dtype=np.float32)
    weights = np.zeros((full_h, full_w), dtype=np.float32)
    places = [(row, col) for row in range(len(rows)) for col in range(len(cols))]
    # at most CHUNK_PIXELS a call, what bounds the network's memory: tiles are for
    # frames too large for it, and a call of several tiles undid what they save
    per_call = max(1, min(max_tiles // n, CHUNK_PIXELS // (n * tile_h * tile_w)))
    for first in range(0, len(places), per_call):
        chunk = places[first : first + per_call]
        tiles = np.concatenate(
            [
                padded[:, :, rows[row] : rows[row] + tile_h, cols[col] : cols[col] + tile_w]
                for row, col in chunk
            ]
        )
        outputs = backend(tiles)
        for index, (row, col) in enumerate(chunk):
            top, left = rows[row], cols[col]
            weight = np.outer(row_ramps[row], col_ramps[col])
            part = outputs[index * n : (index + 1) * n]
            total[:, :, top : top + tile_h, left : left + tile_w] += part * weight
            weights[top : top + tile_h, left : left + tile_w] += weight
    return np.asarray(total / weights, dtype=np.float32)[:, :, :height, :width]


def run_backend(
    backend: Backend, batch: np.ndarray, tile: int | None = None, overlap: int = DEFAULT_OVERLAP
) -> np.ndarray:
    """Restore a batch whole, or tiled when ``tile`` is set or the model has a fixed size.

    Args:
        backend: the network.
        batch: ``(N, C, H, W)`` float32 in [0, 1], ``H, W >= 8``.
        tile: square tile side (pixels, >= 16; cut to a shorter side), or None
            for whole images. A model of a fixed size runs other sizes on tiles
            of its size, and says so once
            (:class:`~lenspair.model.inference.backends.ForcedTiles`).
        overlap: pixels shared by neighbouring tiles.

    Raises:
        ModelError: a tile below 16 px, or the batch's channels differ from
            the network's.
    """
    if batch.shape[1] != backend.channels:
        raise ModelError(
            f"the network takes {backend.channels} channel(s), the images have {batch.shape[1]}"
        )
    check_tile(tile)
    height, width = batch.shape[2:]
    fixed = backend.fixed_size
    if fixed is not None:
        if (height, width) == fixed:
            return backend(batch)
        forced = backend.forced_tiles
        if forced is not None:
            forced.note((height, width))
        return run_tiled(backend, batch, fixed, overlap)
    if tile is None or (height <= tile and width <= tile):
        return backend(batch)
    return run_tiled(backend, batch, (min(tile, height), min(tile, width)), overlap)


def restore_images(
    backend: Backend,
    images: Sequence[np.ndarray],
    bits: int = 16,
    tile: int | None = None,
    overlap: int = DEFAULT_OVERLAP,
) -> list[np.ndarray]:
    """Run ``backend`` on same-shape, same-dtype integer frames; the restored frames, alike.

    Args:
        backend: the network.
        images: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)`` frames of the
            network's channels, ``H, W >= 8``.
        bits: the bits 16-bit frames use (10, 12 or 16); see
            :mod:`lenspair.core.bitdepth`.
        tile: square tile side, or None for whole frames.
        overlap: pixels shared by neighbouring tiles.
    """
    first = images[0]
    try:
        wide = [widen(image, bits) for image in images]
        restored = run_backend(backend, to_batch(wide), tile, overlap)
        return [narrow(image, bits) for image in from_batch(restored, first.dtype, first.ndim == 2)]
    except MemoryError:  # numpy's copies of the frames: a ModelError, as the network's
        height, width = first.shape[:2]
        raise memory_error(backend.description, height, width, "this machine") from None
