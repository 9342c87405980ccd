"""Raindrops on the glass as small spherical-cap lenses.

Optical model (image-space approximation of a ray trace):

* The glass is a thin plate at the lens, normal to the optical axis; a drop
  sits on its outer side. Its footprint is an ellipse (semi-axes ``A >= B``
  pixels, orientation ``phi``); its surface is a spherical cap with contact
  angle ``theta_c``, stretched to the ellipse: in normalised footprint
  coordinates ``(u, v)`` (``rho^2 = u^2 + v^2 <= 1``) the outward surface
  normal is proportional to ``(m s u / A, m s v / B, sqrt(1 - s^2 rho^2))``
  with ``s = sin(theta_c)`` and ``m = sqrt(A B)``; for a round drop this is
  exactly the unit normal of a cap whose rim meets the glass at
  ``theta_c``. No division by the cap radius, so flat drops
  (``theta_c = 0``) and hemispheres (``theta_c = 90°``, tangent rim) are safe.
* The viewing ray of pixel ``p`` (pinhole, focal ``f``, principal point at
  the image centre) enters the water through the flat glass (Snell: the
  tangential component shrinks by ``1/n``) and leaves through the cap
  (vector Snell law, :func:`exit_refraction`). Rays past the critical angle
  ``asin(1/n)`` are totally internally reflected: they are masked
  explicitly and carry no scene light.
* The scene is far compared with the drop, so the refracted ray sees the
  clean-image pixel ``q = c + f (t_x, t_y) / t_z`` (parallax between the ray's
  origin on the drop and the camera centre is neglected). A drop is a strong
  converging lens, so ``q`` runs opposite to ``p``: the drop shows a flipped,
  minified view of the scene around it. The scene beyond the image border is
  mirrored.
* Each drop pixel's colour is ``T L(q) + (1 - T) rim``: ``T`` is the Fresnel
  transmittance of the exit surface (0 under total internal reflection, so
  the dark rim fades in smoothly), ``rim = rim_brightness`` times the drop's
  mean transmitted colour is the light bouncing inside the drop.
* Minified views are sampled from a Gaussian pyramid level chosen per drop
  from the lens's minification at its centre, so they do not alias.
* Coverage is the ellipse with a one-pixel anti-aliased edge, scaled by the
  footprint area for sub-pixel drops (a drop of radius 0 covers nothing).
  With ``refractive_index == 1`` the drops are optically absent: no
  coverage, no footprint, the image is untouched.

Geometry and optics depend only on the glass (sampled once per recording);
:func:`shade` is the only per-frame work.
"""

import math
from dataclasses import dataclass

import cv2
import numpy as np

from lenspair.simulate.effects.layer import Sprites, box_grid, clip_boxes
from lenspair.simulate.effects.spec import RaindropsSpec

MAX_LEVEL = 5
"""Deepest pyramid level a drop samples from (1/32 resolution)."""

_MIN_EXIT_Z = 0.05  # rays leaving closer than ~87° to the axis are clamped there


@dataclass(frozen=True, eq=False)
class Drops:
    """Geometry of the drops on the glass, image pixels.

    Attributes:
        centers: ``float64`` ``(N, 2)`` footprint centres ``(x, y)``.
        semi_axes: ``float64`` ``(N, 2)`` ``(major, minor)`` semi-axes, >= 0.
        angles: ``float64`` ``(N,)`` orientation of the major axis, radians.
        contact_angles: ``float64`` ``(N,)`` radians in ``[0, pi/2]``.

    """

    centers: np.ndarray
    semi_axes: np.ndarray
    angles: np.ndarray
    contact_angles: np.ndarray

    @property
    def count(self) -> int:
        """Number of drops."""
        return int(self.centers.shape[0])

    def select(self, keep: np.ndarray, other: "Drops") -> "Drops":
        """Drops from ``self`` where ``keep`` is true, else from ``other``."""
        return Drops(
            centers=np.where(keep[:, None], self.centers, other.centers),
            semi_axes=np.where(keep[:, None], self.semi_axes, other.semi_axes),
            angles=np.where(keep, self.angles, other.angles),
            contact_angles=np.where(keep, self.contact_angles, other.contact_angles),
        )


@dataclass(frozen=True, eq=False)
class DropOptics:
    """Per-pixel optics of the drops, precomputed from their geometry.

    Attributes:
        sprites: the pixels the drops cover, with anti-aliased coverage.
        source: ``float32`` ``(M, 2)`` clean-image position ``q = (x, y)``
            each pixel sees through its drop, pixels.
        transmittance: ``float32`` ``(M,)`` Fresnel transmittance in
            ``[0, 1]``; exactly 0 where the ray is totally internally reflected.
        tir: ``bool`` ``(M,)`` rays past the critical angle.
        levels: ``int64`` ``(N,)`` pyramid level each drop samples from.
        lookups: per pyramid level, ``(level, pixels, map_x, map_y)``: the
            pixel indices sampling that level and their ``float32`` ``(1, K)``
            source coordinates at that level's resolution, for ``cv2.remap``.

    """

    sprites: Sprites
    source: np.ndarray
    transmittance: np.ndarray
    tir: np.ndarray
    levels: np.ndarray
    lookups: tuple[tuple[int, np.ndarray, np.ndarray, np.ndarray], ...]


def sample_drops(spec: RaindropsSpec, shape: tuple[int, int], rng: np.random.Generator) -> Drops:
    """Draw ``spec.count`` drops uniformly over an image of ``shape`` = (H, W).

    Centres are uniform over the image, so drops near the border are cut.
    Radii follow ``spec.size_distribution`` (:func:`sample_radii`).
    """
    height, width = shape
    count = spec.count
    x = rng.uniform(-0.5, width - 0.5, count)
    y = rng.uniform(-0.5, height - 0.5, count)
    major = sample_radii(spec, rng.random(count))
    minor = major * rng.uniform(*spec.aspect, count)
    angles = rng.uniform(0.0, math.pi, count)
    contact = np.deg2rad(rng.uniform(*spec.contact_angle_deg, count))
    return Drops(np.stack([x, y], 1), np.stack([major, minor], 1), angles, contact)


def sample_radii(spec: RaindropsSpec, uniform: np.ndarray) -> np.ndarray:
    """Drop radii from uniform variates by inverting the size distribution's CDF.

    Args:
        spec: ``radius_px = (r0, r1)``, ``size_distribution``, ``size_exponent``.
        uniform: ``float64`` ``(N,)`` variates in ``[0, 1)``.

    Returns:
        ``float64`` ``(N,)`` radii in ``[r0, r1]``: uniform, or with density
        ``~ r^-k`` (``k = size_exponent``): many small drops, few large ones.

    """
    low, high = spec.radius_px
    if spec.size_distribution == "uniform" or high <= low:
        uniform_radii: np.ndarray = low + (high - low) * uniform
        return uniform_radii
    k = spec.size_exponent  # low > 0: the spec refuses power-law sizes from 0
    if abs(k - 1.0) < 1e-9:
        radii: np.ndarray = low * (high / low) ** uniform
        return radii
    a, b = low ** (1.0 - k), high ** (1.0 - k)
    radii = np.clip((a + (b - a) * uniform) ** (1.0 / (1.0 - k)), low, high)
    return radii


def exit_refraction(
    incident: np.ndarray, normal: np.ndarray, refractive_index: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refract rays leaving water (index ``n``) into air, with Fresnel loss.

    Args:
        incident: ``float32`` ``(..., 3)`` unit ray directions inside the drop.
        normal: ``float32`` ``(..., 3)`` unit outward surface normals.
        refractive_index: ``n >= 1`` of the drop relative to air.

    Returns:
        ``(transmitted, transmittance, tir)``: unit directions in air
        ``(..., 3)`` (the incident direction where no ray leaves),
        unpolarised Fresnel transmittance ``(...)`` in ``[0, 1]`` (0 where no
        ray leaves), and the mask of rays that cannot leave: past the
        critical angle ``asin(1/n)``, tangent, or hitting the surface from
        outside. Always finite.

    """
    incident = np.asarray(incident, np.float32)
    normal = np.asarray(normal, np.float32)
    *transmitted, transmittance, tir = _refract(
        (incident[..., 0], incident[..., 1], incident[..., 2]),
        (normal[..., 0], normal[..., 1], normal[..., 2]),
        refractive_index,
    )
    return np.stack(transmitted, axis=-1), transmittance, tir


_Vector = tuple[np.ndarray, np.ndarray, np.ndarray]


def _refract(
    incident: _Vector, normal: _Vector, refractive_index: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`exit_refraction` on vector components (faster than ``(..., 3)`` arrays)."""
    n = np.float32(refractive_index)
    ix, iy, iz = incident
    nx, ny, nz = normal
    cos_i = np.clip(ix * nx + iy * ny + iz * nz, 0.0, 1.0)
    sin2_t = n * n * (1.0 - cos_i * cos_i)
    tir = (sin2_t >= 1.0) | (cos_i <= 0.0)
    cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, 1.0))
    bend = cos_t - n * cos_i
    tx = np.where(tir, ix, n * ix + bend * nx)
    ty = np.where(tir, iy, n * iy + bend * ny)
    tz = np.where(tir, iz, n * iz + bend * nz)
    length = np.maximum(np.sqrt(tx * tx + ty * ty + tz * tz), np.float32(1e-12))
    tiny = np.float32(1e-12)
    r_s = (n * cos_i - cos_t) / np.maximum(n * cos_i + cos_t, tiny)
    r_p = (cos_i - n * cos_t) / np.maximum(cos_i + n * cos_t, tiny)
    transmittance = np.clip(1.0 - 0.5 * (r_s * r_s + r_p * r_p), 0.0, 1.0)
    transmittance = np.where(tir, np.float32(0.0), transmittance).astype(np.float32)
    return (
        (tx / length).astype(np.float32),
        (ty / length).astype(np.float32),
        (tz / length).astype(np.float32),
        transmittance,
        tir,
    )


def rasterize(drops: Drops, spec: RaindropsSpec, shape: tuple[int, int], pad: int) -> DropOptics:
    """Coverage and refraction of every drop pixel.

    Args:
        drops: drop geometry.
        spec: the raindrops spec (refractive index, focal length).
        shape: image ``(H, W)``.
        pad: boxes may reach this far beyond the image (the defocus reach).

    Returns:
        The optics of the covered pixels (none when ``refractive_index == 1``).

    """
    height, width = shape
    n = spec.refractive_index
    major = np.maximum(drops.semi_axes[:, 0], 1e-3)
    minor = np.maximum(drops.semi_axes[:, 1], 1e-3)
    cos_a, sin_a = np.cos(drops.angles), np.sin(drops.angles)
    extent_x = np.hypot(major * cos_a, minor * sin_a) + 1.0
    extent_y = np.hypot(major * sin_a, minor * cos_a) + 1.0
    cx, cy = drops.centers[:, 0], drops.centers[:, 1]
    boxes = clip_boxes(cx, cy, extent_x, extent_y, shape, pad)
    ys_all, xs_all, owner = box_grid(boxes)

    def per_pixel(values: np.ndarray) -> np.ndarray:
        gathered: np.ndarray = values.astype(np.float32)[owner]
        return gathered

    a, b = per_pixel(major), per_pixel(minor)
    c, s = per_pixel(cos_a), per_pixel(sin_a)
    xs, ys = xs_all.astype(np.float32), ys_all.astype(np.float32)
    dx, dy = xs - per_pixel(cx), ys - per_pixel(cy)
    u = (dx * c + dy * s) / a
    v = (dy * c - dx * s) / b
    rho2 = u * u + v * v
    # Distance to the outline along the ray from the centre, pixels (exact for
    # circles): (1 - rho) times the ellipse's radius in this direction.
    off_centre = rho2 > 1e-12
    inverse_radius2 = np.where(
        off_centre, ((u / a) ** 2 + (v / b) ** 2) / np.where(off_centre, rho2, 1.0), 1.0 / a**2
    )
    distance = (1.0 - np.sqrt(rho2)) / np.sqrt(inverse_radius2)
    # footprint area from the drawn axes, not the clamped ones: radius 0 covers nothing
    area = math.pi * drops.semi_axes[:, 0] * drops.semi_axes[:, 1]
    subpixel = np.minimum(1.0, area).astype(np.float32)[owner]
    alpha = np.clip(distance + 0.5, 0.0, 1.0) * subpixel
    covered = alpha > 0 if n != 1.0 else np.zeros(alpha.shape, bool)  # n = 1: optically absent
    sprites = Sprites(boxes, ys_all, xs_all, owner, alpha.astype(np.float32)).keep(covered)
    u, v, rho2, xs, ys = u[covered], v[covered], rho2[covered], xs[covered], ys[covered]
    a, b, c, s = a[covered], b[covered], c[covered], s[covered]

    sin_c = np.sin(drops.contact_angles).astype(np.float32)[sprites.owner]
    height_scale = np.sqrt(a * b)
    normal_u = height_scale * sin_c * u / a
    normal_v = height_scale * sin_c * v / b
    normal_z = np.sqrt(np.clip(1.0 - sin_c * sin_c * np.minimum(rho2, 1.0), 0.0, 1.0))
    normal_x = normal_u * c - normal_v * s
    normal_y = normal_u * s + normal_v * c
    length = np.maximum(np.sqrt(normal_x**2 + normal_y**2 + normal_z**2), np.float32(1e-12))
    normal = (normal_x / length, normal_y / length, normal_z / length)

    # Camera ray through the pixel, then through the flat glass into the water.
    focal = np.float32(spec.optics_focal_px)
    centre_x, centre_y = np.float32((width - 1) / 2), np.float32((height - 1) / 2)
    ray_x, ray_y = (xs - centre_x) / focal, (ys - centre_y) / focal
    scale = 1.0 / (np.sqrt(ray_x * ray_x + ray_y * ray_y + 1.0) * np.float32(n))
    inside_x, inside_y = ray_x * scale, ray_y * scale
    inside_z = np.sqrt(np.clip(1.0 - inside_x**2 - inside_y**2, 0.0, 1.0))
    exit_x, exit_y, exit_z, transmittance, tir = _refract((inside_x, inside_y, inside_z), normal, n)
    exit_z = np.maximum(exit_z, np.float32(_MIN_EXIT_Z))
    source_x = np.clip(centre_x + focal * exit_x / exit_z, -width, 2 * width - 1)
    source_y = np.clip(centre_y + focal * exit_y / exit_z, -height, 2 * height - 1)

    # Minification at the centre of the lens: q - p ~ -f (n - 1) * normal tilt.
    power = spec.optics_focal_px * (n - 1.0) * np.sqrt(major * minor) * np.sin(drops.contact_angles)
    minification = np.sqrt(np.abs(1 - power / major**2) * np.abs(1 - power / minor**2))
    levels = np.clip(np.round(np.log2(np.maximum(minification, 1.0))), 0, MAX_LEVEL)
    levels = levels.astype(np.int64)
    pixel_levels = levels[sprites.owner]
    lookups = []
    for level in np.unique(pixel_levels).tolist():
        pixels = np.flatnonzero(pixel_levels == level)
        shrink = np.float32(2.0**-level)
        map_x = (source_x[pixels] * shrink).astype(np.float32).reshape(1, -1)
        map_y = (source_y[pixels] * shrink).astype(np.float32).reshape(1, -1)
        lookups.append((int(level), pixels, map_x, map_y))
    return DropOptics(
        sprites=sprites,
        source=np.stack([source_x, source_y], -1).astype(np.float32),
        transmittance=transmittance,
        tir=tir,
        levels=levels,
        lookups=tuple(lookups),
    )


def _pyramid(linear: np.ndarray, depth: int) -> list[np.ndarray]:
    levels = [linear]
    for _ in range(depth):
        if min(levels[-1].shape[:2]) < 2:
            levels.append(levels[-1])
        else:
            levels.append(cv2.pyrDown(levels[-1]))
    return levels


_REMAP_WIDTH = 4096
"""Row length for point lookups: cv2.remap refuses maps of 32767 or more columns."""


def _remap_points(image: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at the ``(N,)`` float32 points ``xs``, ``ys``.

    The points are laid out as rows of at most :data:`_REMAP_WIDTH` so that any
    number of drop pixels (large drops on large images) stays within OpenCV's
    map size limit. Returns ``(N,)`` or ``(N, C)`` like one row of ``image``.
    """
    count = xs.shape[0]
    rows = -(-count // _REMAP_WIDTH)
    padded = rows * _REMAP_WIDTH
    map_x = np.zeros(padded, np.float32)
    map_y = np.zeros(padded, np.float32)
    map_x[:count], map_y[:count] = xs, ys
    values = cv2.remap(
        image,
        map_x.reshape(rows, _REMAP_WIDTH),
        map_y.reshape(rows, _REMAP_WIDTH),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REFLECT_101,
    )
    flat: np.ndarray = values.reshape(padded, *values.shape[2:])[:count]
    return flat


def shade(linear: np.ndarray, optics: DropOptics, rim_brightness: float) -> np.ndarray:
    """Colour each drop pixel sees: refracted scene, Fresnel loss and dark rim.

    Args:
        linear: ``float32`` ``(H, W, C)`` clean image in linear light.
        optics: from :func:`rasterize`.
        rim_brightness: see :class:`RaindropsSpec`.

    Returns:
        ``float32`` ``(M, C)`` colours, not premultiplied.

    """
    channels = linear.shape[2]
    total = optics.sprites.alpha.shape[0]
    sampled = np.empty((total, channels), np.float32)
    if total == 0:
        return sampled
    depth = max(level for level, _, _, _ in optics.lookups)
    pyramid = _pyramid(linear[..., 0] if channels == 1 else linear, depth)
    for level, pixels, map_x, map_y in optics.lookups:
        values = _remap_points(pyramid[level], map_x.ravel(), map_y.ravel())
        sampled[pixels] = values.reshape(-1, channels)
    owner = optics.sprites.owner
    transmittance = optics.transmittance
    weight = transmittance * optics.sprites.alpha
    count = optics.sprites.count
    weight_sum = np.maximum(np.bincount(owner, weights=weight, minlength=count), 1e-12)
    rim = np.empty((count, channels), np.float32)
    for k in range(channels):
        rim[:, k] = np.bincount(owner, weights=weight * sampled[:, k], minlength=count) / weight_sum
    rim *= np.float32(rim_brightness)
    colour: np.ndarray = rim[owner]
    colour += transmittance[:, None] * (sampled - colour)
    return colour
