"""Stereo calibration from board views: each camera alone, then the pair with intrinsics fixed.

The procedure (see DESIGN.md, "Geometry notes"):

1. Each camera is calibrated alone from every view where it sees the board
   (:mod:`~lenspair.rectify.calib_camera`):
   ``cv2.calibrateCamera`` with ``k3`` fixed to 0 for ``pinhole-radtan``
   (Kalibr's radtan has four coefficients), ``cv2.fisheye.calibrate`` for
   ``pinhole-equi`` (Kalibr's equidistant model).
2. Views where both cameras see the board are matched corner by corner
   (ChArUco: by id; a plain chessboard may be numbered from a different
   corner in each camera, e.g. when cam1 is mounted upside down, so its
   numbering is chosen per view to agree with the rig's relative pose).
3. ``cv2.stereoCalibrate`` / ``cv2.fisheye.stereoCalibrate`` with the
   intrinsics fixed estimates the rigid transform cam0 -> cam1.
4. The same call, starting from each camera's intrinsics, refines both
   cameras' intrinsics with the rig over the views step 3 kept, where it can
   and where each camera's own views still fit the result
   (:func:`~lenspair.rectify.calib_refine.refine_jointly`): each camera's own
   focal error would otherwise become baseline error. The intrinsics and the
   baseline come with 1-sigma deviations from the corner residuals
   (:mod:`~lenspair.rectify.calib_uncertainty`).

At every step a view whose RMS reprojection error exceeds
``max(outlier_factor * median, outlier_floor_px)`` is rejected, and the step
is repeated until none is; each rejection is recorded with its reason. A
round that would leave fewer than ``min_views`` views rejects none: outlier
rejection never fails a calibration that works without it
(:mod:`~lenspair.rectify.calib_outliers`).
Each camera's fit and the stereo step's views are then checked
(:mod:`~lenspair.rectify.fit_checks`): a board that stood still or was seen at
too few distinct poses, or a fit with pixels no camera has, is refused; a
camera that fits its views far worse than the other is warned about, as are
a wrong marker size, a wrong lens model and a loosely determined focal length
or baseline (:mod:`~lenspair.rectify.calib_warnings`). Every warning goes into
the result's report (:mod:`~lenspair.rectify.calib_logging`).
Reprojection errors are RMS over corners of the Euclidean pixel residual.
The options and result types are in :mod:`~lenspair.rectify.calib_types`.
"""

import dataclasses
import logging
from collections.abc import Sequence

import numpy as np

from lenspair.core.progress import progress
from lenspair.rectify.boards import Board
from lenspair.rectify.calib_camera import calibrate_camera
from lenspair.rectify.calib_fits import fit_stereo
from lenspair.rectify.calib_logging import held, log, noted, release
from lenspair.rectify.calib_outliers import reject_outliers
from lenspair.rectify.calib_refine import refine_jointly
from lenspair.rectify.calib_types import (
    CalibrationModel,
    CalibrationOptions,
    CalibrationResult,
    CameraCalibration,
    RejectedView,
)
from lenspair.rectify.calib_uncertainty import rig_deviations
from lenspair.rectify.calib_views import Points, match_views, rms, stereo_residuals
from lenspair.rectify.calib_warnings import check_marker_size, check_model, warn_uncertain
from lenspair.rectify.corner_detection import Detection, detect_corners
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.fit_checks import check_distinct_poses, rms_balance_warnings
from lenspair.rectify.layout import unsupported_layout
from lenspair.rectify.rectification import StereoRectification, row_disagreement
from lenspair.rectify.rig import CameraModel, StereoRig


def calibrate_from_detections(
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    model: CalibrationModel,
    resolutions: tuple[tuple[int, int], tuple[int, int]],
    names: Sequence[str] | None = None,
    options: CalibrationOptions | None = None,
) -> CalibrationResult:
    """Calibrate a stereo rig from corners already detected (see the module docstring).

    Args:
        detections: per view, ``(cam0 detection or None, cam1 detection or None)``.
        board: the board seen.
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        resolutions: ``(width, height)`` of cam0 and cam1 images, pixels.
        names: per-view names used when reporting rejected views.
        options: outlier rejection and rectification settings.

    Raises:
        RectifyError: too few usable views, OpenCV failure, implausible result.

    """
    with noted(log) as warnings:
        result = _calibrate(detections, board, model, resolutions, names, options)
        check_model(detections, board, model, resolutions, result)
    return dataclasses.replace(result, warnings=tuple(warnings))


def _calibrate(
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    model: CalibrationModel,
    resolutions: tuple[tuple[int, int], tuple[int, int]],
    names: Sequence[str] | None,
    options: CalibrationOptions | None,
) -> CalibrationResult:
    """:func:`calibrate_from_detections` but for the lens model check and the noted warnings."""
    options = options or CalibrationOptions()
    names = list(names) if names is not None else [f"view {i}" for i in range(len(detections))]
    if len(names) != len(detections):
        raise ValueError(f"names: expected {len(detections)}, got {len(names)}")
    check_marker_size(detections, board)
    monos, rejected, pairs = _calibrate_cameras(
        detections, board, model, resolutions, names, options
    )
    cameras = (monos[0].camera, monos[1].camera)
    errors_px = [mono.view_errors_px for mono in monos]
    for warning in rms_balance_warnings(errors_px, cameras, options.outlier_floor_px):
        log.warning("%s", warning)  # a warning, not a refusal: cameras may differ
    if len(pairs) < options.min_views:  # the stereo step needs views the two cameras share
        raise RectifyError(
            f"stereo: the board was seen by both cameras at once in {len(pairs)} usable views, "
            f"need at least {options.min_views} (cam0 {len(monos[0].views)}, cam1 "
            f"{len(monos[1].views)} views on their own); record views where both see it"
        )
    matched, refused = match_views(pairs, board, cameras, options.pose_tolerance_deg)
    rejected += [RejectedView(v, names[v], "stereo", None, r) for v, r in refused.items()]
    (transform, residuals, rvecs, tvecs), views, dropped = _fit_stereo_views(
        matched, refused, cameras, names, options
    )
    rejected += dropped
    check_distinct_poses(rvecs, tvecs, "stereo", options.min_views, "seen by both cameras")
    stereo = [(matched[v], rvecs[k], tvecs[k]) for k, v in enumerate(views)]
    own = (monos[0].intrinsics_covariance, monos[1].intrinsics_covariance)
    fixed = rig_deviations(cameras, stereo, transform, own)
    baseline_std, refinement = fixed.baseline_m, "not refined with the rig: asked not to"
    if options.refine_jointly:
        monos, transform, residuals, baseline_std, refinement = refine_jointly(
            stereo, monos, detections, board, transform, residuals, fixed, options.min_views
        )
    errors = np.asarray([rms(r) for r in residuals])
    try:
        rig = StereoRig(monos[0].camera, monos[1].camera, transform)
    except ValueError as exc:
        raise RectifyError(f"stereo calibration gave an invalid transform: {exc}") from None
    rows = _row_disagreement(rig, [matched[v] for v in views], options.alpha)
    warn_uncertain(monos, rig.baseline_m, baseline_std)
    return CalibrationResult(
        rig, board, model, (monos[0], monos[1]), rms(np.concatenate(residuals)), tuple(views),
        tuple(float(e) for e in errors), rows, tuple(rejected), _counts(detections),
        baseline_std_m=baseline_std if np.isfinite(baseline_std) else None,
        refinement=refinement,
    )  # fmt: skip


def _calibrate_cameras(
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    model: CalibrationModel,
    resolutions: tuple[tuple[int, int], tuple[int, int]],
    names: Sequence[str],
    options: CalibrationOptions,
) -> tuple[list[CameraCalibration], list[RejectedView], dict[int, tuple[Detection, Detection]]]:
    """Each camera calibrated alone, without rejecting outliers where rejecting leaves too few.

    Returns:
        Both cameras' calibrations, the views they rejected, and the views
        both cameras kept, with their detections.
    """
    # what each camera's calibration says is held back: only the pass that is kept
    # speaks (the fallback calibrates each camera again, over other views)
    said: list[logging.LogRecord] = []
    try:
        monos, rejected, pairs = _each_camera(
            detections, board, model, resolutions, names, options, said
        )
    except RectifyError:  # this pass ends the calibration: what it said is said
        release(said)
        raise
    if len(pairs) < options.min_views and options.max_rounds > 0:
        # each camera rejected other views, and too few are left to both: calibrated
        # without rejecting, as it would work (a factor near 1 on evenly noisy views)
        plain = dataclasses.replace(options, max_rounds=0)
        said_again: list[logging.LogRecord] = []
        try:
            again = _each_camera(detections, board, model, resolutions, names, plain, said_again)
        except RectifyError:
            # the fallback failed too: the first pass stands, with its warnings, and the
            # stereo step refuses its too few views (the reason that helps the user)
            again = None
        if again is not None and len(again[2]) >= options.min_views:
            log.warning(
                "outlier rejection left %d views that both cameras kept (need %d): "
                "calibrating without rejecting any; a larger --outlier-factor rejects fewer",
                len(pairs),
                options.min_views,
            )
            (monos, rejected, pairs), said = again, said_again  # stereo still rejects outliers
    release(said)
    return monos, rejected, pairs


def _each_camera(
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    model: CalibrationModel,
    resolutions: tuple[tuple[int, int], tuple[int, int]],
    names: Sequence[str],
    settings: CalibrationOptions,
    said: list[logging.LogRecord],
) -> tuple[list[CameraCalibration], list[RejectedView], dict[int, tuple[Detection, Detection]]]:
    """One pass of :func:`calibrate_camera` over both cameras, what it says held back.

    Args:
        detections: per view, both cameras' detections (``None``: board not found).
        board: the calibration board.
        model: the lens model fitted.
        resolutions: both cameras' image sizes ``(width, height)``, px.
        names: the views' names, for messages.
        settings: the options of this pass.
        said: receives the log records held back, also when the pass raises
            (the caller decides which pass speaks).

    Returns:
        Both cameras' calibrations, the views they rejected, and the views both
        kept with their detections.
    """
    monos: list[CameraCalibration] = []
    dropped: list[RejectedView] = []
    with held(log, said):
        for index, stage in enumerate(("cam0", "cam1")):
            per_view = [pair[index] for pair in detections]
            mono, left_out = calibrate_camera(
                per_view, board, model, resolutions[index], stage, names, settings
            )
            monos.append(mono)
            dropped += left_out
    usable = set(monos[0].views) & set(monos[1].views)
    shared = {v: (d0, d1) for v, (d0, d1) in enumerate(detections) if v in usable and d0 and d1}
    return monos, dropped, shared


_StereoFit = tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]
"""The stereo step's fit: cam0 -> cam1 ``(4, 4)``, residuals per view, rvecs, tvecs ``(V, 3)``."""


def _fit_stereo_views(
    matched: dict[int, Points],
    refused: dict[int, str],
    cameras: tuple[CameraModel, CameraModel],
    names: Sequence[str],
    options: CalibrationOptions,
) -> tuple[_StereoFit, list[int], list[RejectedView]]:
    """The stereo step with the intrinsics fixed, rejecting outlier views.

    Args:
        matched: the views matched corner by corner.
        refused: the views refused as the cameras' poses disagree, with why.
        cameras: both cameras' own calibrations.
        names: per-view names.
        options: rejection settings.

    Returns:
        The fit, the views it used and those it rejected.

    Raises:
        RectifyError: too few views left (saying why others were refused).
    """

    def fit(views: list[int]) -> tuple[_StereoFit, np.ndarray]:
        _, transform, rvecs, tvecs = fit_stereo([matched[v] for v in views], cameras)
        residuals = [
            stereo_residuals(matched[v], cameras, transform, rvecs[k], tvecs[k])
            for k, v in enumerate(views)
        ]
        return (transform, residuals, rvecs, tvecs), np.asarray([rms(r) for r in residuals])

    try:
        result, views, _, dropped = reject_outliers(sorted(matched), fit, "stereo", names, options)
    except RectifyError as exc:  # too few views: say why the others were refused
        if not refused:
            raise
        first = next(iter(refused.values()))
        raise RectifyError(
            f"{exc}; {len(refused)} views refused as the cameras' poses disagree (the first: "
            f"{first}): frames paired out of step, or a board spec or model that is wrong"
        ) from None
    return result, views, dropped


def _row_disagreement(rig: StereoRig, matched: list[Points], alpha: float) -> float | None:
    """RMS rectified row difference of the matched corners; None (warned of) if not rectified."""
    if (layout := unsupported_layout(rig)) is None:
        return row_disagreement(
            StereoRectification.from_rig(rig, alpha=alpha),
            np.concatenate([points[1] for points in matched]),
            np.concatenate([points[2] for points in matched]),
        )
    # a valid calibration all the same, for other tools: written, with the warning
    log.warning(
        "stereo: %s: the camchain is written, but capture-ingest rectifies side-by-side rigs only",
        layout,
    )
    return None


def _counts(detections: Sequence[tuple[Detection | None, Detection | None]]) -> dict[str, int]:
    """Views given, and those where the board was found by cam0, cam1 and both."""
    return {
        "views": len(detections),
        "cam0_detected": sum(d0 is not None for d0, _ in detections),
        "cam1_detected": sum(d1 is not None for _, d1 in detections),
        "both_detected": sum(d0 is not None and d1 is not None for d0, d1 in detections),
    }


def detect_views(
    views: Sequence[tuple[np.ndarray, np.ndarray]], board: Board
) -> list[tuple[Detection | None, Detection | None]]:
    """Detect the board in each image of each stereo view (with a progress bar)."""
    return [
        (detect_corners(image0, board), detect_corners(image1, board))
        for image0, image1 in progress(views, "detecting board", total=len(views), unit="view")
    ]


def calibrate_stereo(
    views: Sequence[tuple[np.ndarray, np.ndarray]],
    board: Board,
    model: CalibrationModel,
    names: Sequence[str] | None = None,
    options: CalibrationOptions | None = None,
) -> CalibrationResult:
    """Calibrate a stereo rig from board images.

    Args:
        views: ``(cam0 image, cam1 image)`` pairs taken at the same instant;
            ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)``.
        board: the board seen.
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        names: per-view names used when reporting rejected views.
        options: outlier rejection and rectification settings.

    """
    if not views:
        raise RectifyError("calibration: no views given")
    names = list(names) if names is not None else [f"view {i}" for i in range(len(views))]
    resolutions = (
        (int(views[0][0].shape[1]), int(views[0][0].shape[0])),
        (int(views[0][1].shape[1]), int(views[0][1].shape[0])),
    )
    for name, pair in zip(names, views, strict=False):
        for camera, image, size in zip(("cam0", "cam1"), pair, resolutions, strict=True):
            if (image.shape[1], image.shape[0]) != size:
                raise RectifyError(
                    f"{name}: the {camera} image is {image.shape[1]}x{image.shape[0]}, the first "
                    f"view's {size[0]}x{size[1]}: a camera's views must all have one size"
                )
    return calibrate_from_detections(
        detect_views(views, board), board, model, resolutions, names, options
    )
