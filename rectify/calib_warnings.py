"""What a calibration warns of without refusing it: doubtful inputs and loose results.

* a ChArUco board whose markers measure far from the size ``--board`` states
  (:func:`check_marker_size`), which biases the focal length unseen;
* a camera the other lens model fits far better (:func:`check_model`);
* a focal length or baseline the corners determine poorly
  (:func:`warn_uncertain`).

Each warning goes to the calibration's logger
(:data:`~lenspair.rectify.calib_logging.log`), and so into its report.
"""

from collections.abc import Sequence

import numpy as np

from lenspair.rectify.boards import Board
from lenspair.rectify.calib_camera import calibrate_camera
from lenspair.rectify.calib_logging import held, log
from lenspair.rectify.calib_types import (
    CalibrationModel,
    CalibrationOptions,
    CalibrationResult,
    CameraCalibration,
)
from lenspair.rectify.corner_detection import Detection
from lenspair.rectify.errors import RectifyError

FOCAL_DOUBT = 0.005
"""A camera whose focal length's 1-sigma deviation exceeds this share is warned about:
a 9x6 board 2-3 m from a 720x540 camera with f = 350 px gives about 0.6 %, 0.6-1.4 m
about 0.1 % (after the joint refinement)."""
BASELINE_DOUBT = 0.01
"""A baseline whose 1-sigma deviation exceeds this share is warned about."""


def warn_uncertain(
    monos: Sequence[CameraCalibration], baseline_m: float, baseline_std: float
) -> None:
    """Warn of a focal length or baseline the corners determine poorly."""
    for stage, mono in zip(("cam0", "cam1"), monos, strict=True):
        if mono.focal_std > FOCAL_DOUBT:
            log.warning(
                "%s: the focal length is known to +/- %.2f %% only (1 sigma, from the corner "
                "residuals over %d views); depth and baseline inherit it: show the board "
                "nearer, so that it fills more of the image, and tilted in several directions",
                stage,
                100 * mono.focal_std,
                len(mono.views),
            )
    if baseline_std > BASELINE_DOUBT * baseline_m:
        log.warning(
            "stereo: the baseline is known to +/- %.2f %% only (1 sigma); every depth scales "
            "with it: show the board nearer, to both cameras at once",
            100 * baseline_std / baseline_m,
        )


MARKER_TOLERANCE = 0.15
"""Markers measured this far (relative) from the stated ``MARKER_M`` are reported (warning)."""


def check_marker_size(
    detections: Sequence[tuple[Detection | None, Detection | None]], board: Board
) -> None:
    """Warn when the images' ChArUco markers are not the size ``--board`` states.

    The measure (:func:`~lenspair.rectify.corner_detection.measured_marker_m`) comes
    out a few per cent small, and a marker size a little off changes the
    calibration by less than its noise; the tolerance catches the typing
    mistakes (a third off and more) that bias the focal length unseen.
    """
    measured = [d.marker_m for pair in detections for d in pair if d and d.marker_m is not None]
    if board.marker_m is None or not measured:
        return
    median = float(np.median(measured))
    if abs(median / board.marker_m - 1.0) > MARKER_TOLERANCE:
        log.warning(
            "board: its markers measure about %.3g m on the images, %s states %.3g m "
            "(MARKER_M); a wrong marker size biases the focal length: check the printed board",
            median,
            board.spec(),
            board.marker_m,
        )


MODEL_DOUBT_RMS_PX = 0.15
"""Above this RMS (px) a camera's fit is compared with the other lens model's."""

MODEL_DOUBT_RATIO = 0.5
"""... and doubted when the other model's RMS is below this share of it."""


def check_model(
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    model: CalibrationModel,
    resolutions: tuple[tuple[int, int], tuple[int, int]],
    result: CalibrationResult,
) -> None:
    """Warn when the other lens model fits a camera's views far better.

    A fisheye calibrated as ``pinhole-radtan`` gave a baseline 5 % short with
    RMS 0.46 px, and nothing said so: the RMS alone cannot tell (real corners
    are noisier than simulated ones), but the other model's fit of the same
    views can. Only a camera whose RMS is above :data:`MODEL_DOUBT_RMS_PX` is
    refitted (one calibration of its kept views, no outlier rounds).
    """
    other: CalibrationModel = "pinhole-radtan" if model == "pinhole-equi" else "pinhole-equi"
    plain = CalibrationOptions(max_rounds=0)
    for index, (stage, camera) in enumerate(zip(("cam0", "cam1"), result.cameras, strict=True)):
        if camera.rms_px <= MODEL_DOUBT_RMS_PX:
            continue
        kept = set(camera.views)
        views = [pair[index] if v in kept else None for v, pair in enumerate(detections)]
        try:
            with held(log, []):  # its own warnings are of a fit not kept
                refit, _ = calibrate_camera(
                    views, board, other, resolutions[index], stage, None, plain
                )
        except RectifyError:
            continue
        if refit.rms_px < MODEL_DOUBT_RATIO * camera.rms_px:
            log.warning(
                "%s: %s fits its views with RMS %.3f px against %.3f px for %s: the lens "
                "model is likely wrong (--model %s), which biases focal length and baseline",
                stage,
                other,
                refit.rms_px,
                camera.rms_px,
                model,
                other,
            )
