"""Clean natural photographs that installed packages ship (nothing is downloaded).

The realism report and the shipped pretrained weights use these as the
clean side: scikit-image's bundled photographs (``skimage.data``: those in
its wheel, no pooch download) and matplotlib's ``grace_hopper.jpg`` sample.
Textures, micrographs and astronomy images are left out: they are not what a
robot camera sees. Each image is cropped to the requested aspect ratio about
its centre and resized with area averaging.
"""

from collections.abc import Callable

import cv2
import numpy as np
import skimage.data

from lenspair.simulate.errors import SimulateError


def _grace_hopper() -> np.ndarray:
    from matplotlib import cbook

    path = cbook.get_sample_data("grace_hopper.jpg", asfileobj=False)
    data = np.fromfile(str(path), np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if image is None:
        raise SimulateError("matplotlib sample grace_hopper.jpg: cannot be decoded")
    rgb: np.ndarray = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return rgb


NATURAL_IMAGES: dict[str, Callable[[], np.ndarray]] = {
    "astronaut": skimage.data.astronaut,
    "camera": skimage.data.camera,
    "chelsea": skimage.data.chelsea,
    "clock": skimage.data.clock,
    "coffee": skimage.data.coffee,
    "coins": skimage.data.coins,
    "grace_hopper": _grace_hopper,
    "grass": skimage.data.grass,
    "gravel": skimage.data.gravel,
    "brick": skimage.data.brick,
    "rocket": skimage.data.rocket,
}
"""Name -> loader of an ``uint8`` photograph, ``(H, W)`` or ``(H, W, 3)`` RGB."""

HELD_OUT: tuple[str, ...] = ("coffee", "clock")
"""Images kept out of pretraining, for validating the shipped weights."""


def fit(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Centre-crop ``image`` to the aspect ratio of ``shape`` = (H, W), then resize to it.

    Raises:
        SimulateError: the image is too small to hold a crop of that aspect (a 1x1 image).
    """
    height, width = image.shape[:2]
    target_h, target_w = shape
    scale = min(height / target_h, width / target_w)
    crop_h, crop_w = round(target_h * scale), round(target_w * scale)
    if crop_h < 1 or crop_w < 1:
        raise SimulateError(
            f"{width}x{height} px is too small for a crop of {target_w}x{target_h}'s aspect"
        )
    top, left = (height - crop_h) // 2, (width - crop_w) // 2
    window = np.ascontiguousarray(image[top : top + crop_h, left : left + crop_w])
    interpolation = cv2.INTER_AREA if scale > 1 else cv2.INTER_CUBIC
    resized: np.ndarray = cv2.resize(window, (target_w, target_h), interpolation=interpolation)
    return resized


def load_natural_images(
    shape: tuple[int, int] = (480, 720), channels: int = 3, names: tuple[str, ...] | None = None
) -> dict[str, np.ndarray]:
    """The natural images, ``uint8`` ``(H, W)`` (channels 1) or ``(H, W, 3)`` (channels 3).

    Args:
        shape: output ``(H, W)``; 720x480 is the Raindrop dataset's size.
        channels: 1 (grey, ITU-R 601 luma) or 3 (RGB; grey images are repeated).
        names: subset of :data:`NATURAL_IMAGES` (default: all).

    Raises:
        SimulateError: an unknown name or channel count.

    """
    if channels not in (1, 3):
        raise SimulateError(f"channels: expected 1 or 3, got {channels}")
    chosen = tuple(NATURAL_IMAGES) if names is None else names
    images = {}
    for name in chosen:
        if name not in NATURAL_IMAGES:
            valid = ", ".join(NATURAL_IMAGES)
            raise SimulateError(f"unknown natural image {name!r}; valid names: {valid}")
        image: np.ndarray = np.asarray(NATURAL_IMAGES[name](), np.uint8)
        if image.ndim == 3 and image.shape[2] == 4:
            image = image[:, :, :3]
        if channels == 1 and image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        elif channels == 3 and image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        images[name] = fit(image, shape)
    return images
