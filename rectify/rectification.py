"""Stereo rectification that composes: rectified pixel coordinates <-> raw pixel coordinates.

A :class:`StereoRectification` is computed once per recording from a
:class:`~lenspair.rectify.rig.StereoRig`. It never resamples an image by itself unless
asked (:meth:`StereoRectification.rectify`): later stages compose the
rectification with a homography and a crop by mapping *their* output pixel
grid to rectified coordinates and then calling
:meth:`StereoRectification.raw_coordinates`, so each image is interpolated
exactly once (``cv2.remap`` on the raw image).
Rays and raw pixels are converted by :mod:`~lenspair.rectify.projection`.

Conventions:

* Pixel coordinates follow OpenCV: the centre of the top-left pixel is ``(0, 0)``.
* Both rectified views share one camera matrix ``K`` (square pixels, same
  principal point: ``cv2.CALIB_ZERO_DISPARITY``); a point at depth ``Z``
  appears on the same row in both views, at ``x0 - x1 = f * B / Z`` for a
  cam1 on cam0's right (``B`` = :attr:`StereoRectification.baseline_m`).
* The rectifying rotations come from ``cv2.stereoRectify`` (they do not depend
  on the lens distortion, so the same call serves both distortion models).
  ``cv2.stereoRectify`` splits the relative rotation in two halves, which
  turns both images by 90 deg when cam1 is mounted upside down; cam1 is
  therefore first turned by the nearest multiple of 90 deg about its optical
  axis (:attr:`StereoRectification.cam1_quarter_turns`), so rectified views
  are upright in cam0's orientation.
* The rectified camera matrix is chosen here, not by OpenCV, with the meaning
  of ``cv2.stereoRectify``'s ``alpha`` for both distortion models: ``alpha =
  0`` (the default) zooms so that every rectified pixel of both views comes
  from inside its raw image (no black borders; the usable region is the whole
  image); ``alpha = 1`` keeps every raw pixel (black borders); values between
  interpolate. ``cv2.fisheye.stereoRectify``'s ``balance`` has no such
  guarantee, which is why it is not used. ``alpha = 0`` takes the least zoom
  that keeps every pixel valid, wherever a roll between the cameras turns
  their borders (:mod:`~lenspair.rectify.zoom`).
* Only side-by-side rigs are rectified, judged as ``cv2.stereoRectify``
  judges which image axis to put the baseline along
  (:func:`~lenspair.rectify.layout.unsupported_layout`); the rectified
  baseline is checked to lie along the rows.
"""

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from lenspair.rectify import outline
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.layout import quarter_turns, rotation_z, unsupported_layout
from lenspair.rectify.projection import pixel_rays, project_rays
from lenspair.rectify.rig import CameraModel, StereoRig
from lenspair.rectify.zoom import (
    border_pixels,
    camera_matrix,
    inscribed_centre,
    refine_centre,
    smallest_valid_focal,
)

View = Literal["cam0", "cam1"]
OUTSIDE = -1000.0
"""Map value for rectified pixels with no raw source (remap then yields the border value)."""


def _rectified_to_raw(
    camera: CameraModel, rotation: np.ndarray, K: np.ndarray, points_xy: np.ndarray
) -> np.ndarray:
    """Raw pixel coordinates of rectified pixels, ``(..., 2)`` float32; NaN without a ray."""
    points = np.asarray(points_xy, dtype=np.float64)
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    rays = np.stack(
        [(points[..., 0] - cx) / f, (points[..., 1] - cy) / f, np.ones(points.shape[:-1])],
        axis=-1,
    )
    return project_rays(camera, rays @ rotation).astype(np.float32)  # R^T on row vectors


def _inside(raw: np.ndarray, resolution: tuple[int, int]) -> np.ndarray:
    """Whether raw pixel coordinates ``(..., 2)`` have a bilinear source in the image (NaN: no)."""
    width, height = resolution
    with np.errstate(invalid="ignore"):
        x, y = raw[..., 0], raw[..., 1]
        return np.asarray((x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1))


def _alpha_zero(
    rig: StereoRig, rotations: np.ndarray, outlines: list[np.ndarray], size: tuple[int, int]
) -> np.ndarray:
    """``K`` of the least zoom that leaves every rectified pixel of both views valid.

    See :mod:`~lenspair.rectify.zoom`: the centre of the largest rectangle of
    the output's shape inside both border polygons, refined, and at each
    centre the smallest focal length for which every pixel on the output's
    border (and so inside it) has its source in the raw image and lies within
    :data:`~lenspair.rectify.outline.MAX_ANGLE_DEG` of the axis. A fisheye
    squeezes the rays near 90 deg into a ring inside its image, so every
    border pixel of a view reaching 87 deg had its source (a RealSense T265
    rectified to a focal length of 22 px at 848x800): the angle, not the
    image, bounds such a view.
    """
    centre, cell = inscribed_centre(outlines, size[0] / size[1])
    border = border_pixels(size)
    reach = np.tan(np.radians(outline.MAX_ANGLE_DEG))
    # the refinement's searches start from the last answer (their centres lie within
    # cells of each other) and give up past twice the grid centre's: no candidate needs that
    found: list[float] = []

    def least_focal(at: np.ndarray) -> float:
        def valid(f: float) -> bool:
            K = camera_matrix(f, at, size)
            if np.hypot(*((border - K[:2, 2]) / f).T).max() > reach:
                return False
            return all(
                bool(_inside(_rectified_to_raw(camera, rot, K, border), camera.resolution).all())
                for camera, rot in zip((rig.cam0, rig.cam1), rotations, strict=True)
            )

        if not found:  # the grid's centre: there is an answer, or no common region
            found.append(smallest_valid_focal(valid, float(np.mean(rig.cam0.intrinsics[:2]))))
            return found[0]
        answer = smallest_valid_focal(valid, found[-1], 1e-5, 1.01, ceiling=2 * found[0])
        if np.isfinite(answer):
            found.append(answer)
        return answer

    centre, f = refine_centre(least_focal, centre, cell)
    return camera_matrix(f, centre, size)


@dataclass(frozen=True, eq=False)
class StereoRectification:
    """Row-aligned rectification of a stereo rig.

    Attributes:
        rig: the calibrated rig.
        rotations: ``(2, 3, 3)`` float64; ``rotations[i]`` takes a direction in
            raw camera ``i``'s frame to the common rectified frame (OpenCV's
            ``R1``/``R2``, including cam1's quarter turns).
        K: ``(3, 3)`` float64 camera matrix shared by both rectified views.
        size: rectified image ``(width, height)``, pixels.
        baseline_m: signed rectified baseline: cam1's optical centre lies at
            ``x = baseline_m`` in the rectified frame of cam0 (metres).
        cam1_quarter_turns: 90 deg turns of cam1 about its optical axis undone
            before ``cv2.stereoRectify`` (2 for a cam1 mounted upside down).
        alpha: 0 = every pixel valid in both views, 1 = every raw pixel kept.

    """

    rig: StereoRig
    rotations: np.ndarray
    K: np.ndarray
    size: tuple[int, int]
    baseline_m: float
    cam1_quarter_turns: int
    alpha: float

    @classmethod
    def from_rig(
        cls, rig: StereoRig, alpha: float = 0.0, size: tuple[int, int] | None = None
    ) -> "StereoRectification":
        """Compute the rectification of ``rig``.

        Args:
            rig: calibrated rig, horizontal (baseline mostly along cam0's x).
            alpha: in ``[0, 1]``, see the module docstring.
            size: rectified ``(width, height)``; cam0's resolution by default.

        Raises:
            RectifyError: a rig that is not side by side (top/bottom, or a baseline
                along the optical axis), no common valid region, bad ``alpha``.

        """
        if not 0.0 <= alpha <= 1.0:
            raise RectifyError(f"rectification alpha: expected 0..1, got {alpha}")
        size = size or rig.cam0.resolution
        # decided as cv2.stereoRectify decides, on the same vector: a rig judged by cam1's
        # centre alone was rectified top/bottom near 45 deg, its rows 50 px apart
        if (problem := unsupported_layout(rig)) is not None:
            raise RectifyError(
                f"rectification: {problem}; only side-by-side rigs are rectified (mount "
                "cam1 beside cam0, or check T_cn_cnm1 in the calibration)"
            )
        turns = quarter_turns(rig)
        turn = rotation_z(turns)
        zero = np.zeros(5)
        r0, r1_virtual, *_ = cv2.stereoRectify(
            rig.cam0.K, zero, rig.cam1.K, zero, size, turn @ rig.R, (turn @ rig.t).reshape(3, 1),
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1,
        )  # fmt: skip
        rotations = np.stack([np.asarray(r0), np.asarray(r1_virtual) @ turn])
        rectified_t = rotations[1] @ rig.t
        # OpenCV picks the axis itself; rows agree only if it put the baseline along x,
        # where its x is the whole baseline (y: about none of it, whence the 0.9)
        if abs(rectified_t[0]) < 0.9 * rig.baseline_m:
            raise RectifyError(
                f"rectification: cv2.stereoRectify put the {rig.baseline_m:.4f} m baseline "
                f"at {np.round(-rectified_t, 4).tolist()} m, not along the rows; only "
                "side-by-side rigs are rectified (check T_cn_cnm1 in the calibration)"
            )
        turned = float(np.degrees(np.arccos(np.clip(rotations[0][2, 2], -1.0, 1.0))))
        outlines = [
            outline.raw_border(rig.camera(name), rotations[index], name, turned)
            for index, name in enumerate(("cam0", "cam1"))
        ]
        everything = np.concatenate(outlines)
        low, high = everything.min(axis=0), everything.max(axis=0)
        # alpha = 1: the bounding box of both raw images, contained whole
        f_loose = min(size[0] / (high[0] - low[0]), size[1] / (high[1] - low[1]))
        loose = camera_matrix(f_loose, (low + high) / 2, size)
        tight = _alpha_zero(rig, rotations, outlines, size) if alpha < 1.0 else loose
        K = (1 - alpha) * tight + alpha * loose
        baseline = float(-rectified_t[0])
        return cls(rig, rotations, K, tuple(size), baseline, turns, alpha)  # type: ignore[arg-type]

    def _index(self, view: View) -> int:
        if view not in ("cam0", "cam1"):
            raise ValueError(f"view must be 'cam0' or 'cam1', got {view!r}")
        return 0 if view == "cam0" else 1

    def rotation(self, view: View) -> np.ndarray:
        """Rectifying rotation of ``view`` (OpenCV's ``R1``/``R2``), ``(3, 3)`` float64."""
        return np.array(self.rotations[self._index(view)], dtype=np.float64)

    def projection(self, view: View) -> np.ndarray:
        """Rectified projection matrix (OpenCV's ``P1``/``P2``), ``(3, 4)`` float64."""
        P = np.zeros((3, 4))
        P[:, :3] = self.K
        if self._index(view) == 1:
            P[0, 3] = -self.K[0, 0] * self.baseline_m
        return P

    def rectified_to_raw(self, view: View, points_xy: np.ndarray) -> np.ndarray:
        """Map rectified pixel coordinates of ``view`` to raw (distorted) pixel coordinates.

        Args:
            view: ``cam0`` or ``cam1``.
            points_xy: ``(..., 2)`` rectified pixel coordinates, any float dtype.

        Returns:
            ``(..., 2)`` float32 raw pixel coordinates; NaN where no raw ray exists.

        """
        index = self._index(view)
        return _rectified_to_raw(self.rig.camera(view), self.rotations[index], self.K, points_xy)

    raw_coordinates = rectified_to_raw

    def raw_to_rectified(self, view: View, points_xy: np.ndarray) -> np.ndarray:
        """Map raw pixel coordinates of ``view`` to rectified pixel coordinates.

        Args:
            view: ``cam0`` or ``cam1``.
            points_xy: ``(..., 2)`` raw pixel coordinates.

        Returns:
            ``(..., 2)`` float64 rectified pixel coordinates; NaN behind the rectified plane.

        """
        rays = pixel_rays(self.rig.camera(view), points_xy) @ self.rotations[self._index(view)].T
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(rays[..., 2:] > 1e-9, rays[..., 2:], np.nan)
            xy = rays[..., :2] / z
        return np.asarray(xy * self.K[0, 0] + self.K[[0, 1], [2, 2]], dtype=np.float64)

    def maps(self, view: View) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps from the rectified image of ``view`` to its raw image.

        Returns:
            ``(map_x, map_y)``, each ``(H, W)`` float32 raw pixel coordinates
            for the rectified grid of :attr:`size`; :data:`OUTSIDE` where no
            raw ray exists.

        """
        width, height = self.size
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
        raw = self.rectified_to_raw(view, np.stack([xs, ys], axis=-1))
        raw[~np.isfinite(raw)] = OUTSIDE
        return np.ascontiguousarray(raw[..., 0]), np.ascontiguousarray(raw[..., 1])

    def valid_region(self, view: View) -> np.ndarray:
        """Rectified pixels of ``view`` whose bilinear source lies inside the raw image.

        Returns:
            ``(H, W)`` bool mask over the rectified grid of :attr:`size`.

        """
        map_x, map_y = self.maps(view)
        return _inside(np.stack([map_x, map_y], axis=-1), self.rig.camera(view).resolution)

    def rectify(self, view: View, image: np.ndarray) -> np.ndarray:
        """Resample a raw image of ``view`` into its rectified view (bilinear, black outside)."""
        map_x, map_y = self.maps(view)
        return np.asarray(cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderValue=0))


def row_differences(
    rectification: StereoRectification, points0: np.ndarray, points1: np.ndarray
) -> np.ndarray:
    """Rectified row of each matched point in cam0 minus its row in cam1.

    Args:
        rectification: the rectification to judge.
        points0: ``(N, 2)`` raw pixel coordinates in cam0.
        points1: ``(N, 2)`` raw pixel coordinates of the same points in cam1.

    Returns:
        ``(N,)`` float64 ``y0 - y1`` in rectified pixels.

    """
    y0 = rectification.raw_to_rectified("cam0", points0)[..., 1]
    y1 = rectification.raw_to_rectified("cam1", points1)[..., 1]
    return np.asarray(y0 - y1, dtype=np.float64)


def row_disagreement(
    rectification: StereoRectification, points0: np.ndarray, points1: np.ndarray
) -> float:
    """RMS of :func:`row_differences` (rectified pixels); 0 for perfectly aligned rows."""
    differences = row_differences(rectification, points0, points1)
    if differences.size == 0:
        raise RectifyError("row disagreement: no matched points")
    return float(np.sqrt(np.mean(differences**2)))


def on_camera(rig: StereoRig, camera: View) -> "StereoRectification":
    """The rectification on ``camera``'s pixels: its resolution, about its scale (alpha 0).

    ``capture-ingest`` rectifies on the obstructed camera's: its frames are
    what the network restores, at their own scale. Of a rig whose cameras
    differ in resolution, a grid of cam0's size enlarged a coarser
    obstructed camera or aliased a finer one.
    """
    return StereoRectification.from_rig(rig, size=rig.camera(camera).resolution)
