"""Out-of-focus glass: blur the glass layer by averaging random shifts.

The paper's method: the drop layer (premultiplied colours *and* coverage,
shifted together) is averaged over ``shifts`` random sub-pixel offsets drawn
uniformly in a disk of radius ``shift_px``, then composited over the clean
image. Averaging shifted copies with bilinear interpolation is a linear
filter, so it is applied as one correlation kernel: each shift splats its
four bilinear weights into the kernel. An optional thin-lens disk blur
(``disk_radius_px``) is folded into the same kernel. The kernel's *reach*
(the largest distance of a non-zero tap from its centre: largest shift plus
the interpolation margin plus the disk radius) is how far the footprint of
the glass grows.
"""

import math

import cv2
import numpy as np

from lenspair.simulate.effects.spec import DefocusSpec


def sample_shifts(spec: DefocusSpec, rng: np.random.Generator) -> np.ndarray:
    """``float64`` ``(shifts, 2)`` offsets ``(dx, dy)`` uniform in a disk of the shift radius.

    The radius is the thin-lens blur radius of the glass unless ``shift_px``
    sets it (:class:`~lenspair.simulate.effects.spec.DefocusSpec`).
    """
    radius = spec.shift_radius_px * np.sqrt(rng.random(spec.shifts))
    angle = rng.uniform(0.0, 2 * math.pi, spec.shifts)
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


def disk_kernel(radius: float) -> np.ndarray:
    """Anti-aliased disk of ``radius`` pixels, ``float32``, sums to 1 (``[[1]]`` for 0)."""
    half = math.ceil(radius + 0.5) if radius > 0 else 0
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    distance = np.hypot(offsets[:, None], offsets[None, :])
    weights = np.clip(radius + 0.5 - distance, 0.0, 1.0)
    disk: np.ndarray = (weights / weights.sum()).astype(np.float32)
    return disk


def blur_kernel(shifts: np.ndarray, disk_radius_px: float) -> np.ndarray:
    """Correlation kernel of "average the layer shifted by each shift, then disk blur".

    ``cv2.filter2D(layer, -1, kernel)`` equals ``mean_k layer(p - shift_k)``
    (bilinear) convolved with the disk.

    Args:
        shifts: ``(K, 2)`` offsets ``(dx, dy)``, pixels.
        disk_radius_px: thin-lens disk radius, pixels (0 = none).

    Returns:
        ``float32`` ``(2h + 1, 2h + 1)``, non-negative, sums to 1, ``h`` the
        largest offset of a tap that is not zero (``[[1]]`` for no shift).

    """
    half = math.ceil(float(np.abs(shifts).max(initial=0.0))) + 1
    kernel: np.ndarray = np.zeros((2 * half + 1, 2 * half + 1), np.float64)
    for dx, dy in shifts:
        # layer(p - s) is read at kernel offset -s.
        fx, fy = -dx, -dy
        x0, y0 = math.floor(fx), math.floor(fy)
        wx, wy = fx - x0, fy - y0
        for oy, weight_y in ((y0, 1.0 - wy), (y0 + 1, wy)):
            for ox, weight_x in ((x0, 1.0 - wx), (x0 + 1, wx)):
                kernel[oy + half, ox + half] += weight_x * weight_y / len(shifts)
    disk = disk_kernel(disk_radius_px).astype(np.float64)
    if disk.shape[0] > 1:
        grow = disk.shape[0] // 2
        padded = np.pad(kernel, grow)
        kernel = cv2.filter2D(padded, -1, disk, borderType=cv2.BORDER_CONSTANT)
    kernel = np.where(kernel > 1e-9, kernel, 0.0)
    # cut to the taps that are not zero: a zero shift is [[1]], so a declared blur of
    # nothing pads the drops by nothing and renders as no defocus (the pad reached into
    # the rim colour of drops on the frame border)
    centre = kernel.shape[0] // 2
    rows, cols = np.nonzero(kernel)
    reach = int(max(np.abs(rows - centre).max(), np.abs(cols - centre).max()))
    kernel = kernel[centre - reach : centre + reach + 1, centre - reach : centre + reach + 1]
    normalised: np.ndarray = (kernel / kernel.sum()).astype(np.float32)
    return normalised


def kernel_reach(kernel: np.ndarray) -> float:
    """Largest distance from the centre of a non-zero tap, pixels."""
    half = kernel.shape[0] // 2
    rows, cols = np.nonzero(kernel)
    return float(np.hypot(rows - half, cols - half).max(initial=0.0))


def grow_element(reach: float) -> np.ndarray:
    """``uint8`` disk structuring element holding every offset within ``reach``."""
    half = math.ceil(reach)
    offsets = np.arange(-half, half + 1)
    inside = offsets[:, None] ** 2 + offsets[None, :] ** 2 <= reach * reach + 1e-6
    return inside.astype(np.uint8)


def blur_layer(
    canvas: np.ndarray, margin: int, boxes: np.ndarray, kernel: np.ndarray
) -> np.ndarray:
    """Filter the glass layer with ``kernel``, only where it can be non-zero.

    Args:
        canvas: ``float32`` ``(H + 2m, W + 2m, C + 1)`` sharp premultiplied
            layer, zero outside the boxes; ``m = margin >= 2 * half``.
        margin: canvas margin ``m``, pixels.
        boxes: ``int64`` ``(N, 4)`` sprite boxes ``(y0, y1, x0, x1)`` in
            image coordinates, within ``half`` of the image.
        kernel: ``(2 half + 1)^2`` correlation kernel.

    Returns:
        ``float32`` ``(H, W, C + 1)`` blurred layer on the image pixels.

    """
    half = kernel.shape[0] // 2
    height = canvas.shape[0] - 2 * margin
    width = canvas.shape[1] - 2 * margin
    blurred = np.zeros((height, width, canvas.shape[2]), np.float32)
    regions = np.empty_like(boxes)
    regions[:, 0] = np.clip(boxes[:, 0] - half, 0, height)
    regions[:, 1] = np.clip(boxes[:, 1] + half, 0, height)
    regions[:, 2] = np.clip(boxes[:, 2] - half, 0, width)
    regions[:, 3] = np.clip(boxes[:, 3] + half, 0, width)
    area = np.maximum(regions[:, 1] - regions[:, 0], 0) * np.maximum(
        regions[:, 3] - regions[:, 2], 0
    )
    if area.sum() > height * width // 2:  # cheaper to filter the whole frame once
        regions = np.array([[0, height, 0, width]], np.int64)
    for y0, y1, x0, x1 in regions.tolist():
        if y1 <= y0 or x1 <= x0:
            continue
        source = canvas[
            y0 + margin - half : y1 + margin + half, x0 + margin - half : x1 + margin + half
        ]
        filtered = cv2.filter2D(source, -1, kernel, borderType=cv2.BORDER_CONSTANT)
        blurred[y0:y1, x0:x1] = filtered[half : half + y1 - y0, half : half + x1 - x0]
    return blurred
