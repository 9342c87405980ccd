"""Dirt on the glass: opaque and semi-transparent blobs with irregular outlines.

Each blob is a star-shaped region whose radius varies with the polar angle,
``r(theta) = R (1 + sum_k a_k cos(k theta + phase_k))`` for ``k = 2..5``
with ``sum a_k <= irregularity <= 0.6`` (so ``r >= 0.4 R > 0``). Its
coverage is ``opacity`` inside, falling smoothly to 0 over the outer quarter
of the radius (at least one pixel), and 0 outside ``r(theta)``: the blob's
support is exactly where its coverage is positive. The blob's colour is a
linear-light grey, composited over the glass layer.
"""

import math
from dataclasses import dataclass

import numpy as np

from lenspair.simulate.effects.layer import Sprites, box_grid, clip_boxes
from lenspair.simulate.effects.spec import DirtSpec

_HARMONICS = np.arange(2, 6)


@dataclass(frozen=True, eq=False)
class Blobs:
    """Geometry of the dirt blobs, image pixels.

    Attributes:
        centers: ``float64`` ``(N, 2)`` centres ``(x, y)``.
        radii: ``float64`` ``(N,)`` mean radius ``R`` >= 0.
        opacities: ``float64`` ``(N,)`` in ``[0, 1]``.
        amplitudes: ``float64`` ``(N, 4)`` outline harmonics ``a_2..a_5``.
        phases: ``float64`` ``(N, 4)`` their phases, radians.

    """

    centers: np.ndarray
    radii: np.ndarray
    opacities: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray

    @property
    def count(self) -> int:
        """Number of blobs."""
        return int(self.radii.shape[0])


def sample_blobs(spec: DirtSpec, shape: tuple[int, int], rng: np.random.Generator) -> Blobs:
    """Draw ``spec.count`` blobs uniformly over an image of ``shape`` = (H, W)."""
    height, width = shape
    count = spec.count
    x = rng.uniform(-0.5, width - 0.5, count)
    y = rng.uniform(-0.5, height - 0.5, count)
    radii = rng.uniform(*spec.radius_px, count)
    opacities = rng.uniform(*spec.opacity, count)
    weights = (1.0 / _HARMONICS) / np.sum(1.0 / _HARMONICS)
    amplitudes = spec.irregularity * rng.random((count, len(_HARMONICS))) * weights
    phases = rng.uniform(0.0, 2 * math.pi, (count, len(_HARMONICS)))
    return Blobs(np.stack([x, y], 1), radii, opacities, amplitudes, phases)


def rasterize(blobs: Blobs, shape: tuple[int, int], pad: int) -> Sprites:
    """Coverage of every blob inside its bounding box.

    Args:
        blobs: blob geometry.
        shape: image ``(H, W)``.
        pad: boxes may reach this far beyond the image (the defocus reach).

    Returns:
        Sprites with coverage in ``[0, opacity]``.

    """
    reach = blobs.radii * (1.0 + blobs.amplitudes.sum(axis=1)) + 1.0
    cx, cy = blobs.centers[:, 0], blobs.centers[:, 1]
    boxes = clip_boxes(cx, cy, reach, reach, shape, pad)
    ys, xs, owner = box_grid(boxes)
    dx = xs.astype(np.float32) - cx.astype(np.float32)[owner]
    dy = ys.astype(np.float32) - cy.astype(np.float32)[owner]
    distance = np.hypot(dx, dy)
    # sum_k a_k cos(k theta + phase_k) = Re(sum_k c_k z^k), z = e^(i theta), by Horner.
    z = np.where(distance > 0, (dx + 1j * dy) / np.maximum(distance, 1e-12), 1.0 + 0j)
    z = z.astype(np.complex64)
    coefficients = (blobs.amplitudes * np.exp(1j * blobs.phases)).astype(np.complex64)
    wiggle = np.zeros_like(z)
    for k in range(len(_HARMONICS) - 1, -1, -1):
        wiggle = (wiggle + coefficients[owner, k]) * z
    wiggle *= z  # lowest harmonic is 2
    radius = blobs.radii.astype(np.float32)[owner] * (1.0 + wiggle.real)
    width = np.maximum(0.25 * radius, 1.0)
    ramp = np.clip((radius - distance) / width, 0.0, 1.0)
    alpha = blobs.opacities.astype(np.float32)[owner] * ramp * ramp * (3.0 - 2.0 * ramp)
    sprites = Sprites(boxes, ys, xs, owner, alpha.astype(np.float32))
    return sprites.keep(sprites.alpha > 0)


def premultiplied(sprites: Sprites, color: float, channels: int) -> np.ndarray:
    """Colour times coverage of the blob pixels.

    Args:
        sprites: from :func:`rasterize`.
        color: linear-light grey level of the dirt.
        channels: 1 or 3.

    Returns:
        ``float32`` ``(M, channels)``.

    """
    value = sprites.alpha * np.float32(color)
    return np.repeat(value[:, None], channels, axis=1).astype(np.float32)
