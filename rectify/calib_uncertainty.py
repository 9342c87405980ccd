"""How well the corners determine a calibration: covariances of intrinsics and of the rig.

:func:`intrinsic_covariance` gives one camera's, :func:`rig_deviations` a
stereo rig's (both cameras' intrinsics, the rotation and the translation) and
its baseline's 1-sigma deviation, both from the least-squares fit's residuals
and the Jacobians OpenCV's ``projectPoints`` / ``fisheye.projectPoints``
compute, each view's board pose eliminated (Schur complement).
"""

from dataclasses import dataclass

import cv2
import numpy as np

from lenspair.rectify.calib_views import Points
from lenspair.rectify.rig import CameraModel

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
    """One board view's corners in one or both cameras, for :func:`_information`.

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
            (:func:`~lenspair.rectify.calib_fits.fit_stereo` ``refine``); else
            each camera's intrinsics covariance from its own fit
            (:func:`intrinsic_covariance`), held fixed in the stereo fit: their
            errors then reach the rig through its dependence on them,
            ``M_rr^-1 M_ri`` (the two fits' shared corners are taken as
            independent).

    Returns:
        The covariance and the baseline's deviation; the intrinsics' are ``own``
        when given.
    """
    rig_r = cv2.Rodrigues(np.ascontiguousarray(transform[:3, :3]))[0].ravel()
    rig_t = np.ascontiguousarray(transform[:3, 3])
    views = [
        _stereo_observations(cameras, item, rvec, tvec, rig_r, rig_t) for item, rvec, tvec in stereo
    ]
    information, variance = _information(views, 22)
    if own is None:
        covariance = _inverse(information, variance)
    else:
        covariance = _covariance_with_fixed_intrinsics(information, variance, own)
    direction = rig_t / np.linalg.norm(rig_t)
    translation = covariance[-3:, -3:]
    baseline = (
        float(np.sqrt(max(0.0, direction @ translation @ direction)))
        if np.all(np.isfinite(translation))
        else np.inf
    )
    return RigDeviations(covariance, baseline)


def _stereo_observations(
    cameras: tuple[CameraModel, CameraModel],
    item: Points,
    rvec: np.ndarray,
    tvec: np.ndarray,
    rig_r: np.ndarray,
    rig_t: np.ndarray,
) -> _Observations:
    """One stereo view's corners in both cameras, cam1's projected through the rig ``(r, t)``."""
    obj, pixels0, pixels1 = item
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
    return _Observations(seen, (in_pose, in_rig))


def _covariance_with_fixed_intrinsics(
    information: np.ndarray, variance: float, own: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """``(22, 22)`` covariance for a rig fitted with each camera's own intrinsics held fixed."""
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
    return covariance
