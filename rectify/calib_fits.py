"""The OpenCV fits behind :mod:`lenspair.rectify.calibration`, where OpenCV 4/5 differences live.

:func:`fit_camera` calibrates one camera, :func:`fit_stereo` the rig (with
the intrinsics fixed, or refined with it where :func:`refinable`). The
covariances of what they fit are in :mod:`~lenspair.rectify.calib_uncertainty`,
board poses and reprojection errors per view in
:mod:`~lenspair.rectify.calib_views`.

* ``cv2.fisheye`` flags are ``cv2.fisheye.CALIB_*`` in OpenCV 4 and the shared
  ``cv2.CALIB_*`` (other values) in OpenCV 5: :func:`fisheye_flag`.
* OpenCV 5's ``cv2.fisheye.calibrate`` / ``stereoCalibrate`` reject
  ``(N, 1, C)`` point arrays (OpenCV issue 29692): points go in as ``(1, N, C)``.
* ``cv2.fisheye.stereoCalibrate`` fails when views hold different numbers of
  corners (OpenCV issue 21748): see :func:`fit_stereo`.
* Without ``CALIB_RECOMPUTE_EXTRINSIC`` ``cv2.fisheye.calibrate`` often
  converges to a wrong solution (OpenCV issue 23962); it is always set.
"""

from typing import Any

import cv2
import numpy as np

from lenspair.rectify.calib_views import Points
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.projection import pixel_rays
from lenspair.rectify.rig import CameraModel, DistortionModel

CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def fisheye_flag(name: str) -> int:
    """Value of a ``cv2.fisheye`` flag such as ``CALIB_FIX_INTRINSIC`` in this OpenCV."""
    # OpenCV 4.x: cv2.fisheye.CALIB_*, with values of its own; OpenCV 5: the shared cv2.CALIB_*.
    value = getattr(cv2.fisheye, name, None)
    return int(value if value is not None else getattr(cv2, name))


def _as_camera(
    K: np.ndarray, D: np.ndarray, model: DistortionModel, size: tuple[int, int]
) -> CameraModel:
    d = np.asarray(D, dtype=np.float64).ravel()
    intrinsics = (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
    try:
        return CameraModel(intrinsics, model, tuple(float(v) for v in d[:4]), size)  # type: ignore[arg-type]
    except ValueError as exc:
        raise RectifyError(f"calibration diverged: {exc}") from None


def fit_camera(
    points: list[tuple[np.ndarray, np.ndarray]], model: DistortionModel, size: tuple[int, int]
) -> tuple[CameraModel, np.ndarray, np.ndarray]:
    """One single-camera calibration (k3 = 0 for radtan; skew 0 for equidistant).

    Args:
        points: per view, object points ``(N, 3)`` and image points ``(N, 2)``.
        model: ``radtan`` or ``equidistant``.
        size: image ``(width, height)``.

    Returns:
        The camera and the per-view board poses: ``rvecs``, ``tvecs`` ``(V, 3)``.

    Raises:
        RectifyError: OpenCV failed or returned a non-finite camera.

    """
    try:
        if model == "radtan":
            objects = [o.astype(np.float32) for o, _ in points]
            images = [i.astype(np.float32) for _, i in points]
            flags = cv2.CALIB_FIX_K3
            _, K, D, rvecs, tvecs = cv2.calibrateCamera(
                objects, images, size, None, None, flags=flags, criteria=CRITERIA
            )
        else:
            K, D, rvecs, tvecs = _fit_fisheye(points, size)
    except cv2.error as exc:
        raise RectifyError(
            f"single-camera calibration failed: {str(exc).strip().splitlines()[-1]}"
        ) from None
    camera = _as_camera(K, D, model, size)
    return camera, np.asarray(rvecs).reshape(-1, 3), np.asarray(tvecs).reshape(-1, 3)


FISHEYE_FOCAL_GUESSES = (1.0, 1.3, 0.8)
"""Starting focal lengths tried when ``cv2.fisheye.calibrate``'s own start fails, as
multiples of ``max(width, height) / pi`` (an equidistant lens seeing 180 degrees across
the longer side)."""

RETRY_MAX_RMS_PX = 5.0
"""A fit from another start with a larger RMS reprojection error is no fit: started far
from the lens, ``cv2.fisheye.calibrate`` also "converges" to errors of tens of pixels."""

Fit = tuple[float, np.ndarray, np.ndarray, Any, Any]
"""``cv2.fisheye.calibrate``'s answer: RMS, ``K``, ``D``, ``rvecs``, ``tvecs``."""


def _sound(fit: Fit) -> bool:
    rms_px, K, D, _, _ = fit
    return bool(
        np.isfinite(rms_px) and np.isfinite(K).all() and np.isfinite(D).all()
        and K[0, 0] > 0 and K[1, 1] > 0
    )  # fmt: skip


def _fit_fisheye(
    points: list[tuple[np.ndarray, np.ndarray]], size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, Any, Any]:
    """``cv2.fisheye.calibrate``: ``K, D, rvecs, tvecs``; raises ``cv2.error`` when no start fits.

    OpenCV starts from its own guess, which fails on lenses wider than about
    165 degrees once the board reaches far off axis, as the coverage advice
    asks (``InitExtrinsics``: "fabs(norm_u1) > 0"), or ends at a camera with
    a negative focal length or no finite error. Then the fit starts again
    from each focal length such lenses have (:data:`FISHEYE_FOCAL_GUESSES`,
    centred), and the fit with the least RMS error is taken among those that
    give a camera and an error under :data:`RETRY_MAX_RMS_PX`; the later
    checks of the fit judge it as any other. With none, OpenCV's own answer
    stands: its error, or its unsound camera for those checks to refuse.
    """
    objects = [o.reshape(1, -1, 3).astype(np.float64) for o, _ in points]
    images = [i.reshape(1, -1, 2).astype(np.float64) for _, i in points]
    flags = fisheye_flag("CALIB_RECOMPUTE_EXTRINSIC") | fisheye_flag("CALIB_FIX_SKEW")
    first: Fit | cv2.error
    try:
        first = cv2.fisheye.calibrate(
            objects, images, size, np.eye(3), np.zeros(4), flags=flags, criteria=CRITERIA
        )
    except cv2.error as exc:
        first = exc
    if not isinstance(first, cv2.error) and _sound(first):
        return first[1:]
    guess = flags | fisheye_flag("CALIB_USE_INTRINSIC_GUESS")
    fits: list[Fit] = []
    for scale in FISHEYE_FOCAL_GUESSES:
        focal = scale * max(size) / np.pi
        start = np.array([[focal, 0, (size[0] - 1) / 2], [0, focal, (size[1] - 1) / 2], [0, 0, 1]])
        try:
            fit = cv2.fisheye.calibrate(
                objects, images, size, start, np.zeros(4), flags=guess, criteria=CRITERIA
            )
        except cv2.error:
            continue
        if _sound(fit) and fit[0] <= RETRY_MAX_RMS_PX:
            fits.append(fit)
    if fits:
        return min(fits, key=lambda fit: fit[0])[1:]
    if isinstance(first, cv2.error):
        raise first
    return first[1:]


def refinable(data: list[Points], cameras: tuple[CameraModel, CameraModel]) -> bool:
    """Whether :func:`fit_stereo` can refine the intrinsics on these views.

    Not for equidistant cameras whose views hold different numbers of corners
    (partial ChArUco views): ``cv2.fisheye.stereoCalibrate`` fails on them
    (OpenCV issue 21748) and the fit runs on undistorted corners instead.
    """
    return cameras[0].distortion_model != "equidistant" or len({len(o) for o, _, _ in data}) == 1


def fit_stereo(
    data: list[Points],
    cameras: tuple[CameraModel, CameraModel],
    refine: bool = False,
) -> tuple[tuple[CameraModel, CameraModel], np.ndarray, np.ndarray, np.ndarray]:
    """``cv2.(fisheye.)stereoCalibrate``; returns the cameras, T (4x4), rvecs, tvecs.

    Without ``refine`` the intrinsics stay fixed and the cameras come back
    unchanged; with it (where :func:`refinable`) they are refined with the rig,
    starting from ``cameras`` (``k3`` stays 0 and the skew 0, as in the
    single-camera fits).

    ``cv2.fisheye.stereoCalibrate`` fails when views hold different numbers of
    corners (OpenCV issue 21748: partial ChArUco views). Then, as the
    intrinsics are fixed anyway, the corners are undistorted exactly and the
    pinhole ``cv2.stereoCalibrate`` runs on them with zero distortion.
    """
    if refine and not refinable(data, cameras):
        raise ValueError("fit_stereo: these views cannot refine the intrinsics (see refinable)")
    objects = [o.astype(np.float64) for o, _, _ in data]
    images = [
        [a.astype(np.float64) for _, a, _ in data],
        [b.astype(np.float64) for _, _, b in data],
    ]
    (K0, D0), (K1, D1) = ((c.K, c.dist_coeffs) for c in cameras)
    fisheye = cameras[0].distortion_model == "equidistant"
    if fisheye and not refinable(data, cameras):
        for index, camera in enumerate(cameras):
            images[index] = [pixel_rays(camera, i) @ camera.K[:2].T for i in images[index]]
        D0, D1, fisheye = np.zeros(5), np.zeros(5), False
    result: Any
    try:
        if not fisheye:
            flags = (
                cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3
                if refine
                else cv2.CALIB_FIX_INTRINSIC
            )
            result = cv2.stereoCalibrateExtended(
                [o.astype(np.float32) for o in objects],
                [i.astype(np.float32) for i in images[0]],
                [i.astype(np.float32) for i in images[1]],
                K0, D0, K1, D1, cameras[0].resolution, np.eye(3), np.zeros(3),
                flags=flags, criteria=CRITERIA,
            )  # fmt: skip
            R, t, rvecs, tvecs = result[5], result[6], result[9], result[10]
        else:  # OpenCV 5 wants (1, N, C) arrays here, not (N, 1, C)
            flags = (
                fisheye_flag("CALIB_USE_INTRINSIC_GUESS") | fisheye_flag("CALIB_FIX_SKEW")
                if refine
                else fisheye_flag("CALIB_FIX_INTRINSIC")
            )
            result = cv2.fisheye.stereoCalibrate(
                [o.reshape(1, -1, 3) for o in objects],
                [i.reshape(1, -1, 2) for i in images[0]],
                [i.reshape(1, -1, 2) for i in images[1]],
                K0, D0, K1, D1, cameras[0].resolution, flags=flags, criteria=CRITERIA,
            )  # fmt: skip
            R, t, rvecs, tvecs = result[5], result[6], result[7], result[8]
    except cv2.error as exc:
        message = str(exc).strip().splitlines()[-1]
        raise RectifyError(f"stereo calibration failed: {message}") from None
    if refine:
        model = cameras[0].distortion_model
        cameras = (
            _as_camera(result[1], result[2], model, cameras[0].resolution),
            _as_camera(result[3], result[4], model, cameras[1].resolution),
        )
    transform = np.eye(4)
    transform[:3, :3] = np.asarray(R, dtype=np.float64)
    transform[:3, 3] = np.asarray(t, dtype=np.float64).ravel()
    return cameras, transform, np.asarray(rvecs).reshape(-1, 3), np.asarray(tvecs).reshape(-1, 3)
