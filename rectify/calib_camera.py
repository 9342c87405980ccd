"""One camera calibrated alone from the views where it sees the board.

``cv2.calibrateCamera`` with ``k3`` fixed to 0 for ``pinhole-radtan``
(Kalibr's radtan has four coefficients), ``cv2.fisheye.calibrate`` for
``pinhole-equi`` (Kalibr's equidistant model), through
:func:`~lenspair.rectify.calib_fits.fit_camera`, with outlier views rejected
(:func:`~lenspair.rectify.calib_outliers.reject_outliers`) and the fit
checked (:mod:`~lenspair.rectify.fit_checks`).
"""

from collections.abc import Sequence

import cv2
import numpy as np

from lenspair.rectify.boards import Board
from lenspair.rectify.calib_fits import fit_camera
from lenspair.rectify.calib_logging import log
from lenspair.rectify.calib_outliers import reject_outliers
from lenspair.rectify.calib_types import (
    MODELS,
    CalibrationModel,
    CalibrationOptions,
    CameraCalibration,
    RejectedView,
    parse_model,
)
from lenspair.rectify.calib_uncertainty import intrinsic_covariance
from lenspair.rectify.calib_views import rms, view_error
from lenspair.rectify.corner_detection import Detection
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.fit_checks import check_distinct_poses, check_fit, check_pose_spread
from lenspair.rectify.projection import project_rays
from lenspair.rectify.rig import CameraModel

_COVERAGE_GRID = np.array([8, 6])


def calibrate_camera(
    detections: Sequence[Detection | None],
    board: Board,
    model: CalibrationModel,
    resolution: tuple[int, int],
    stage: str = "cam0",
    names: Sequence[str] | None = None,
    options: CalibrationOptions | None = None,
) -> tuple[CameraCalibration, list[RejectedView]]:
    """Calibrate one camera from its detections, rejecting outlier views.

    Args:
        detections: per view, the corners found or ``None``.
        board: the board (object points per corner id).
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        resolution: image ``(width, height)``, pixels.
        stage: name used in errors and rejections (``cam0``/``cam1``).
        names: per-view names for rejections; ``view <i>`` by default.
        options: rejection settings.

    Raises:
        RectifyError: too few usable views, or OpenCV failed.

    """
    options = options or CalibrationOptions()
    names = names or [f"view {i}" for i in range(len(detections))]
    distortion_model = MODELS[parse_model(model)]
    objects = board.object_points()
    data = {
        i: (objects[d.ids], d.corners.astype(np.float64))
        for i, d in enumerate(detections)
        if d is not None
    }

    def fit(views: list[int]) -> tuple[tuple[CameraModel, np.ndarray, np.ndarray], np.ndarray]:
        camera, rvecs, tvecs = fit_camera([data[v] for v in views], distortion_model, resolution)
        errors = [view_error(camera, *data[v], rvecs[k], tvecs[k]) for k, v in enumerate(views)]
        return (camera, rvecs, tvecs), np.asarray(errors)

    try:
        (camera, rvecs, tvecs), views, errors, rejected = reject_outliers(
            sorted(data), fit, stage, names, options
        )
    except RectifyError as exc:
        raise RectifyError(
            f"{stage}: {exc}" if not str(exc).startswith(stage) else str(exc)
        ) from None
    if (few_tilts := check_pose_spread(rvecs, tvecs, stage)) is not None:
        log.warning("%s", few_tilts)
    check_distinct_poses(rvecs, tvecs, stage, options.min_views)
    check_fit(camera, stage)
    residuals = np.concatenate(
        [project_rays(camera, data[v][0] @ cv2.Rodrigues(rvecs[k])[0].T + tvecs[k]) - data[v][1]
         for k, v in enumerate(views)]
    )  # fmt: skip
    if not np.isfinite(residuals).all():
        # a fit whose lens model folds back before some corners (their projection: NaN)
        # passed with an RMS error of NaN, which no threshold refuses
        raise RectifyError(
            f"{stage}: the calibration diverged: the fitted lens model cannot project "
            f"{int((~np.isfinite(residuals).all(axis=1)).sum())} of the board corners; show "
            "the board at more poses, across the whole image"
        )
    corners = np.concatenate([data[v][1] for v in views])
    cells = np.floor(corners / resolution * _COVERAGE_GRID).astype(int)
    inside = np.all((cells >= 0) & (cells < _COVERAGE_GRID), axis=1)
    coverage = len({tuple(c) for c in cells[inside]}) / (_COVERAGE_GRID[0] * _COVERAGE_GRID[1])
    covariance = intrinsic_covariance(camera, [data[v] for v in views], rvecs, tvecs)
    calibration = CameraCalibration(
        camera, rms(residuals), tuple(views), tuple(float(e) for e in errors), rvecs, tvecs,
        coverage, covariance,
    )  # fmt: skip
    return calibration, rejected
