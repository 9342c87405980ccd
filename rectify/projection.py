"""Camera projection under both lens models: camera-frame rays <-> raw (distorted) pixels.

:func:`project_rays` applies a :class:`~lenspair.rectify.rig.CameraModel`'s
distortion (``radtan``: OpenCV's ``k1, k2, p1, p2``; ``equidistant``: the
fisheye model ``k1..k4``) in closed form; :func:`pixel_rays` inverts it with
OpenCV's iterative undistortion and checks each answer by projecting it back.
Both refuse the part of the image plane where the distortion polynomial folds
back on itself, so a ray is never matched with the wrong pixel.

Pixel coordinates follow OpenCV: the centre of the top-left pixel is ``(0, 0)``.
"""

import functools

import cv2
import numpy as np

from lenspair.rectify.rig import CameraModel

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@functools.lru_cache(maxsize=64)  # asked anew for each of the zoom search's projections
def monotonic_limit(camera: CameraModel) -> float:
    """Largest radius (radtan: ``r``; equidistant: ``theta``) where distortion is monotonic."""
    k = camera.distortion
    if camera.distortion_model == "radtan":
        # d/dr [r (1 + k1 r^2 + k2 r^4)] = 1 + 3 k1 s + 5 k2 s^2, s = r^2
        coefficients = [5 * k[1], 3 * k[0], 1.0]
    else:
        # d/dtheta [theta (1 + k1 t^2 + ... + k4 t^8)], t = theta, in s = theta^2
        coefficients = [9 * k[3], 7 * k[2], 5 * k[1], 3 * k[0], 1.0]
    roots = np.roots(np.trim_zeros(np.asarray(coefficients), "f"))
    positive = [r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
    limit = float(np.sqrt(min(positive))) if positive else np.inf
    return min(limit, np.pi / 2) if camera.distortion_model == "equidistant" else limit


def distorted_angle(camera: CameraModel, theta: np.ndarray | float) -> np.ndarray:
    """The equidistant model's ``theta_d`` of off-axis angles ``theta`` (radians)."""
    k = camera.distortion
    t2 = np.square(theta)
    return np.asarray(theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))))


def project_rays(camera: CameraModel, rays: np.ndarray) -> np.ndarray:
    """Project camera-frame rays to raw (distorted) pixel coordinates.

    Args:
        camera: the camera model.
        rays: ``(..., 3)`` directions (or points) in the camera frame, any scale.

    Returns:
        ``(..., 2)`` float64 pixel coordinates; NaN for rays at or behind the
        image plane and beyond the radius where the distortion polynomial
        stops being monotonic (those would fold back into the image).

    """
    rays = np.asarray(rays, dtype=np.float64)
    z = rays[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(z > 0, rays[..., 0] / z, np.nan)
        y = np.where(z > 0, rays[..., 1] / z, np.nan)
    k = camera.distortion
    r2 = x * x + y * y
    limit = monotonic_limit(camera)
    if camera.distortion_model == "radtan":
        radial = 1.0 + k[0] * r2 + k[1] * r2 * r2
        xd = x * radial + 2 * k[2] * x * y + k[3] * (r2 + 2 * x * x)
        yd = y * radial + k[2] * (r2 + 2 * y * y) + 2 * k[3] * x * y
        bad = r2 >= limit * limit
    else:
        r = np.sqrt(r2)
        theta = np.arctan(r)
        theta_d = distorted_angle(camera, theta)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(r > 1e-12, theta_d / np.maximum(r, 1e-12), 1.0)
        xd, yd = x * scale, y * scale
        bad = theta >= limit
    fx, fy, cx, cy = camera.intrinsics
    pixels = np.stack([fx * xd + cx, fy * yd + cy], axis=-1)
    pixels[bad | ~np.isfinite(r2)] = np.nan
    return pixels


def pixel_rays(camera: CameraModel, pixels: np.ndarray) -> np.ndarray:
    """Back-project raw pixel coordinates to camera-frame rays ``(x, y, 1)``.

    Uses ``cv2.undistortPoints`` / ``cv2.fisheye.undistortPoints`` with tight
    termination criteria (OpenCV's default of 5 iterations is not enough
    for strong distortion), and checks each result by projecting it back:
    a calibration fitted to board views that never reached the image corners
    may have no ray at all for a corner pixel.

    Args:
        camera: the camera model.
        pixels: ``(..., 2)`` raw pixel coordinates.

    Returns:
        ``(..., 3)`` float64 rays with ``z = 1``; NaN where no ray projects
        back onto the pixel (within 0.01 px).

    """
    pixels = np.asarray(pixels, dtype=np.float64)
    flat = pixels.reshape(-1, 1, 2)
    if flat.shape[0] == 0:
        return np.zeros((*pixels.shape[:-1], 3))
    if camera.distortion_model == "radtan":
        iterative = getattr(cv2, "undistortPointsIter", None)  # OpenCV 4's name for it
        if iterative is not None:
            normalized = iterative(flat, camera.K, camera.dist_coeffs, None, None, _CRITERIA)
        else:
            normalized = cv2.undistortPoints(flat, camera.K, camera.dist_coeffs, criteria=_CRITERIA)
    else:
        normalized = cv2.fisheye.undistortPoints(
            flat, camera.K, camera.dist_coeffs, criteria=_CRITERIA
        )
    xy = np.asarray(normalized, dtype=np.float64).reshape(*pixels.shape[:-1], 2)
    rays = np.concatenate([xy, np.ones((*xy.shape[:-1], 1))], axis=-1)
    with np.errstate(invalid="ignore"):
        wrong = ~(np.linalg.norm(project_rays(camera, rays) - pixels, axis=-1) < 0.01)
    rays[wrong] = np.nan
    return rays
