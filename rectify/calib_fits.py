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

from dataclasses import dataclass
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
"""The intrinsics :func:`intrinsic_covariance` is the covariance of, in this order (``d*``: the
four distortion coefficients, radtan ``k1 k2 p1 p2`` or equidistant ``k1..k4``)."""


def intrinsic_covariance(
    camera: CameraModel,
    points: list[tuple[np.ndarray, np.ndarray]],
    rvecs: np.ndarray,
    tvecs: np.ndarray,
) -> np.ndarray:
    """Covariance of a fitted camera's intrinsics, from its residuals.

    The covariance of the least-squares fit, ``s^2 (J^T J)^-1``, with ``J`` the
    Jacobian of every corner's projection in the intrinsics and every view's
    pose (OpenCV's ``projectPoints`` / ``fisheye.projectPoints`` compute it)
    and ``s^2`` the residual variance per coordinate. For radtan the square
    roots of its diagonal are what ``cv2.calibrateCameraExtended`` reports
    (``stdDeviationsIntrinsics``); ``cv2.fisheye.calibrate`` reports none, and
    one function serves both. It measures the noise of the corners, not a
    model or board spec that is wrong: a far or barely tilted board shows here
    as a large deviation.

    Args:
        camera: the fitted camera (radtan with ``k3 = 0``, or equidistant with skew 0).
        points: the views it was fitted to: object points ``(N, 3)``, pixels ``(N, 2)``.
        rvecs: ``(V, 3)`` the fitted board rotations (Rodrigues vectors).
        tvecs: ``(V, 3)`` the fitted board translations.

    Returns:
        ``(8, 8)`` in the order of :data:`INTRINSIC_NAMES`; pixels for ``f`` and ``c``.
    """
    views = [
        _Observations([(_projected(camera, obj, rvecs[k], tvecs[k]), img, 0)], None)
        for k, (obj, img) in enumerate(points)
    ]
    information, variance = _information(views, len(INTRINSIC_NAMES))
    return _inverse(information, variance)


def deviations(covariance: np.ndarray) -> np.ndarray:
    """1-sigma deviations: the square roots of a covariance's diagonal."""
    spread: np.ndarray = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    return spread


@dataclass
class _Observations:
    """One board view's corners in one or both cameras, for :func:`_covariance`.

    ``seen``: per camera that saw it, ``(projection, pixels, column)``: the
    projection at the estimate with its Jacobians, the measured pixels ``(N, 2)``,
    and the first column of that camera's intrinsics among the shared parameters.
    ``stereo``: for a cam1 projection through the rig, the derivatives of the
    cam1 pose in the cam0 pose and in the rig's ``(r, t)`` (shared columns
    ``-6:``); None for a view fitted in one camera.
    """

    seen: list[tuple["_Projection", np.ndarray, int]]
    stereo: tuple[np.ndarray, np.ndarray] | None


@dataclass
class _Projection:
    """Projected corners ``(2N,)`` and their Jacobians.

    In the intrinsics ``(2N, 8)`` (order :data:`INTRINSIC_NAMES`) and in the
    board pose ``(2N, 6)`` (``r``, ``t``).
    """

    points: np.ndarray
    intrinsic: np.ndarray
    pose: np.ndarray


def _projected(
    camera: CameraModel, obj: np.ndarray, rvec: np.ndarray, tvec: np.ndarray
) -> _Projection:
    K, D = camera.K, np.asarray(camera.distortion, np.float64)  # D: the 4 fitted (no k3)
    rvec, tvec = np.asarray(rvec, np.float64).ravel(), np.asarray(tvec, np.float64).ravel()
    if camera.distortion_model == "radtan":  # columns: r, t, f, c, dist
        points, J = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, D)
        return _Projection(points.reshape(-1), J[:, 6:14], J[:, 0:6])
    # columns: f, c, k1..k4, r, t, skew (fixed at 0: left out)
    points, J = cv2.fisheye.projectPoints(obj.reshape(1, -1, 3), rvec, tvec, K, D, alpha=0.0)
    return _Projection(points.reshape(-1), J[:, 0:8], J[:, 8:14])


def _information(views: list[_Observations], shared: int) -> tuple[np.ndarray, float]:
    """``J^T J`` of the parameters the views share, their poses eliminated, and ``s^2``.

    ``J^T J`` has a shared block ``A``, a 6x6 block ``C_k`` per view's pose and
    couplings ``B_k``; the shared block of its inverse is the inverse of
    ``A - sum B_k C_k^-1 B_k^T`` (Schur complement), returned here, without
    forming ``J`` (a dense ``J`` of 1000 views would take gigabytes). ``s^2``
    is the residual variance per coordinate (infinite without degrees of
    freedom left).
    """
    reduced = np.zeros((shared, shared))
    squared, rows = 0.0, 0
    for view in views:
        blocks_shared, blocks_pose = [], []
        for projection, pixels, column in view.seen:
            block = np.zeros((len(projection.points), shared))
            block[:, column : column + 8] = projection.intrinsic
            pose = projection.pose
            if view.stereo is not None and column > 0:  # cam1, through the rig
                in_pose, in_rig = view.stereo
                block[:, -6:] = pose @ in_rig
                pose = pose @ in_pose
            blocks_shared.append(block)
            blocks_pose.append(pose)
            residuals = projection.points - pixels.reshape(-1)
            squared += float(residuals @ residuals)
            rows += len(residuals)
        J_shared, J_pose = np.concatenate(blocks_shared), np.concatenate(blocks_pose)
        coupling = J_shared.T @ J_pose
        try:
            reduced += J_shared.T @ J_shared - coupling @ np.linalg.solve(
                J_pose.T @ J_pose, coupling.T
            )
        except np.linalg.LinAlgError:  # a pose the view does not constrain
            reduced[:] = 0.0
            break
    freedom = rows - shared - 6 * len(views)
    return reduced, squared / freedom if freedom > 0 else np.inf


def _inverse(information: np.ndarray, variance: float) -> np.ndarray:
    """``variance * information^-1``; infinite where the views leave a parameter free."""
    try:
        if np.isfinite(variance):
            inverse: np.ndarray = variance * np.linalg.inv(information)
            return inverse
    except np.linalg.LinAlgError:
        pass
    return np.full(information.shape, np.inf)


@dataclass(frozen=True, eq=False)
class RigDeviations:
    """How well the corners determine a calibrated rig.

    Attributes:
        covariance: ``(22, 22)``: cam0's intrinsics, cam1's (each in the order of
            :data:`INTRINSIC_NAMES`), the rig's rotation vector and translation.
        baseline_m: the baseline's 1-sigma deviation, metres (inf: undetermined).
    """

    covariance: np.ndarray
    baseline_m: float

    def intrinsics(self, camera: int) -> np.ndarray:
        """``(8, 8)`` covariance of cam0's (0) or cam1's (1) intrinsics."""
        block: np.ndarray = self.covariance[
            8 * camera : 8 * camera + 8, 8 * camera : 8 * camera + 8
        ]
        return block


def rig_deviations(
    cameras: tuple[CameraModel, CameraModel],
    stereo: list[tuple[Points, np.ndarray, np.ndarray]],
    transform: np.ndarray,
    own: tuple[np.ndarray, np.ndarray] | None = None,
) -> RigDeviations:
    """How well the corners determine a rig, as it was fitted.

    The parameters the views share are both cameras' intrinsics and the rig's
    rotation and translation; each view gives its corners in both cameras at
    one board pose (cam1's through the rig, derivatives from ``cv2.composeRT``).

    Args:
        cameras: cam0, cam1.
        stereo: the views of the stereo fit: ``(object, cam0 pixels, cam1
            pixels)`` and the cam0 board pose ``rvec``, ``tvec``.
        transform: 4x4 cam0 -> cam1.
        own: None for intrinsics refined with the rig on these views
            (:func:`fit_stereo` ``refine``); else each camera's intrinsics
            covariance from its own fit (:func:`intrinsic_covariance`), held fixed
            in the stereo fit: their errors then reach the rig through its
            dependence on them, ``M_rr^-1 M_ri`` (the two fits' shared corners
            are taken as independent).

    Returns:
        The covariance and the baseline's deviation; the intrinsics' are ``own``
        when given.
    """
    rig_r = cv2.Rodrigues(np.ascontiguousarray(transform[:3, :3]))[0].ravel()
    rig_t = np.ascontiguousarray(transform[:3, 3])
    views: list[_Observations] = []
    for (obj, pixels0, pixels1), rvec, tvec in stereo:
        rvec, tvec = np.asarray(rvec, np.float64).ravel(), np.asarray(tvec, np.float64).ravel()
        r1, t1, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = cv2.composeRT(
            rvec, tvec, rig_r, rig_t
        )
        seen = [
            (_projected(cameras[0], obj, rvec, tvec), pixels0, 0),
            (_projected(cameras[1], obj, r1, t1), pixels1, 8),
        ]
        in_pose = np.block([[dr3dr1, dr3dt1], [dt3dr1, dt3dt1]])
        in_rig = np.block([[dr3dr2, dr3dt2], [dt3dr2, dt3dt2]])
        views.append(_Observations(seen, (in_pose, in_rig)))
    information, variance = _information(views, 22)
    if own is None:
        covariance = _inverse(information, variance)
    else:
        held = np.zeros((16, 16))
        held[:8, :8], held[8:, 8:] = own
        covariance = np.zeros((22, 22))
        covariance[:16, :16] = held
        rig_only = _inverse(information[16:, 16:], variance)
        try:
            follows = np.linalg.solve(information[16:, 16:], information[16:, :16])
            covariance[16:, 16:] = rig_only + follows @ held @ follows.T
        except np.linalg.LinAlgError:
            covariance[16:, 16:] = np.inf
    direction = rig_t / np.linalg.norm(rig_t)
    translation = covariance[-3:, -3:]
    baseline = (
        float(np.sqrt(max(0.0, direction @ translation @ direction)))
        if np.all(np.isfinite(translation))
        else np.inf
    )
    return RigDeviations(covariance, baseline)


def refit_poses(
    camera: CameraModel, points: list[tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each view's board pose for a fixed camera, and its RMS error: ``rvecs, tvecs, errors``."""
    poses = [board_pose(camera, obj, img) for obj, img in points]
    rvecs = np.array([cv2.Rodrigues(pose[:3, :3])[0].ravel() for pose in poses])
    tvecs = np.array([pose[:3, 3] for pose in poses])
    errors = np.array(
        [view_error(camera, obj, img, rvecs[k], tvecs[k]) for k, (obj, img) in enumerate(points)]
    )
    return rvecs, tvecs, errors


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
