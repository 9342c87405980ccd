"""Projection and unprojection for pinhole cameras with radtan or equidistant distortion.

Conventions (those of OpenCV and Kalibr, see :mod:`lenspair.rectify.rig`): points in
the camera frame are metres, x right, y down, z forward; pixel centres are at
integer coordinates, so pixel ``(0, 0)`` covers ``[-0.5, 0.5]^2``.

* ``radtan``: ``x_d = x r + 2 p1 x y + p2 (rho^2 + 2 x^2)``,
  ``y_d = y r + p1 (rho^2 + 2 y^2) + 2 p2 x y`` with ``r = 1 + k1 rho^2 + k2 rho^4``
  on the normalised pinhole coordinates ``(x, y) = (X/Z, Y/Z)``.
* ``equidistant``: ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
  k4 theta^8)`` with ``theta`` the angle to the optical axis; the image point
  is ``theta_d`` along the azimuth. Rays beyond 90 deg are valid.

Unprojection inverts these with Newton's method in float64 and marks pixels
that have no pre-image (outside a radtan fold) as NaN. The renderer calls it
once per camera (:func:`ray_map`), never per frame.
"""

from dataclasses import dataclass

import numpy as np

from lenspair.rectify.rig import CameraModel

_NEWTON_STEPS = 30
_TOLERANCE = 1e-10


def project(camera: CameraModel, points: np.ndarray) -> np.ndarray:
    """Project camera-frame points to distorted pixel coordinates.

    Args:
        camera: the camera model.
        points: ``(N, 3)`` points (or directions) in the camera frame, metres.

    Returns:
        ``(N, 2)`` float64 pixel coordinates; NaN for points the model cannot
        image (behind a radtan camera, or exactly behind an equidistant one).

    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    fx, fy, cx, cy = camera.intrinsics
    X, Y, Z = points[:, 0], points[:, 1], points[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        if camera.distortion_model == "equidistant":
            k1, k2, k3, k4 = camera.distortion
            rho = np.hypot(X, Y)
            theta = np.arctan2(rho, Z)
            t2 = theta * theta
            theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
            scale = np.where(rho > 0, theta_d / rho, 1.0 / np.where(Z > 0, Z, np.nan))
            xd, yd = X * scale, Y * scale
            bad = (rho == 0) & (Z <= 0)
        else:
            k1, k2, p1, p2 = camera.distortion
            x, y = X / Z, Y / Z
            xd, yd = _radtan(x, y, k1, k2, p1, p2)
            bad = ~(Z > 0)
    pixels = np.stack([fx * xd + cx, fy * yd + cy], axis=1)
    pixels[bad] = np.nan
    return pixels


def unproject(camera: CameraModel, pixels: np.ndarray) -> np.ndarray:
    """Unproject distorted pixel coordinates to unit rays in the camera frame.

    Args:
        camera: the camera model.
        pixels: ``(N, 2)`` pixel coordinates.

    Returns:
        ``(N, 3)`` float64 unit vectors; rows of NaN where the distortion
        model has no pre-image for the pixel.

    """
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    fx, fy, cx, cy = camera.intrinsics
    xd = (pixels[:, 0] - cx) / fx
    yd = (pixels[:, 1] - cy) / fy
    if camera.distortion_model == "equidistant":
        rays = _unproject_equidistant(xd, yd, camera.distortion)
    else:
        x, y = _undistort_radtan(xd, yd, camera.distortion)
        rays = np.stack([x, y, np.ones_like(x)], axis=1)
    with np.errstate(invalid="ignore"):
        return np.asarray(rays / np.linalg.norm(rays, axis=1, keepdims=True))


def _radtan(
    x: np.ndarray, y: np.ndarray, k1: float, k2: float, p1: float, p2: float
) -> tuple[np.ndarray, np.ndarray]:
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * k2)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def _undistort_radtan(
    xd: np.ndarray, yd: np.ndarray, coefficients: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    k1, k2, p1, p2 = coefficients
    x, y = xd.copy(), yd.copy()
    with np.errstate(all="ignore"):
        for _ in range(_NEWTON_STEPS):
            fx_, fy_ = _radtan(x, y, k1, k2, p1, p2)
            ex, ey = fx_ - xd, fy_ - yd
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * k2)
            dradial = 2 * (k1 + 2 * k2 * r2)  # d radial / d(x or y), divided by x or y
            j11 = radial + x * x * dradial + 2 * p1 * y + 6 * p2 * x
            j12 = x * y * dradial + 2 * p1 * x + 2 * p2 * y
            j21 = x * y * dradial + 2 * p1 * x + 2 * p2 * y
            j22 = radial + y * y * dradial + 6 * p1 * y + 2 * p2 * x
            det = j11 * j22 - j12 * j21
            step_x = (j22 * ex - j12 * ey) / det
            step_y = (j11 * ey - j21 * ex) / det
            x, y = x - step_x, y - step_y
            if not np.nanmax(np.abs(step_x) + np.abs(step_y), initial=0.0) > 1e-14:
                break
        fx_, fy_ = _radtan(x, y, k1, k2, p1, p2)
        r2 = x * x + y * y
        # Past the fold of the radial polynomial the image point belongs to no ray.
        monotonic = 1 + 3 * k1 * r2 + 5 * k2 * r2 * r2 > 0
        converged = np.hypot(fx_ - xd, fy_ - yd) < _TOLERANCE * (1 + np.hypot(xd, yd))
    good = monotonic & converged & np.isfinite(x) & np.isfinite(y)
    return np.where(good, x, np.nan), np.where(good, y, np.nan)


def _unproject_equidistant(
    xd: np.ndarray, yd: np.ndarray, coefficients: tuple[float, float, float, float]
) -> np.ndarray:
    k1, k2, k3, k4 = coefficients
    theta_d = np.hypot(xd, yd)
    theta = theta_d.copy()
    with np.errstate(all="ignore"):
        for _ in range(_NEWTON_STEPS):
            t2 = theta * theta
            value = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
            slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            step = value / slope
            theta = theta - step
            if not np.nanmax(np.abs(step), initial=0.0) > 1e-14:
                break
        t2 = theta * theta
        value = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
        slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        good = (np.abs(value) < _TOLERANCE * (1 + theta_d)) & (slope > 0)
        good &= (theta >= 0) & (theta < np.pi)
        azimuth_x = np.where(theta_d > 0, xd / theta_d, 0.0)
        azimuth_y = np.where(theta_d > 0, yd / theta_d, 0.0)
    sin_theta = np.sin(theta)
    rays = np.stack([sin_theta * azimuth_x, sin_theta * azimuth_y, np.cos(theta)], axis=1)
    rays[~good] = np.nan
    return rays


def sample_positions(resolution: tuple[int, int], supersample: int) -> np.ndarray:
    """Sub-pixel sample positions of a supersampled image.

    Pixel ``i`` covers ``[i - 0.5, i + 0.5]``; with ``s = supersample`` its
    samples sit at ``i - 0.5 + (k + 0.5) / s`` for ``k = 0..s-1``.

    Returns:
        ``(H*s, W*s, 2)`` float64 ``(x, y)`` pixel coordinates.

    """
    width, height = resolution
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    xs = (np.arange(width)[:, None] + offsets[None, :]).reshape(-1)
    ys = (np.arange(height)[:, None] + offsets[None, :]).reshape(-1)
    grid_x, grid_y = np.meshgrid(xs, ys)
    return np.stack([grid_x, grid_y], axis=2)


@dataclass(frozen=True)
class RayMap:
    """Unit rays of every sample of a camera, computed once per camera.

    Attributes:
        rays: ``(3, H*s*W*s)`` float32 unit vectors in the camera frame
            (one column per sample, row-major over the supersampled grid);
            zero columns where the model has no ray (background samples).
        valid: ``(H*s*W*s,)`` bool, False where the model has no ray.
        resolution: ``(width, height)`` of the output image, pixels.
        supersample: samples per pixel along each axis.

    """

    rays: np.ndarray
    valid: np.ndarray
    resolution: tuple[int, int]
    supersample: int

    @property
    def grid_shape(self) -> tuple[int, int]:
        """``(H*s, W*s)`` of the sample grid."""
        width, height = self.resolution
        return height * self.supersample, width * self.supersample


def ray_map(camera: CameraModel, supersample: int = 1) -> RayMap:
    """Unproject every sample position of ``camera`` (see :func:`sample_positions`)."""
    positions = sample_positions(camera.resolution, supersample).reshape(-1, 2)
    rays = unproject(camera, positions)
    valid = np.all(np.isfinite(rays), axis=1)
    rays[~valid] = 0.0
    return RayMap(
        rays=np.ascontiguousarray(rays.T, dtype=np.float32),
        valid=valid,
        resolution=camera.resolution,
        supersample=supersample,
    )


def undistort_maps(
    camera: CameraModel, K_new: np.ndarray | None = None, size: tuple[int, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap`` maps from the distorted image to an undistorted pinhole image.

    Args:
        camera: the distorted camera.
        K_new: 3x3 camera matrix of the pinhole image (default: the camera's K).
        size: ``(width, height)`` of the pinhole image (default: the camera's).

    Returns:
        ``(map_x, map_y)``, each ``(height, width)`` float32.

    """
    K = camera.K if K_new is None else np.asarray(K_new, dtype=np.float64)
    width, height = camera.resolution if size is None else size
    grid = sample_positions((width, height), 1).reshape(-1, 2)
    normalised = (grid - K[:2, 2]) / np.array([K[0, 0], K[1, 1]])
    points = np.concatenate([normalised, np.ones((grid.shape[0], 1))], axis=1)
    pixels = project(camera, points).astype(np.float32)
    pixels[~np.isfinite(pixels)] = -1e4
    return pixels[:, 0].reshape(height, width), pixels[:, 1].reshape(height, width)
