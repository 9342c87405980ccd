"""Plane textures: scikit-image samples or user images, as linear-light mip pyramids.

Textures are looked up by name in :data:`NAMES` (images that scikit-image
ships inside its wheel, so nothing is downloaded) or read from an image file
(``~`` expanded; a relative path is relative to the scene spec's folder).
They are decoded once to linear light ``float32`` in ``[0, 1]``, converted
to the rig's colour mode, and pre-filtered into a Gaussian pyramid for
anti-aliased sampling.

Pyramid convention: level ``l`` texel ``j`` is centred on level-0 texel
``j * 2**l`` (``cv2.pyrDown``), so a level-0 coordinate ``x`` (texel centres
at integers) is ``x / 2**l`` at level ``l``.
"""

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import skimage.data

from lenspair.core.config import config_path
from lenspair.core.errors import ConfigError, ImageIOError
from lenspair.core.imageio import image_header, read_image
from lenspair.core.pixels import to_float, to_linear

NAMES: dict[str, Callable[[], np.ndarray]] = {
    "astronaut": skimage.data.astronaut,
    "brick": skimage.data.brick,
    "camera": skimage.data.camera,
    "cell": skimage.data.cell,
    "chelsea": skimage.data.chelsea,
    "coffee": skimage.data.coffee,
    "coins": skimage.data.coins,
    "grass": skimage.data.grass,
    "gravel": skimage.data.gravel,
    "hubble_deep_field": skimage.data.hubble_deep_field,
    "immunohistochemistry": skimage.data.immunohistochemistry,
    "moon": skimage.data.moon,
    "page": skimage.data.page,
    "retina": skimage.data.retina,
    "rocket": skimage.data.rocket,
    "text": skimage.data.text,
}
"""Texture names -> scikit-image loaders (all ship with scikit-image, none downloads)."""

TILE_MULTIPLE = 64
"""Tiled textures are resized to multiples of this so every pyramid level wraps exactly."""

_MIN_LEVEL_SIZE = 4
_LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


@dataclass(frozen=True)
class Texture:
    """A texture ready for sampling.

    Attributes:
        levels: mip pyramid, level 0 first; ``float32`` linear light,
            ``(h, w)`` (mono) or ``(h, w, 3)`` (RGB), halving per level.
        tiled: the texture repeats (sampled with wrap-around) instead of
            being clamped at its border.

    """

    levels: tuple[np.ndarray, ...]
    tiled: bool

    @property
    def size(self) -> tuple[int, int]:
        """Level-0 ``(width, height)`` in texels."""
        return int(self.levels[0].shape[1]), int(self.levels[0].shape[0])


def texture_file(name: str, base_dir: Path) -> Path:
    """The image file a texture name (not one of :data:`NAMES`) stands for.

    ``~`` is the home folder; a relative path is relative to ``base_dir``,
    the scene spec's folder (:func:`lenspair.core.config.config_path`).
    """
    return config_path(name, base_dir)


def check_texture(name: str, base_dir: Path) -> str | None:
    """Return ``None`` if ``name`` is a known texture or an 8/16-bit image file, else the problem.

    The file's header is read (pixels are not), so that a spec naming a file
    that is no image is refused with the spec and its key, before a
    simulation starts writing.
    """
    if name in NAMES:
        return None
    file = texture_file(name, base_dir)
    if file.is_file():
        try:
            _, _, _, pixel_format = image_header(file)
        except ImageIOError as exc:
            return str(exc)
        if pixel_format not in ("uint8", "uint16"):
            return f"{file}: {pixel_format} pixels; a texture is an 8- or 16-bit image"
        return None
    if Path(name).suffix or "/" in name or "\\" in name:  # meant as a file: say where it looked
        return f"{file}: no such file (a texture file is read relative to the scene spec's folder)"
    return f"unknown texture {name!r}; use an image file or one of: {', '.join(sorted(NAMES))}"


def load_texture_image(name: str, base_dir: Path) -> np.ndarray:
    """Load a texture as linear-light ``float32`` ``(h, w)`` or ``(h, w, 3)`` in ``[0, 1]``.

    Raises:
        ConfigError: unknown name and no such file.
        ImageIOError: the file cannot be read.

    """
    if name in NAMES:
        raw = np.asarray(NAMES[name]())
        if raw.ndim == 3:
            raw = raw[:, :, :3]
        encoded = to_float(np.ascontiguousarray(raw.astype(np.uint8)))
    else:
        problem = check_texture(name, base_dir)
        if problem is not None:
            raise ConfigError(problem)
        file = texture_file(name, base_dir)
        try:
            encoded = to_float(read_image(file))
        except ValueError as exc:
            raise ImageIOError(f"{file}: {exc}") from None
    return to_linear(encoded)


def to_channels(image: np.ndarray, channels: int) -> np.ndarray:
    """Convert a linear image to 1 channel ``(h, w)`` (luminance) or 3 ``(h, w, 3)``."""
    if channels == 1:
        if image.ndim == 3:
            return np.ascontiguousarray(image @ _LUMA)
        return image
    if image.ndim == 2:
        return np.ascontiguousarray(np.repeat(image[:, :, None], 3, axis=2))
    return image


def mosaic(images: list[np.ndarray], tile_size: tuple[int, int]) -> np.ndarray:
    """Lay ``images`` out in a near-square grid, each resized to ``tile_size`` (w, h)."""
    columns = int(np.ceil(np.sqrt(len(images))))
    rows = int(np.ceil(len(images) / columns))
    width, height = tile_size
    tiles = [cv2.resize(im, (width, height), interpolation=cv2.INTER_AREA) for im in images]
    # Fill an incomplete last row by repeating from the start (no blank holes).
    tiles += tiles[: rows * columns - len(tiles)]
    grid = [np.concatenate(tiles[r * columns : (r + 1) * columns], axis=1) for r in range(rows)]
    return np.ascontiguousarray(np.concatenate(grid, axis=0))


def _round_to_multiple(value: int, multiple: int) -> int:
    return max(multiple, round(value / multiple) * multiple)


def _pyr_down_wrap(image: np.ndarray) -> np.ndarray:
    pad = 4
    padded = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_WRAP)
    reduced = cv2.pyrDown(padded)
    half = pad // 2
    return np.ascontiguousarray(reduced[half:-half, half:-half])


def build_texture(image: np.ndarray, tiled: bool) -> Texture:
    """Build the mip pyramid of a linear-light ``float32`` image.

    Args:
        image: ``(h, w)`` or ``(h, w, 3)`` float32, linear light.
        tiled: repeat the texture; it is then resized to multiples of
            :data:`TILE_MULTIPLE` so that every level wraps seamlessly.

    """
    image = np.ascontiguousarray(image, dtype=np.float32)
    if tiled:
        height, width = image.shape[:2]
        size = (_round_to_multiple(width, TILE_MULTIPLE), _round_to_multiple(height, TILE_MULTIPLE))
        if size != (width, height):
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    levels = [image]
    while min(levels[-1].shape[:2]) >= 2 * _MIN_LEVEL_SIZE:
        current = levels[-1]
        if tiled:
            if current.shape[0] % 2 or current.shape[1] % 2:
                break
            levels.append(_pyr_down_wrap(current))
        else:
            levels.append(cv2.pyrDown(current))
    return Texture(levels=tuple(levels), tiled=tiled)


def sample_texture(
    texture: Texture, x: np.ndarray, y: np.ndarray, lod: np.ndarray, block: int = 1
) -> np.ndarray:
    """Trilinear (mip-mapped bilinear) samples of ``texture`` on a sample grid.

    Args:
        texture: the pyramid.
        x: level-0 texel x coordinates, ``(R, C)`` float32 (centres at
            integers; wrapped here for tiled textures).
        y: level-0 texel y coordinates, ``(R, C)`` float32.
        lod: level of detail per ``block x block`` cell, ``(R/block, C/block)``
            float32: log2 of the sample spacing in level-0 texels (clamped to
            the pyramid).
        block: samples per lod cell along each axis (the supersampling factor).

    Returns:
        ``(R, C)`` or ``(R, C, 3)`` float32 linear light.

    """
    top = len(texture.levels) - 1
    # fmin/fmax also map NaN to the bounds (a footprint that cannot be measured).
    lod = np.fmax(np.fmin(lod, np.float32(top)), np.float32(0.0)).astype(np.float32)
    rows, cols = x.shape
    channels = texture.levels[0].shape[2:]
    width, height = texture.size
    if texture.tiled:
        # remap's fixed-point maps need small coordinates: wrap at level 0, where
        # every level's period divides the texture size exactly.
        x = x - np.floor(x / np.float32(width)) * np.float32(width)
        y = y - np.floor(y / np.float32(height)) * np.float32(height)
        border = cv2.BORDER_WRAP
    else:
        x = np.clip(x, np.float32(-2.0), np.float32(width + 1))
        y = np.clip(y, np.float32(-2.0), np.float32(height + 1))
        border = cv2.BORDER_REPLICATE
    out = np.zeros((rows, cols, *channels), dtype=np.float32)
    first = int(np.floor(lod.min(initial=float(top))))
    last = int(np.ceil(lod.max(initial=0.0)))
    for level in range(first, last + 1):
        weight = np.maximum(np.float32(1.0) - np.abs(lod - np.float32(level)), np.float32(0.0))
        used_rows = np.flatnonzero(weight.any(axis=1))
        if used_rows.size == 0:
            continue
        used_cols = np.flatnonzero(weight.any(axis=0))
        # Sample this level only inside the cells that use it (fisheye levels form rings).
        cells = (
            slice(int(used_rows[0]), int(used_rows[-1]) + 1),
            slice(int(used_cols[0]), int(used_cols[-1]) + 1),
        )
        window = (
            slice(cells[0].start * block, cells[0].stop * block),
            slice(cells[1].start * block, cells[1].stop * block),
        )
        scale = np.float32(2.0**-level)
        values: np.ndarray = cv2.remap(
            texture.levels[level],
            x[window] * scale,
            y[window] * scale,
            cv2.INTER_LINEAR,
            borderMode=border,
        )
        size = (values.shape[1], values.shape[0])
        full: np.ndarray = cv2.resize(weight[cells], size, interpolation=cv2.INTER_NEAREST)
        if channels:
            out[window] += values * full[:, :, None]
        else:
            cv2.accumulateProduct(values, full, out[window])
    return out
