"""Calibrating a fisheye wider than OpenCV's own starting guess reaches."""

import dataclasses

import cv2
import numpy as np
import pytest

from lenspair.rectify.boards import parse_board_spec
from lenspair.rectify.calib_camera import calibrate_camera
from lenspair.rectify.calib_fits import CRITERIA, fisheye_flag, fit_camera
from lenspair.rectify.corner_detection import Detection
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.projection import project_rays
from lenspair.rectify.rig import CameraModel

SIZE = (720, 540)
WIDE = CameraModel((230.0, 230.5, 360.0, 270.0), "equidistant", (0.01, -0.002, 0.001, -5e-4), SIZE)
"""About 180 degrees across the image's width (equidistant: 360 px / 230 px = 1.57 rad)."""


def _views(
    count: int = 25, seed: int = 3, camera: CameraModel = WIDE
) -> list[tuple[np.ndarray, np.ndarray]]:
    """A 9x6 board 0.4-1 m away, tilted, every corner inside the image by 5 px.

    With seeds 3-6 and 10 (of 0-11) OpenCV's own start fails; seed 3 is taken.
    """
    board = parse_board_spec("chessboard:9x6:0.04")
    objects = board.object_points()
    rng = np.random.default_rng(seed)
    views = []
    while len(views) < count:
        direction = np.array([*rng.uniform([-0.55, -0.4], [0.55, 0.4]), 1.0])
        R = cv2.Rodrigues(np.array([*rng.normal(0.0, 0.35, 2), rng.uniform(-0.3, 0.3)]))[0]
        t = direction / np.linalg.norm(direction) * rng.uniform(0.4, 1.0) - R @ objects.mean(0)
        pixels = project_rays(camera, objects @ R.T + t)
        inside = np.isfinite(pixels).all() and pixels.min() > 5
        if inside and pixels[:, 0].max() < SIZE[0] - 6 and pixels[:, 1].max() < SIZE[1] - 6:
            views.append((objects, pixels + rng.normal(0.0, 0.05, pixels.shape)))
    return views


def test_a_fisheye_wider_than_opencvs_own_start_reaches_is_calibrated() -> None:
    views = _views()
    # the fit from OpenCV's own start (K = I) asserts on these views ...
    flags = fisheye_flag("CALIB_RECOMPUTE_EXTRINSIC") | fisheye_flag("CALIB_FIX_SKEW")
    with pytest.raises(cv2.error, match="norm_u1"):
        cv2.fisheye.calibrate(
            [o.reshape(1, -1, 3) for o, _ in views],
            [i.reshape(1, -1, 2) for _, i in views],
            SIZE, np.eye(3), np.zeros(4), flags=flags, criteria=CRITERIA,
        )  # fmt: skip
    # ... and started from a fisheye's focal length it converges to the truth
    camera, rvecs, tvecs = fit_camera(views, "equidistant", SIZE)
    np.testing.assert_allclose(camera.intrinsics, WIDE.intrinsics, rtol=2e-3, atol=0.3)
    assert rvecs.shape == tvecs.shape == (len(views), 3)


def test_of_the_other_starts_the_fit_with_the_least_error_is_taken_not_the_first() -> None:
    # a circular fisheye (f 150 px in 720x540): OpenCV's own start asserts, the first other
    # start "converged" to f 127 with an RMS error of NaN, and that camera was accepted
    circular = CameraModel((150.0, 150.5, 360.0, 270.0), "equidistant", WIDE.distortion, SIZE)
    views = _views(10, 21, circular)
    detections = [
        Detection(np.arange(len(o), dtype=np.int32), i.astype(np.float32)) for o, i in views
    ]
    board = parse_board_spec("chessboard:9x6:0.04")
    calibration, rejected = calibrate_camera(detections, board, "pinhole-equi", SIZE)
    np.testing.assert_allclose(
        calibration.camera.intrinsics, circular.intrinsics, rtol=5e-3, atol=1
    )
    assert calibration.rms_px < 0.1 and rejected == []


def test_a_fit_that_cannot_project_the_corners_is_refused_not_given_an_error_of_nan(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a lens model folding back at 23 deg (k1 = -2): every view's corners beyond it, so no
    # view stood out to reject, and the calibration was accepted with an RMS error of NaN
    from lenspair.rectify import calib_camera

    fit = calib_camera.fit_camera

    def folded(*args: object) -> tuple[CameraModel, np.ndarray, np.ndarray]:
        camera, rvecs, tvecs = fit(*args)  # type: ignore[arg-type]
        return dataclasses.replace(camera, distortion=(-2.0, 0.0, 0.0, 0.0)), rvecs, tvecs

    monkeypatch.setattr(calib_camera, "fit_camera", folded)
    views = _views(25, 0)
    detections = [
        Detection(np.arange(len(o), dtype=np.int32), i.astype(np.float32)) for o, i in views
    ]
    board = parse_board_spec("chessboard:9x6:0.04")
    with pytest.raises(RectifyError, match=r"^cam0: the calibration diverged: the fitted lens"):
        calibrate_camera(detections, board, "pinhole-equi", SIZE)
