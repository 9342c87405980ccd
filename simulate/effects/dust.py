"""Dust and smudges: low-frequency attenuation and scattering, ``I = I0 a + b``.

The dust's optical depth is a sum of smooth bumps with compact support,

    ``tau(x) = sum_k tau_k (1 - |x - c_k|^2 / r_k^2)^3``  for ``|x - c_k| < r_k``,

each twice continuously differentiable and exactly 0 outside its disc. The
transmission is ``a = exp(-tau)`` (Beer-Lambert, so overlapping patches
multiply) and the veil of light scattered towards the camera is
``b = scatter (1 - a)``. Outside the union of the discs ``a = 1`` and
``b = 0`` exactly: that union is the dust's footprint. The number of patches
is drawn from a Poisson law whose mean makes the expected covered fraction of
the image (``1 - exp(-N a / (H W))``, ``a`` a patch's mean area inside the
frame) equal ``coverage`` (capped at 0.99): :func:`patch_count`. Fine dust takes
many patches (50 % of a 1920x1080 frame under 4 px patches: 49,000), so they
are evaluated together, window by window, not one by one: an earlier cap of
4,096 patches silently covered half what was asked.
"""

import math
from dataclasses import dataclass

import numpy as np

from lenspair.simulate.effects.spec import DustSpec

_CHUNK_VALUES = 1 << 22
"""Patch-window pixels evaluated at once (memory: about 100 MB of temporaries)."""

_MAX_WINDOW_REACH = 64
"""Patches whose window reaches further go one by one, their windows cut to the frame
(a whole window of a patch far larger than the frame would not fit in memory)."""

_MIN_TRANSMISSION = 1e-4


@dataclass(frozen=True, eq=False)
class DustField:
    """The smooth dust fields of one glass, over the whole image.

    Attributes:
        transmission: ``float32`` ``(H, W)`` ``a`` in ``(0, 1]``, 1 outside the support.
        veil: ``float32`` ``(H, W)`` ``b`` in ``[0, scatter]``, 0 outside the support.
        support: ``bool`` ``(H, W)`` where the optical depth is positive.

    """

    transmission: np.ndarray
    veil: np.ndarray
    support: np.ndarray


def _mean_area_in_frame(scale_px: float, shape: tuple[int, int]) -> float:
    """Mean area of one patch inside the frame, pixels: its centre uniform over the frame.

    For a disc of radius ``r`` and a ``W x H`` frame this is
    ``(1 / WH) * integral over |d| < r of (W - |d_x|)+ (H - |d_y|)+``, averaged
    over ``r ~ U(0.5, 1) * scale_px`` (midpoint rule, 8 radii; the disc by a
    129 x 129 grid). It is ``pi r^2`` less the parts cut off at the frame's
    edges, and the frame's area for a patch much larger than the frame.
    """
    height, width = shape
    total = 0.0
    radii = scale_px * (0.5 + (np.arange(8) + 0.5) / 16.0)
    for radius in radii:
        half_x, half_y = min(radius, width), min(radius, height)
        xs = np.linspace(-half_x, half_x, 129)
        ys = np.linspace(-half_y, half_y, 129)
        inside = xs[None, :] ** 2 + ys[:, None] ** 2 < radius**2
        overlap = np.outer(
            np.maximum(height - np.abs(ys), 0.0), np.maximum(width - np.abs(xs), 0.0)
        )
        cell = (xs[1] - xs[0]) * (ys[1] - ys[0])
        total += float((overlap * inside).sum() * cell) / (height * width)
    return total / len(radii)


def patch_count(spec: DustSpec, shape: tuple[int, int], rng: np.random.Generator) -> int:
    """Number of patches: Poisson, so that on average ``coverage`` of the frame is covered.

    Patches are a Boolean model: a Poisson number with mean ``n`` of discs,
    each covering ``a`` of the frame's ``A`` pixels on average, leave a share
    ``exp(-n a / A)`` uncovered; ``n = -ln(1 - coverage) A / a``. ``a`` is the
    area inside the frame (:func:`_mean_area_in_frame`): a patch larger than
    the frame covers the frame, not its whole disc. A fixed count of at least
    one patch covered several times the share asked for where one patch is
    larger than that share (a small coverage, a small frame, a large scale).
    """
    if spec.coverage <= 0.0:
        return 0
    height, width = shape
    depth = -math.log(1.0 - min(spec.coverage, 0.99))
    expected = depth * height * width / _mean_area_in_frame(spec.scale_px, shape)
    return int(rng.poisson(expected))


def sample_dust(spec: DustSpec, shape: tuple[int, int], rng: np.random.Generator) -> DustField:
    """Draw dust patches and evaluate ``a`` and ``b`` over an image of ``shape``.

    Args:
        spec: the dust spec.
        shape: image ``(H, W)``.
        rng: random generator.

    Returns:
        The dust fields.

    """
    height, width = shape
    count = patch_count(spec, shape, rng)
    x = rng.uniform(-0.5, width - 0.5, count)
    y = rng.uniform(-0.5, height - 0.5, count)
    radii = spec.scale_px * rng.uniform(0.5, 1.0, count)
    lowest = max(spec.attenuation[0], _MIN_TRANSMISSION)
    depths = -np.log(rng.uniform(lowest, max(spec.attenuation[1], lowest), count))
    tau = _optical_depth(x, y, radii, depths, shape)
    support = tau > 0
    transmission = np.ones(shape, np.float32)
    transmission[support] = np.exp(-tau[support])
    veil = np.zeros(shape, np.float32)
    veil[support] = np.float32(spec.scatter) * (1.0 - transmission[support])
    return DustField(transmission=transmission, veil=veil, support=support)


def _optical_depth(
    x: np.ndarray, y: np.ndarray, radii: np.ndarray, depths: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """``tau``: the sum of every patch's bump, ``float32`` ``(H, W)``.

    Each patch is evaluated on the square window of pixels around its centre
    that holds its disc, all patches of a chunk at once, and the values are
    summed into the image with one ``bincount``; large patches (there are few)
    one by one, on the part of their window inside the frame.
    """
    height, width = shape
    tau = np.zeros(height * width, np.float64)
    if len(x) == 0:
        return tau.reshape(shape).astype(np.float32)
    reach = math.ceil(float(radii.max())) + 1  # floor(c) +- reach holds |p - c| < r
    if reach > _MAX_WINDOW_REACH:  # few, large patches: each on its window cut to the frame
        flat = tau.reshape(shape)
        for cx, cy, radius, depth in zip(x, y, radii, depths, strict=True):
            top, bottom = max(0, math.floor(cy - radius)), min(height, math.ceil(cy + radius) + 1)
            left, right = max(0, math.floor(cx - radius)), min(width, math.ceil(cx + radius) + 1)
            if bottom > top and right > left:
                dy2 = ((np.arange(top, bottom) - cy) ** 2)[:, None]
                dx2 = ((np.arange(left, right) - cx) ** 2)[None, :]
                inside = np.maximum(1.0 - (dy2 + dx2) / radius**2, 0.0)
                flat[top:bottom, left:right] += depth * inside**3
        return flat.astype(np.float32)
    offsets = np.arange(-reach, reach + 1)
    chunk = max(1, _CHUNK_VALUES // len(offsets) ** 2)
    for start in range(0, len(x), chunk):
        part = slice(start, start + chunk)
        cx, cy = x[part, None], y[part, None]
        radius, depth = radii[part, None, None], depths[part, None, None]
        rows = np.floor(cy).astype(np.int64) + offsets  # (n, k)
        cols = np.floor(cx).astype(np.int64) + offsets
        dy2 = ((rows - cy) ** 2)[:, :, None]
        dx2 = ((cols - cx) ** 2)[:, None, :]
        inside = np.maximum(1.0 - (dy2 + dx2) / radius**2, 0.0)
        bump = depth * inside**3
        keep = (
            (bump > 0)
            & ((rows >= 0) & (rows < height))[:, :, None]
            & ((cols >= 0) & (cols < width))[:, None, :]
        )
        index = rows[:, :, None] * width + cols[:, None, :]
        tau += np.bincount(index[keep], weights=bump[keep], minlength=height * width)
    return tau.reshape(shape).astype(np.float32)


def apply_dust(values: np.ndarray, transmission: np.ndarray, veil: np.ndarray) -> np.ndarray:
    """``I = I0 a + b`` on a list of pixels.

    Args:
        values: ``float32`` ``(M, C)`` linear light.
        transmission: ``float32`` ``(M,)`` ``a`` at those pixels.
        veil: ``float32`` ``(M,)`` ``b`` at those pixels.

    Returns:
        ``float32`` ``(M, C)``.

    """
    result: np.ndarray = (values * transmission[:, None] + veil[:, None]).astype(np.float32)
    return result
