"""Checking the declared obstructed camera against the images.

Raindrops, dust and dirt on the glass blur and attenuate what lies behind
them, so the obstructed view has less high-frequency detail where anomalies
sit. Both views of a frame pair are cut into the same grid of tiles; in each
tile the energy of the Laplacian (mean squared response, after dividing the
image by its mean so that a gain or exposure difference between the cameras
cancels) is compared as ``r = log(E_cam1 / E_cam0)``, and the median of ``r``
over the frames is taken per tile. A tile votes for "cam0 obstructed" when
``r > log(ratio_threshold)`` (cam0 notably less detailed there), for "cam1"
when ``r < -log(ratio_threshold)``.

The side with the larger share of votes is inferred when that share reaches
``min_tile_fraction`` and outweighs the other side's share ``dominance``
times; otherwise the result is ``undetermined`` (identical views, views too
flat, or contradicting evidence). The check is a hint, not a verdict: dust,
dirt and defocused drops remove detail, but sharp, refracting drops add edges
(their rims), so heavy rain can leave the clean camera with less detail: on
the bundled ``heavy_rain`` scene it named the clean camera on 8 of 14 seeds,
up to confidence 0.52. Its messages say so, a mismatch is reported and never
fatal, and ``dataset-build`` refuses only on the detector's check
(:mod:`lenspair.capture.side_detector`). The raw (unrectified) views are used,
so the grid must be coarse compared with the disparity between the cameras.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from lenspair.capture.errors import CaptureError
from lenspair.capture.rigfile import CameraName
from lenspair.core.pixels import check_image, to_float

Inferred = Literal["cam0", "cam1", "undetermined"]


@dataclass(frozen=True)
class SideCheck:
    """Outcome of :func:`check_obstructed_side`.

    Attributes:
        declared: the camera ``rig.yaml`` or ``--obstructed`` names.
        inferred: the camera the images point to, or ``undetermined``.
        confidence: in ``[0, 1]``: how one-sided the tile votes are, times how
            many tiles vote (saturating at ``4 * min_tile_fraction``); 0 when
            undetermined.
        agrees: ``inferred == declared``; None when undetermined.
        mismatch: True when a side was inferred and it is not the declared one.
        lower_cam0: fraction of textured tiles where cam0 has notably less detail.
        lower_cam1: fraction of textured tiles where cam1 has notably less detail.
        num_frames: frame pairs compared.
        num_tiles: textured tiles that took part (of ``rows * cols``).
        message: one line for people and reports.
        method: ``detail``.
    """

    declared: CameraName
    inferred: Inferred
    confidence: float
    agrees: bool | None
    mismatch: bool
    lower_cam0: float
    lower_cam1: float
    num_frames: int
    num_tiles: int
    message: str
    method: str = "detail"


DETAIL_HINT = "a hint, not a check: drops can add detail; --detector checks the side"
"""What every verdict of the fine-detail check adds (see the module docstring)."""


def side_message(declared: CameraName, inferred: Inferred, shares: str) -> tuple[bool | None, str]:
    """Whether ``inferred`` agrees with ``declared`` (``None``: undetermined) and the sentence.

    Args:
        declared: the obstructed camera that ``rig.yaml`` (or ``--obstructed``) names.
        inferred: what the images say.
        shares: the figures the verdict rests on, put in brackets.
    """
    agrees = None if inferred == "undetermined" else inferred == declared
    if agrees is None:
        message = f"obstructed side undetermined ({shares}); declared {declared}"
    elif agrees:
        message = f"images agree that {declared} is obstructed ({shares})"
    else:
        message = (
            f"images suggest {inferred} is obstructed, but {declared} is declared ({shares}); "
            "check rig.yaml or --obstructed"
        )
    return agrees, message


def tile_detail(image: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """Laplacian energy per tile of a gain-normalised grey image.

    Args:
        image: ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)``, ``H, W >= 3``.
        grid: ``(rows, cols)`` of tiles.

    Returns:
        ``float64`` ``(rows, cols)``: mean squared 4-neighbour Laplacian of
        ``grey / mean(grey)`` in each tile (dimensionless, >= 0).
    """
    check_image(image)
    grey = to_float(image)
    if grey.ndim == 3:
        grey = grey.mean(axis=2)
    if min(grey.shape) < 3:
        raise ValueError(f"image: expected at least 3x3 pixels, got {grey.shape}")
    grey = grey.astype(np.float64) / max(float(grey.mean()), 1e-6)
    laplacian = (
        grey[1:-1, :-2] + grey[1:-1, 2:] + grey[:-2, 1:-1] + grey[2:, 1:-1] - 4 * grey[1:-1, 1:-1]
    )
    energy = laplacian**2
    rows, cols = grid
    row_edges = np.linspace(0, energy.shape[0], rows + 1).astype(int)
    col_edges = np.linspace(0, energy.shape[1], cols + 1).astype(int)
    detail = np.zeros((rows, cols))
    for i in range(rows):
        for j in range(cols):
            tile = energy[row_edges[i] : row_edges[i + 1], col_edges[j] : col_edges[j + 1]]
            detail[i, j] = float(tile.mean()) if tile.size else 0.0
    return detail


def check_obstructed_side(
    images_cam0: Sequence[np.ndarray],
    images_cam1: Sequence[np.ndarray],
    declared: CameraName,
    *,
    grid: tuple[int, int] = (6, 8),
    ratio_threshold: float = 1.5,
    min_tile_fraction: float = 0.05,
    dominance: float = 3.0,
    min_energy: float = 1e-6,
) -> SideCheck:
    """Infer which camera is obstructed and compare with the declared one.

    Args:
        images_cam0: cam0 views of a few frame pairs (same count as cam1),
            ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)``.
        images_cam1: the cam1 views of the same pairs.
        declared: the camera said to be obstructed.
        grid: ``(rows, cols)`` of tiles.
        ratio_threshold: detail ratio (> 1) that makes a tile vote.
        min_tile_fraction: smallest share of votes that decides a side.
        dominance: how many times the winning share must exceed the other.
        min_energy: tiles whose detail is below this in both views (flat sky,
            black borders) take no part.

    Returns:
        The :class:`SideCheck`.

    Raises:
        CaptureError: no frames, or different numbers of frames per camera.
        ValueError: an image breaks the :mod:`lenspair.core.pixels` convention.
    """
    if len(images_cam0) != len(images_cam1) or not images_cam0:
        raise CaptureError(
            "side check needs the same, non-zero number of frames per camera, "
            f"got {len(images_cam0)} and {len(images_cam1)}"
        )
    ratios = []
    for image0, image1 in zip(images_cam0, images_cam1, strict=True):
        detail0 = tile_detail(image0, grid)
        detail1 = tile_detail(image1, grid)
        ratio = np.log((detail1 + min_energy) / (detail0 + min_energy))
        textured = np.maximum(detail0, detail1) >= min_energy
        ratios.append(np.where(textured, ratio, np.nan))
    stacked = np.stack(ratios)
    valid = ~np.all(np.isnan(stacked), axis=0)
    num_tiles = int(valid.sum())
    threshold = float(np.log(ratio_threshold))
    if num_tiles:
        median = np.nanmedian(stacked[:, valid], axis=0)
        lower0 = float(np.mean(median > threshold))
        lower1 = float(np.mean(median < -threshold))
    else:
        lower0 = lower1 = 0.0
    high, low = max(lower0, lower1), min(lower0, lower1)
    inferred: Inferred = "undetermined"
    confidence = 0.0
    if high > 0 and high >= min_tile_fraction and high >= dominance * low:
        inferred = "cam0" if lower0 > lower1 else "cam1"
        saturation = min(1.0, high / (4 * min_tile_fraction))
        confidence = (high - low) / (high + low) * saturation
    shares = f"tiles with less detail: cam0 {lower0:.0%}, cam1 {lower1:.0%} of {num_tiles}"
    if inferred == "undetermined":
        agrees, message = side_message(declared, inferred, shares)
    else:  # never "images agree": the views differ, maybe the other way
        agrees = inferred == declared
        said = "as declared" if agrees else f"but {declared} is declared"
        message = f"fine detail is lower on {inferred}, {said} ({shares}); {DETAIL_HINT}"
    return SideCheck(
        declared=declared,
        inferred=inferred,
        confidence=round(confidence, 4),
        agrees=agrees,
        mismatch=agrees is False,
        lower_cam0=lower0,
        lower_cam1=lower1,
        num_frames=len(images_cam0),
        num_tiles=num_tiles,
        message=message,
    )
