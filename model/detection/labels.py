"""Labels for the detector: kinds, tile maps from masks and from registered pairs.

Tile truth (:func:`tile_truth`): a footprint mask (``uint8``/bool ``(H, W)``,
non-zero = covered) is area-averaged onto the detector's tile grid; a tile is
*covered* when at least ``min_fraction`` (10 %) of its pixels are.

Pair rule (:func:`pair_anomaly_mask`), for ingested pairs without a truth mask:
the obstructed view ``I`` and the registered clean view ``C`` are turned into
linear-light luma; the clean view is gain-compensated by the median of
``I / C`` over trustworthy pixels (cameras differ in exposure); the relative
difference ``|I - g C| / (g C + 0.02)`` is blurred with a Gaussian of
``sigma_px`` (3 px: registration residuals of a pixel or two must not count)
and thresholded at ``threshold`` (0.12: 12 % brighter or darker than the clean
view, well above sensor noise and below the attenuation of light dust).
Untrustworthy pixels (``mask/``) are never covered, and tiles made mostly of
them are excluded from the map loss and from tile IoU (:func:`tile_valid`).
"""

from collections.abc import Sequence

import cv2
import numpy as np

from lenspair.core.pixels import check_image, to_float, to_linear
from lenspair.model.networks.detector import KINDS

KIND_ALIASES: dict[str, str] = {"raindrops": "rain", "drops": "rain", "smudge": "dirt"}
"""Other spellings of anomaly labels found in ``rig.yaml`` files."""


def kind_index(labels: Sequence[str]) -> int | None:
    """Index into :data:`KINDS` of a recording's anomaly labels.

    The first label that names a known kind wins; no label means ``clean``
    (a simulated recording's ``rig.yaml`` lists none when its glass changed
    nothing). Returns None when labels exist but none is known (the kind is
    then not trained on, only the obstructed/clean answer and the map). A
    dataset pair is obstructed or clean by its difficulty, whatever its
    labels: :func:`lenspair.model.detection.data.dataset_kind`.
    """
    if not labels:
        return 0
    for label in labels:
        name = KIND_ALIASES.get(label.lower(), label.lower())
        if name in KINDS:
            return KINDS.index(name)
    return None


def to_luma(image: np.ndarray) -> np.ndarray:
    """Encoded luma of an image: ``float32`` ``(H, W)`` in ``[0, 1]`` (sRGB weights)."""
    check_image(image)
    values = to_float(image)
    if values.ndim == 3:
        values = values @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    return np.ascontiguousarray(values, dtype=np.float32)


def tile_fractions(mask: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """Covered fraction of each tile: ``float32`` ``(rows, cols)`` in ``[0, 1]``.

    The mask is padded at the bottom/right to a whole number of tiles (the
    network pads its convolutions the same way) before area averaging.
    """
    rows, cols = grid
    covered = (np.asarray(mask) > 0).astype(np.float32)
    height, width = covered.shape
    tile_h, tile_w = -(-height // rows), -(-width // cols)
    padded = np.zeros((rows * tile_h, cols * tile_w), np.float32)
    padded[:height, :width] = covered
    fractions: np.ndarray = padded.reshape(rows, tile_h, cols, tile_w).mean(axis=(1, 3))
    return fractions


def tile_truth(mask: np.ndarray, grid: tuple[int, int], min_fraction: float = 0.1) -> np.ndarray:
    """Covered tiles: ``bool`` ``(rows, cols)``, fraction of covered pixels >= ``min_fraction``."""
    return tile_fractions(mask, grid) >= min_fraction


def tile_valid(untrusted: np.ndarray | None, grid: tuple[int, int]) -> np.ndarray:
    """Tiles that count: ``bool`` ``(rows, cols)``, fewer than half their pixels untrusted."""
    if untrusted is None:
        return np.ones(grid, dtype=bool)
    return tile_fractions(untrusted, grid) < 0.5


def pair_anomaly_mask(
    obstructed: np.ndarray,
    clean: np.ndarray,
    untrusted: np.ndarray | None = None,
    *,
    sigma_px: float = 3.0,
    threshold: float = 0.12,
    compensate_gain: bool = True,
) -> np.ndarray:
    """Where a registered pair differs: the module docstring's rule.

    Args:
        obstructed: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)``, the input view.
        clean: the clean view registered onto it, same shape.
        untrusted: optional ``(H, W)``, non-zero where the pair is not trustworthy.
        sigma_px: Gaussian blur of the relative difference, pixels.
        threshold: relative difference above which a pixel is covered.
        compensate_gain: scale the clean view by the median ratio first (two
            cameras differ in exposure); False when both views share one
            exposure (a render over the clean view, the simulator's
            ``truth/clear``), so that a frame-wide darkening counts.

    Returns:
        ``bool`` ``(H, W)``, True where the glass is judged covered.

    Raises:
        ValueError: shapes differ or break the image convention.
    """
    if obstructed.shape[:2] != clean.shape[:2]:
        raise ValueError(f"pair: shapes differ, {obstructed.shape} and {clean.shape}")
    seen = to_linear(to_luma(obstructed))
    reference = to_linear(to_luma(clean))
    trusted = np.ones(seen.shape, bool) if untrusted is None else np.asarray(untrusted) == 0
    usable = trusted & (reference > 0.01)
    gain = 1.0
    if compensate_gain and usable.any():
        gain = float(np.median(seen[usable] / reference[usable]))
    relative = np.abs(seen - gain * reference) / (gain * reference + 0.02)
    blurred = cv2.GaussianBlur(relative.astype(np.float32), (0, 0), sigma_px)
    covered: np.ndarray = (blurred > threshold) & trusted
    return covered
