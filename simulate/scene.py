"""Ray-cast rendering of textured planes, in linear light.

Each output pixel is covered by ``s x s`` samples whose rays come from a
:class:`~lenspair.simulate.camera.RayMap` (computed once per camera). A ray is
intersected with every plane in the world frame; the nearest positive hit
inside the plane's extent wins, and its texture is sampled trilinearly from
the texture's mip pyramid at a level matched to the sample's footprint on
the plane (finite differences of texture coordinates between neighbouring
samples). Samples are box-averaged into pixels. Samples that hit nothing see
a constant background.

Output images are ``float32`` linear light in ``[0, 1]`` (before gain),
``(H, W)`` for mono or ``(H, W, 3)`` for RGB; encoding and quantisation
happen once, later (:mod:`lenspair.simulate.recording`).
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lenspair.simulate.camera import RayMap
from lenspair.simulate.spec import PlaneSpec
from lenspair.simulate.textures import (
    Texture,
    build_texture,
    load_texture_image,
    mosaic,
    sample_texture,
    to_channels,
)
from lenspair.simulate.transforms import rotation_xyz_deg


@dataclass(frozen=True)
class Plane:
    """A textured plane in the world frame.

    Texture coordinate ``(x, y)`` (level-0 texels, centres at integers) of
    a world point ``X`` is ``x = (a_u . (X - centre) + anchor_u) / texel_u - 0.5``
    and likewise for ``y`` with ``a_v``; ``anchor`` is half the physical size
    of one texture copy, so the texture is centred on ``centre``.

    Attributes:
        centre: ``(3,)`` world point at the middle of the plane, metres.
        axis_u: ``(3,)`` unit vector along the texture's x axis.
        axis_v: ``(3,)`` unit vector along the texture's y axis (image down).
        size_m: ``(width, height)`` extent for a finite plane, ``None`` = infinite.
        texel_m: metres per level-0 texel, ``(x, y)``.
        texture: the mip pyramid (``tiled`` repeats it).
        brightness: linear-light multiplier.

    """

    centre: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    size_m: tuple[float, float] | None
    texel_m: tuple[float, float]
    texture: Texture
    brightness: float = 1.0

    @property
    def normal(self) -> np.ndarray:
        """Unit normal ``axis_u x axis_v``; points away from a viewer that sees the texture."""
        return np.asarray(np.cross(self.axis_u, self.axis_v))

    @property
    def offset_m(self) -> float:
        """``d`` of the plane equation ``normal . X = d`` in the world frame, metres."""
        return float(self.normal @ self.centre)


def plane_from_spec(spec: PlaneSpec, texture: Texture) -> Plane:
    """Place a :class:`PlaneSpec` in the world frame with its loaded texture."""
    rotation = rotation_xyz_deg(spec.rotation_deg)
    width_m, height_m = spec.texture_size_m
    texture_width, texture_height = texture.size
    return Plane(
        centre=np.array([spec.center_xy_m[0], spec.center_xy_m[1], spec.depth_m]),
        axis_u=rotation[:, 0].copy(),
        axis_v=rotation[:, 1].copy(),
        size_m=spec.size_m,
        texel_m=(width_m / texture_width, height_m / texture_height),
        texture=texture,
        brightness=spec.brightness,
    )


def build_planes(specs: Sequence[PlaneSpec], base_dir: Path, channels: int) -> list[Plane]:
    """Load textures (each file once) and place every plane of a scene.

    Args:
        specs: the scene's planes.
        base_dir: folder that relative texture paths are resolved against.
        channels: 1 (mono) or 3 (RGB).

    """
    images: dict[str, np.ndarray] = {}
    planes = []
    for spec in specs:
        loaded = []
        for name in spec.textures:
            if name not in images:
                images[name] = to_channels(load_texture_image(name, base_dir), channels)
            loaded.append(images[name])
        if len(loaded) == 1:
            image = loaded[0]
        else:
            height, width = loaded[0].shape[:2]
            side = max(64, round(float(np.sqrt(height * width)) / 64) * 64)
            image = mosaic(loaded, (side, side))
        tiled = spec.size_m is None or spec.texture_size_m != spec.size_m
        planes.append(plane_from_spec(spec, build_texture(image, tiled)))
    return planes


def intersect(
    rays: np.ndarray, T_world_cam: np.ndarray, plane: Plane
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intersect camera rays with the unbounded plane.

    Args:
        rays: ``(3, N)`` float32 unit rays in the camera frame.
        T_world_cam: 4x4 camera pose (camera frame -> world), metres.
        plane: the plane.

    Returns:
        ``(t, u, v)``: ``(N,)`` float32 ray parameter (metres along the ray;
        ``inf`` where the ray is parallel or points away) and plane
        coordinates along ``axis_u`` / ``axis_v`` relative to the centre, metres.

    """
    R = T_world_cam[:3, :3]
    origin = T_world_cam[:3, 3]
    axes = np.stack([plane.normal, plane.axis_u, plane.axis_v], axis=0) @ R
    projected = axes.astype(np.float32) @ rays
    numerator = np.float32(plane.offset_m - plane.normal @ origin)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = numerator / projected[0]
    t[~(t > 0)] = np.inf
    finite_t = np.where(np.isfinite(t), t, np.float32(0.0))
    relative = origin - plane.centre
    offset_u, offset_v = float(relative @ plane.axis_u), float(relative @ plane.axis_v)
    if plane.size_m is None and plane.texture.tiled:
        # An endless repeating plane looks the same a whole number of copies along: the
        # offset is reduced to one copy in float64 before the float32 sum. A camera 1e5 m
        # along it (or driven there over a long recording) lost the texture to rounding.
        width, height = plane.texture.size
        offset_u = math.fmod(offset_u, width * plane.texel_m[0])
        offset_v = math.fmod(offset_v, height * plane.texel_m[1])
    u = np.float32(offset_u) + finite_t * projected[1]
    v = np.float32(offset_v) + finite_t * projected[2]
    return t, u, v


def _level_of_detail(x: np.ndarray, y: np.ndarray, block: int) -> np.ndarray:
    """log2 of the sample spacing in texels, per ``block x block`` cell.

    Args:
        x: ``(R, C)`` texel x coordinates of the samples.
        y: ``(R, C)`` texel y coordinates.
        block: samples per cell along each axis.

    Returns:
        ``(R/block, C/block)`` float32 (large where the footprint is undefined).

    """
    centre = block // 2
    xs = x[centre::block, centre::block]
    ys = y[centre::block, centre::block]

    def _diff(a: np.ndarray, axis: int) -> np.ndarray:
        if a.shape[axis] < 2:
            return np.zeros_like(a)
        d = np.diff(a, axis=axis)
        return np.asarray(np.concatenate([d, d.take([-1], axis=axis)], axis=axis))

    with np.errstate(invalid="ignore", over="ignore"):
        along_x = _diff(xs, 1) ** 2 + _diff(ys, 1) ** 2
        along_y = _diff(xs, 0) ** 2 + _diff(ys, 0) ** 2
        spacing_sq = np.maximum(along_x, along_y) / np.float32(block * block)
        lod = np.float32(0.5) * np.log2(np.maximum(spacing_sq, np.float32(1e-12)))
    # fmin maps NaN (and inf) to a level beyond every pyramid: the coarsest one.
    return np.asarray(np.fmin(lod, np.float32(64.0)), dtype=np.float32)


def _bounding_box(mask: np.ndarray, block: int) -> tuple[slice, slice]:
    """Smallest block-aligned window of ``mask`` (2-D bool) that holds every True."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    r0, r1 = rows[0] // block * block, (rows[-1] // block + 1) * block
    c0, c1 = cols[0] // block * block, (cols[-1] // block + 1) * block
    return slice(int(r0), int(r1)), slice(int(c0), int(c1))


def render_view(
    ray_map: RayMap,
    T_world_cam: np.ndarray,
    planes: Sequence[Plane],
    background: float,
    channels: int,
) -> np.ndarray:
    """Render what a camera at ``T_world_cam`` sees of ``planes``.

    Args:
        ray_map: the camera's rays (also fixes resolution and supersampling).
        T_world_cam: 4x4 pose of the camera (camera frame -> world), metres.
        planes: planes in the world frame.
        background: linear-light value where no plane is hit.
        channels: 1 (mono) or 3 (RGB); must match the textures.

    Returns:
        ``(H, W)`` or ``(H, W, 3)`` float32 linear light.

    """
    rows, cols = ray_map.grid_shape
    block = ray_map.supersample
    nearest = np.full(rows * cols, np.inf, dtype=np.float32)
    owner = np.full(rows * cols, -1, dtype=np.int32)
    coordinates = []
    for number, plane in enumerate(planes):
        t, u, v = intersect(ray_map.rays, T_world_cam, plane)
        closer = ray_map.valid & (t < nearest)
        if plane.size_m is not None:
            closer &= np.abs(u) <= np.float32(plane.size_m[0] / 2)
            closer &= np.abs(v) <= np.float32(plane.size_m[1] / 2)
        nearest[closer] = t[closer]
        owner[closer] = number
        coordinates.append((u.reshape(rows, cols), v.reshape(rows, cols)))
    owner_grid = owner.reshape(rows, cols)
    extra = (channels,) if channels > 1 else ()
    samples = np.full((rows, cols, *extra), np.float32(background), dtype=np.float32)
    for number, plane in enumerate(planes):
        mask = owner_grid == number
        if not mask.any():
            continue
        window = _bounding_box(mask, block)
        u, v = coordinates[number]
        width, height = plane.texture.size
        texel_u, texel_v = plane.texel_m
        x = (u[window] + np.float32(width * texel_u / 2)) / np.float32(texel_u) - np.float32(0.5)
        y = (v[window] + np.float32(height * texel_v / 2)) / np.float32(texel_v) - np.float32(0.5)
        lod = _level_of_detail(x, y, block)
        # Levels are chosen from the cells this plane owns, not from the rest of the window.
        owned = mask[window].reshape(lod.shape[0], block, lod.shape[1], block).any(axis=(1, 3))
        lod = np.where(owned, lod, np.where(owned, lod, np.inf).min()).astype(np.float32)
        values = sample_texture(plane.texture, x, y, lod, block)
        if plane.brightness != 1.0:
            values *= np.float32(plane.brightness)
        target = samples[window]
        np.copyto(target, values, where=mask[window][..., None] if extra else mask[window])
    if block == 1:
        return samples
    # INTER_AREA with an integer factor is the exact block mean.
    size = (cols // block, rows // block)
    return np.asarray(cv2.resize(samples, size, interpolation=cv2.INTER_AREA))
