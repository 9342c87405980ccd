"""The joint refinement: both cameras' intrinsics refined with the rig, where that is surer.

After the stereo step with the intrinsics fixed, the same OpenCV call,
starting from each camera's intrinsics, refines both cameras' intrinsics
with the rig over the views that step kept (:func:`refine_jointly`): each
camera's own focal error would otherwise become baseline error. The
refinement is kept only where its baseline is surer, the refined rig
rectifies and each camera's own views still fit it.
"""

import dataclasses
from collections.abc import Sequence

import numpy as np

from lenspair.rectify.boards import Board
from lenspair.rectify.calib_fits import fit_stereo, refinable
from lenspair.rectify.calib_logging import log
from lenspair.rectify.calib_types import CameraCalibration
from lenspair.rectify.calib_uncertainty import RigDeviations, rig_deviations
from lenspair.rectify.calib_views import Points, refit_poses, stereo_residuals
from lenspair.rectify.corner_detection import Detection
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.fit_checks import distinct_poses
from lenspair.rectify.layout import unsupported_layout
from lenspair.rectify.rectification import StereoRectification
from lenspair.rectify.rig import CameraModel, StereoRig

JOINT_FIT_TOLERANCE = (1.2, 0.02)
"""Intrinsics refined with the rig are kept only when each camera's own views still fit
them within ``ratio * RMS + px`` of its own fit's RMS (both with poses solved per view)."""


def refine_jointly(
    stereo: list[tuple[Points, np.ndarray, np.ndarray]],
    monos: Sequence[CameraCalibration],
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    transform: np.ndarray,
    residuals: list[np.ndarray],
    fixed: RigDeviations,
    min_views: int,
) -> tuple[list[CameraCalibration], np.ndarray, list[np.ndarray], float, str]:
    """Refine both cameras' intrinsics with the rig over the stereo step's views, if better.

    Each camera calibrated alone has focal lengths off by its own noise; with
    the intrinsics then fixed, the stereo step turns the two cameras' different
    depth errors into baseline: 8 % off for boards 2-3 m away (0.2 % at 1 m),
    where ``cv2.stereoCalibrate`` refining everything together gives 0.4 %
    (0.06 %). But the refinement sees only the views both cameras saw: where
    most views were seen by one camera alone, each camera's own fit is the
    surer one. Fisheye views run only where they share a corner count
    (:func:`_refinable_views`). So the refinement is kept when its baseline
    deviation is the smaller of the two (``fixed``: the fixed-intrinsics fit's, intrinsics
    errors included, :func:`~lenspair.rectify.calib_uncertainty.rig_deviations`),
    the refined rig rectifies, and each camera's own views still fit the
    refined intrinsics (:data:`JOINT_FIT_TOLERANCE`).

    Args:
        stereo: the stereo step's views and their cam0 board poses.
        monos: each camera's own calibration.
        detections: every view's corners, per camera.
        board: the board.
        transform: the fixed-intrinsics fit's cam0 -> cam1.
        residuals: its residuals per view.
        fixed: its deviations.
        min_views: distinct board poses a refinement over a subset of the
            views needs (``CalibrationOptions.min_views``).

    Returns:
        The cameras' calibrations (refined or as given), the transform, the
        stereo residuals per view, the baseline's 1-sigma deviation and a line
        saying what was done.
    """
    cameras = (monos[0].camera, monos[1].camera)
    kept = list(monos), transform, residuals, fixed.baseline_m
    data = [item for item, _, _ in stereo]
    used = _refinable_views(data, cameras)
    shared = [np.array([stereo[v][k] for v in used]) for k in (1, 2)]  # rvecs, tvecs
    if len(used) < len(data) and distinct_poses(*shared) < min_views:
        return *kept, (
            f"not refined with the rig: fisheye views with different corner counts (the "
            f"{len(used)} sharing one hold fewer than {min_views} distinct board poses)"
        )
    try:
        refined, joint, rvecs, tvecs = fit_stereo([data[v] for v in used], cameras, refine=True)
    except RectifyError as exc:
        log.warning("stereo: intrinsics not refined with the rig (%s)", exc)
        return *kept, f"not refined with the rig: {exc}"
    try:  # a degenerate set (a board barely tilted) can refine into a rig nothing rectifies
        rig = StereoRig(refined[0], refined[1], joint)
        if (layout := unsupported_layout(rig)) is None:
            StereoRectification.from_rig(rig)
        elif unsupported_layout(StereoRig(cameras[0], cameras[1], transform)) is None:
            raise RectifyError(layout)  # the rig before refining was side by side
    except (ValueError, RectifyError) as exc:
        log.warning(
            "stereo: intrinsics not refined with the rig: the refined rig is unusable (%s)", exc
        )
        return *kept, "not refined with the rig: the refined rig was unusable"
    views = list(zip([data[v] for v in used], rvecs, tvecs, strict=True))
    together = rig_deviations(refined, views, joint)
    over = (
        ""
        if len(used) == len(data)
        else f"over {len(used)} of {len(data)} views, the most sharing a corner count "
        "as OpenCV's fisheye fit needs; "
    )
    spreads = (
        f"{over}baseline +/- {_share(together.baseline_m, rig.baseline_m)} refined, "
        f"+/- {_share(fixed.baseline_m, float(np.linalg.norm(transform[:3, 3])))} with each "
        "camera's own"
    )
    if not together.baseline_m < fixed.baseline_m:  # views one camera saw alone weigh more
        return *kept, f"not refined with the rig: each camera's own fits are surer ({spreads})"
    updated = _own_views_fit(monos, refined, detections, board)
    if updated is None:
        return *kept, "not refined with the rig: a camera's own views disagree"
    poses = _cam0_poses(data, used, refined[0], rvecs, tvecs)
    residuals = [
        stereo_residuals(item, refined, joint, r, t)
        for item, (r, t) in zip(data, poses, strict=True)
    ]
    calibrations = [
        dataclasses.replace(
            mono,
            camera=camera,
            rms_px=after,
            view_errors_px=tuple(float(e) for e in errors),
            rvecs=rvecs_own,
            tvecs=tvecs_own,
            intrinsics_covariance=together.intrinsics(index),
        )
        for index, (mono, (camera, errors, rvecs_own, tvecs_own, after)) in enumerate(
            zip(monos, updated, strict=True)
        )
    ]
    return calibrations, joint, residuals, together.baseline_m, f"refined with the rig ({spreads})"


def _refinable_views(data: list[Points], cameras: tuple[CameraModel, CameraModel]) -> list[int]:
    """The views the refinement can run over, as indices into ``data``.

    All of them, or for fisheye cameras the largest set holding one corner
    count (the most corners on a tie):
    ``cv2.fisheye.stereoCalibrate`` fails on views of different corner counts
    (OpenCV issue 21748, :func:`~lenspair.rectify.calib_fits.refinable`): a
    ChArUco session with a few partial views had no refinement at all. The
    refinement then rests on these views alone (its deviations too, which
    :func:`refine_jointly` weighs against the fixed-intrinsics fit's over
    every view); the others are only scored with it, their cam0 poses solved
    anew (:func:`_cam0_poses`).
    """
    everything = list(range(len(data)))
    if refinable(data, cameras):
        return everything
    counts = [len(obj) for obj, _, _ in data]
    best = max(set(counts), key=lambda n: (counts.count(n), n))
    return [v for v in everything if counts[v] == best]


def _cam0_poses(
    data: list[Points],
    used: list[int],
    camera: CameraModel,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every view's cam0 board pose, ``(rvec, tvec)``.

    The refinement's for the views it used, solved with the refined cam0 for
    the others.
    """
    fitted = dict(zip(used, zip(rvecs, tvecs, strict=True), strict=True))
    others = [v for v in range(len(data)) if v not in fitted]
    solved = refit_poses(camera, [(data[v][0], data[v][1]) for v in others])
    fitted.update(zip(others, zip(solved[0], solved[1], strict=True), strict=True))
    return [fitted[v] for v in range(len(data))]


_OwnFit = tuple[CameraModel, np.ndarray, np.ndarray, np.ndarray, float]
"""A refined camera over its own views: itself, view errors, rvecs, tvecs, pooled RMS (px)."""


def _own_views_fit(
    monos: Sequence[CameraCalibration],
    refined: Sequence[CameraModel],
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
) -> list[_OwnFit] | None:
    """Each refined camera's fit of its own views, poses solved per view; None if one is worse.

    A camera's own views are those its calibration alone kept; the refined
    intrinsics fit them worse than :data:`JOINT_FIT_TOLERANCE` allows when the
    views one camera saw alone disagree with those both saw (warned of).
    """
    objects = board.object_points()
    updated: list[_OwnFit] = []
    for index, (mono, camera) in enumerate(zip(monos, refined, strict=True)):
        found = [detections[v][index] for v in mono.views]
        points = [(objects[d.ids], d.corners.astype(np.float64)) for d in found if d is not None]
        corners = np.array([len(obj) for obj, _ in points])
        before = _pooled(refit_poses(mono.camera, points)[2], corners)
        rvecs_own, tvecs_own, errors = refit_poses(camera, points)
        after = _pooled(errors, corners)
        ratio, extra = JOINT_FIT_TOLERANCE
        if after > ratio * before + extra:
            log.warning(
                "cam%d: the intrinsics refined with the rig fit its own %d views with RMS "
                "%.3f px against %.3f px: kept each camera's own fit (views seen by one camera "
                "alone disagree with those both saw)",
                index,
                len(points),
                after,
                before,
            )
            return None
        updated.append((camera, errors, rvecs_own, tvecs_own, after))
    return updated


def _share(deviation: float, value: float) -> str:
    """A deviation as a percentage of ``value``: ``0.36 %``."""
    return f"{100 * deviation / value:.3g} %" if np.isfinite(deviation) else "undetermined"


def _pooled(view_errors: np.ndarray, corners: np.ndarray) -> float:
    """RMS over all corners from per-view RMS errors and corner counts."""
    return float(np.sqrt(np.sum(corners * view_errors**2) / np.sum(corners)))
