"""The OpenCV calls behind :mod:`lenspair.rectify.calibration`, where OpenCV 4/5 differences live.

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

from lenspair.rectify.boards import Board, Detection
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rectification import pixel_rays, project_rays
from lenspair.rectify.rig import CameraModel, DistortionModel

CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
MIN_COMMON = 6
"""Corners both cameras must share for a view to count in the stereo step."""
Points = tuple[np.ndarray, np.ndarray, np.ndarray]
"""One stereo view: object points ``(N, 3)``, cam0 and cam1 pixels ``(N, 2)``, float64."""


def fisheye_flag(name: str) -> int:
    """Value of a ``cv2.fisheye`` flag such as ``CALIB_FIX_INTRINSIC`` in this OpenCV."""
    # OpenCV 4.x: cv2.fisheye.CALIB_*, with values of its own; OpenCV 5: the shared cv2.CALIB_*.
    value = getattr(cv2.fisheye, name, None)
    return int(value if value is not None else getattr(cv2, name))


def rms(residuals: np.ndarray) -> float:
    """RMS of the Euclidean norms of ``(..., 2)`` residuals, pixels."""
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=-1))))


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
            objects = [o.reshape(1, -1, 3).astype(np.float64) for o, _ in points]
            images = [i.reshape(1, -1, 2).astype(np.float64) for _, i in points]
            flags = fisheye_flag("CALIB_RECOMPUTE_EXTRINSIC") | fisheye_flag("CALIB_FIX_SKEW")
            _, K, D, rvecs, tvecs = cv2.fisheye.calibrate(
                objects, images, size, np.eye(3), np.zeros(4), flags=flags, criteria=CRITERIA
            )
    except cv2.error as exc:
        raise RectifyError(
            f"single-camera calibration failed: {str(exc).strip().splitlines()[-1]}"
        ) from None
    camera = _as_camera(K, D, model, size)
    return camera, np.asarray(rvecs).reshape(-1, 3), np.asarray(tvecs).reshape(-1, 3)


INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "d0", "d1", "d2", "d3")
"""What :func:`intrinsic_std` returns the deviation of, in this order (``d*``: the
four distortion coefficients, radtan ``k1 k2 p1 p2`` or equidistant ``k1..k4``)."""


def intrinsic_std(
    camera: CameraModel,
    points: list[tuple[np.ndarray, np.ndarray]],
    rvecs: np.ndarray,
    tvecs: np.ndarray,
) -> np.ndarray:
    """1-sigma standard deviations of a fitted camera's intrinsics, from its residuals.

    The covariance of the least-squares fit, ``s^2 (J^T J)^-1``, with ``J`` the
    Jacobian of every corner's projection in the intrinsics and every view's
    pose (OpenCV's ``projectPoints`` / ``fisheye.projectPoints`` compute it)
    and ``s^2`` the residual variance per coordinate. For radtan this is what
    ``cv2.calibrateCameraExtended`` reports (``stdDeviationsIntrinsics``);
    ``cv2.fisheye.calibrate`` reports none, and one function serves both.
    It measures the noise of the corners, not a model or board spec that is
    wrong: a far or barely tilted board shows here as a large deviation.

    Args:
        camera: the fitted camera (radtan with ``k3 = 0``, or equidistant with skew 0).
        points: the views it was fitted to: object points ``(N, 3)``, pixels ``(N, 2)``.
        rvecs: ``(V, 3)`` the fitted board rotations (Rodrigues vectors).
        tvecs: ``(V, 3)`` the fitted board translations.

    Returns:
        ``(8,)``: see :data:`INTRINSIC_NAMES`; pixels for ``f`` and ``c``.
    """
    fx, fy, cx, cy = camera.intrinsics
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    D = np.asarray(camera.distortion, np.float64)
    count = len(INTRINSIC_NAMES)
    # J^T J has an intrinsics block A, a 6x6 block C_k per view and couplings B_k:
    # the intrinsics' block of its inverse is (A - sum B_k C_k^-1 B_k^T)^-1 (Schur
    # complement), without forming J (a dense J of 1000 views would take gigabytes)
    reduced = np.zeros((count, count))
    squared, rows = 0.0, 0
    try:
        for k, (obj, img) in enumerate(points):
            rvec, tvec = np.asarray(rvecs[k], np.float64), np.asarray(tvecs[k], np.float64)
            if camera.distortion_model == "radtan":  # columns: r, t, f, c, dist
                projected, J = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, D)
                intrinsic, pose = J[:, 6:14], J[:, 0:6]
            else:  # columns: f, c, k1..k4, r, t, skew (fixed at 0: left out)
                projected, J = cv2.fisheye.projectPoints(
                    obj.reshape(1, -1, 3), rvec, tvec, K, D, alpha=0.0
                )
                intrinsic, pose = J[:, 0:8], J[:, 8:14]
            coupling = intrinsic.T @ pose
            reduced += intrinsic.T @ intrinsic - coupling @ np.linalg.solve(
                pose.T @ pose, coupling.T
            )
            residuals = projected.reshape(-1) - img.reshape(-1)
            squared += float(residuals @ residuals)
            rows += len(residuals)
        freedom = rows - count - 6 * len(points)
        if freedom <= 0:
            return np.full(count, np.inf)
        covariance = squared / freedom * np.linalg.inv(reduced)
    except np.linalg.LinAlgError:  # a parameter or pose the views do not constrain at all
        return np.full(count, np.inf)
    deviations: np.ndarray = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    return deviations


def view_error(
    camera: CameraModel, obj: np.ndarray, img: np.ndarray, rvec: np.ndarray, tvec: np.ndarray
) -> float:
    """RMS reprojection error of one view at pose ``(rvec, tvec)``, pixels."""
    rotation = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))[0]
    projected = project_rays(camera, obj @ rotation.T + np.asarray(tvec).reshape(3))
    return rms(np.nan_to_num(projected - img, nan=1e6))


def board_pose(camera: CameraModel, obj: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """4x4 board -> camera transform from one view (PnP on undistorted rays)."""
    rays = np.ascontiguousarray(pixel_rays(camera, corners)[:, :2])
    _, rvec, tvec = cv2.solvePnP(obj, rays, np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = np.asarray(tvec).ravel()
    return pose


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between the rotation parts of ``a`` and ``b``, degrees."""
    cosine = (np.trace(a[:3, :3] @ b[:3, :3].T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def match_views(
    pairs: dict[int, tuple[Detection, Detection]],
    board: Board,
    cameras: tuple[CameraModel, CameraModel],
    tolerance_deg: float,
) -> tuple[dict[int, Points], dict[int, str]]:
    """Corner correspondences per view, with cam1's numbering chosen to agree with the rig.

    Each view gives one candidate cam0 -> cam1 transform per board symmetry
    (board pose in cam1 times the inverse pose in cam0); the true transform is
    the one most views agree on, and each view keeps its candidate closest to it.

    Args:
        pairs: view index -> (cam0, cam1) detections.
        board: the board (object points, symmetries).
        cameras: calibrated cam0 and cam1.
        tolerance_deg: a view whose best candidate rotation is further than
            this from the consensus is refused.

    Returns:
        ``(matched, refused)``: view -> matched points, and view -> reason.

    """
    objects = board.object_points()
    candidates: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for view, (d0, d1) in pairs.items():
        pose0 = board_pose(cameras[0], objects[d0.ids], d0.corners)
        candidates[view] = []
        for perm in board.symmetries():
            ids1 = perm[d1.ids]
            pose1 = board_pose(cameras[1], objects[ids1], d1.corners)
            candidates[view].append((ids1, pose1 @ np.linalg.inv(pose0)))
    tolerance = tolerance_deg
    everything = [relative for cands in candidates.values() for _, relative in cands]
    support = [
        sum(
            any(angle_deg(c, other) < tolerance for _, other in cands)
            for cands in candidates.values()
        )
        for c in everything
    ]
    consensus = everything[int(np.argmax(support))]
    matched: dict[int, Points] = {}
    refused: dict[int, str] = {}
    for view, cands in candidates.items():
        angles = [angle_deg(relative, consensus) for _, relative in cands]
        best = int(np.argmin(angles))
        if angles[best] > tolerance:
            reason = (
                f"cam0->cam1 rotation from this view's board poses is {angles[best]:.1f} deg off "
                "the other views (board moved between exposures, or a false detection)"
            )
            refused[view] = reason
            continue
        d0, d1 = pairs[view]
        common, index0, index1 = np.intersect1d(d0.ids, cands[best][0], return_indices=True)
        if len(common) < MIN_COMMON:
            refused[view] = f"only {len(common)} corners seen by both cameras (need {MIN_COMMON})"
            continue
        matched[view] = (objects[common], d0.corners[index0], d1.corners[index1])
    return matched, refused


def fit_stereo(
    data: list[Points],
    cameras: tuple[CameraModel, CameraModel],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``cv2.(fisheye.)stereoCalibrate`` with intrinsics fixed; returns T (4x4), rvecs, tvecs.

    ``cv2.fisheye.stereoCalibrate`` fails when views hold different numbers of
    corners (OpenCV issue 21748: partial ChArUco views). Then, as the
    intrinsics are fixed anyway, the corners are undistorted exactly and the
    pinhole ``cv2.stereoCalibrate`` runs on them with zero distortion.
    """
    objects = [o.astype(np.float64) for o, _, _ in data]
    images = [
        [a.astype(np.float64) for _, a, _ in data],
        [b.astype(np.float64) for _, _, b in data],
    ]
    (K0, D0), (K1, D1) = ((c.K, c.dist_coeffs) for c in cameras)
    fisheye = cameras[0].distortion_model == "equidistant"
    if fisheye and len({len(o) for o in objects}) > 1:
        for index, camera in enumerate(cameras):
            images[index] = [pixel_rays(camera, i) @ camera.K[:2].T for i in images[index]]
        D0, D1, fisheye = np.zeros(5), np.zeros(5), False
    result: Any
    try:
        if not fisheye:
            result = cv2.stereoCalibrateExtended(
                [o.astype(np.float32) for o in objects],
                [i.astype(np.float32) for i in images[0]],
                [i.astype(np.float32) for i in images[1]],
                K0, D0, K1, D1, cameras[0].resolution, np.eye(3), np.zeros(3),
                flags=cv2.CALIB_FIX_INTRINSIC, criteria=CRITERIA,
            )  # fmt: skip
            R, t, rvecs, tvecs = result[5], result[6], result[9], result[10]
        else:  # OpenCV 5 wants (1, N, C) arrays here, not (N, 1, C)
            result = cv2.fisheye.stereoCalibrate(
                [o.reshape(1, -1, 3) for o in objects],
                [i.reshape(1, -1, 2) for i in images[0]],
                [i.reshape(1, -1, 2) for i in images[1]],
                K0, D0, K1, D1, cameras[0].resolution,
                flags=fisheye_flag("CALIB_FIX_INTRINSIC"), criteria=CRITERIA,
            )  # fmt: skip
            R, t, rvecs, tvecs = result[5], result[6], result[7], result[8]
    except cv2.error as exc:
        message = str(exc).strip().splitlines()[-1]
        raise RectifyError(f"stereo calibration failed: {message}") from None
    transform = np.eye(4)
    transform[:3, :3] = np.asarray(R, dtype=np.float64)
    transform[:3, 3] = np.asarray(t, dtype=np.float64).ravel()
    return transform, np.asarray(rvecs).reshape(-1, 3), np.asarray(tvecs).reshape(-1, 3)


def stereo_residuals(
    item: Points,
    cameras: tuple[CameraModel, CameraModel],
    transform: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
) -> np.ndarray:
    """Residuals ``(2N, 2)`` of one view in both cameras for the cam0 pose ``(rvec, tvec)``."""
    obj, img0, img1 = item
    in_cam0 = obj @ cv2.Rodrigues(rvec)[0].T + tvec
    in_cam1 = in_cam0 @ transform[:3, :3].T + transform[:3, 3]
    residuals = [project_rays(cameras[0], in_cam0) - img0, project_rays(cameras[1], in_cam1) - img1]
    return np.asarray(np.nan_to_num(np.concatenate(residuals), nan=1e6))
