"""A raw image's border on the rectified plane: what the rectified view's zoom fits.

For :mod:`~lenspair.rectify.rectification`: the border of each raw image,
as rays turned into the rectified frame, is the outline the rectified view
must stay inside (alpha 0) or contain (alpha 1). Two things keep a wide
fisheye's outline finite:

* a border pixel that a fisheye sees past 90 deg off its axis is pulled in
  onto 89.9 deg along its bearing (:func:`within_90_deg`), where the lens
  model holds to 90 deg;
* a ray beyond :data:`MAX_ANGLE_DEG` off the rectified axis is drawn at that
  angle (:func:`capped`): a pinhole view of rays near 90 deg is unbounded.
"""

import numpy as np

from lenspair.rectify.errors import RectifyError
from lenspair.rectify.projection import distorted_angle, monotonic_limit, pixel_rays
from lenspair.rectify.rig import CameraModel

_EDGE_NAMES = ("left", "right", "top", "bottom")


def raw_border(camera: CameraModel, rotation: np.ndarray, name: str, turn_deg: float) -> np.ndarray:
    """A raw image's border on the rectified plane, in order around the image.

    Every pixel centre along the border (centres, not pixel edges, so that
    bilinear sources stay inside the image); those without a ray or behind
    the rectified plane are left out, which joins their neighbours by a chord.
    A fisheye whose model holds to 90 deg sees past 90 deg beyond a circle
    about the principal point (the side edges of a RealSense T265: 848 px at
    f 286): its border pixels outside that circle are pulled in onto it
    along their bearing (:func:`within_90_deg`), so the outline is the image
    within the circle, what a rectified plane can show.

    Args:
        camera: the raw camera.
        rotation: its rectifying rotation.
        name: ``cam0`` or ``cam1``, for errors.
        turn_deg: how far the rectification turns the camera, for errors.

    Returns:
        ``(N, 2)`` float64 normalised rectified coordinates: a closed polygon.

    Raises:
        RectifyError: a whole edge of the image has no usable ray where the
            distortion model stops short of 90 deg (a calibration extrapolated),
            or lies behind the plane; naming ``name`` and the edge.
    """
    width, height = camera.resolution
    xs, ys = np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)
    edges = {
        "top": np.column_stack([xs, np.zeros(width)]),
        "right": np.column_stack([np.full(height, width - 1.0), ys]),
        "bottom": np.column_stack([xs[::-1], np.full(width, height - 1.0)]),
        "left": np.column_stack([np.zeros(height), ys[::-1]]),
    }
    sides: list[np.ndarray] = []
    no_ray: list[str] = []
    behind: list[str] = []
    # an equidistant model monotonic to 90 deg gives no ray only past 90 deg
    past_90 = camera.distortion_model == "equidistant" and monotonic_limit(camera) >= np.pi / 2
    for edge, points in edges.items():
        rays = pixel_rays(camera, within_90_deg(camera, points) if past_90 else points)
        rays = rays @ rotation.T
        ok = rays[:, 2] > 1e-6  # False for NaN: pixels without a ray are skipped
        if not ok.any():
            (behind if np.isfinite(rays).all(axis=1).any() else no_ray).append(edge)
            continue
        sides.append(capped(rays[np.isfinite(rays).all(axis=1)]))
    # named in a fixed order, whatever the walk around the image
    no_ray, behind = ([e for e in _EDGE_NAMES if e in lost] for lost in (no_ray, behind))
    if no_ray:
        raise RectifyError(
            f"rectification: no pixel on {name}'s {' and '.join(no_ray)} "
            f"{'edge' if len(no_ray) == 1 else 'edges'} has a valid ray: beyond the range "
            "of its distortion model, which a calibration extrapolates where its boards never "
            "reached (calibrate again with views that bring the board near the image edges)"
        )
    if behind:
        raise RectifyError(
            f"rectification: {name}'s {' and '.join(behind)} "
            f"{'edge falls' if len(behind) == 1 else 'edges fall'} behind the rectified plane: "
            f"bringing the baseline along the rows turns the cameras {turn_deg:.0f} deg, more "
            "than their field of view allows (mount cam1 beside cam0, or check T_cn_cnm1 in "
            "the calibration)"
        )
    return np.concatenate(sides)


def within_90_deg(camera: CameraModel, pixels: np.ndarray) -> np.ndarray:
    """``pixels`` of an equidistant camera, those past 90 deg off-axis moved onto 89.9 deg.

    Each moves towards the principal point along its bearing (in normalised
    distorted coordinates) to the radius the model gives 89.9 deg, or to
    pi / 2 where that is less (the most OpenCV inverts); the others stay where
    they are, exactly. For a model monotonic up to 90 deg
    (:func:`~lenspair.rectify.projection.monotonic_limit`).
    """
    fx, fy, cx, cy = camera.intrinsics
    x, y = (pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy
    limit = float(distorted_angle(camera, np.radians(89.9)))
    # cv2.fisheye.undistortPoints (behind pixel_rays) takes no distorted angle over 90 deg:
    # a lens whose distortion widens near the rim is pulled in a little further
    limit = min(limit, np.pi / 2 - 1e-6)
    radius = np.hypot(x, y)
    scale = np.where(radius > limit, limit / np.maximum(radius, 1e-12), 1.0)
    return np.column_stack([cx + fx * x * scale, cy + fy * y * scale])


MAX_ANGLE_DEG = 75.0
"""The most a rectified view reaches off its axis: a border beyond is drawn at this angle."""


def capped(rays: np.ndarray) -> np.ndarray:
    """Rays' points on the rectified plane, those over :data:`MAX_ANGLE_DEG` off its axis pulled in.

    A pinhole view spreads a fisheye's rays near 90 deg off-axis over an
    unbounded plane: the border of a lens that sees past 90 deg in its
    corners (a diagonal field over 180 deg) ran out to infinity along the
    diagonals, and the zoom search put the rectified view out there (a focal
    length of a few pixels, the centre thousands of pixels away). Each ray is
    kept on its bearing; one beyond the angle (behind the plane too) is
    placed at the angle, so the border is the lens's within that cone.
    """
    radial = np.linalg.norm(rays[:, :2], axis=1)
    limit = np.tan(np.radians(MAX_ANGLE_DEG))
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = (rays[:, 2] > 0) & (radial < limit * rays[:, 2])
        planar = rays[:, :2] / rays[:, 2:]
        pulled = rays[:, :2] * (limit / radial)[:, None]
    keep = inside | (radial > 0)
    return np.asarray(np.where(inside[:, None], planar, pulled)[keep])
