"""ChArUco boards of the legacy pattern (OpenCV < 4.6): the ``:legacy`` spec and the hint.

The boards are printed by OpenCV itself (``CharucoBoard.setLegacyPattern``),
not through :class:`~lenspair.rectify.boards.Board`, so the views show what
an old OpenCV or another tool printed, whatever lenspair builds.
"""

from pathlib import Path

import cv2
import numpy as np
import pytest

from lenspair.core.imagewrite import write_image
from lenspair.rectify.boards import parse_board_spec
from lenspair.rectify.corner_detection import detect_corners
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.recording_calibration import calibrate_recording

PIXELS_PER_SQUARE = 60
K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
BASELINE_M = 0.1


def _printed(columns: int, rows: int, square_m: float, legacy: bool) -> np.ndarray:
    """OpenCV's print of a DICT_5X5_100 board with a one-square white margin."""
    words = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    board = cv2.aruco.CharucoBoard((columns, rows), square_m, 0.75 * square_m, words)
    board.setLegacyPattern(legacy)
    p = PIXELS_PER_SQUARE
    size = ((columns + 2) * p, (rows + 2) * p)
    return np.asarray(board.generateImage(size, marginSize=p, borderBits=1), np.uint8)


def _view(
    texture: np.ndarray, square_m: float, rotation: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The board at pose ``(rotation, t)`` (ChArUco origin, metres) through a pinhole camera.

    Returns:
        The image and the homography from board metres to image pixels.
    """
    scale = PIXELS_PER_SQUARE / square_m
    offset = PIXELS_PER_SQUARE - 0.5  # the outer corner, in texture pixels (centres at 0)
    board_to_texture = np.array([[scale, 0, offset], [0, scale, offset], [0, 0, 1.0]])
    board_to_image = K @ np.column_stack([rotation[:, 0], rotation[:, 1], t])
    # drawn at 4x and averaged down: a plain warp aliases the squares' edges by tenths of a px
    s = 4
    upscale = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1.0]])
    warp = upscale @ board_to_image @ np.linalg.inv(board_to_texture)
    fine = cv2.warpPerspective(
        texture, warp, (SIZE[0] * s, SIZE[1] * s), flags=cv2.INTER_LINEAR, borderValue=110
    )
    image = cv2.resize(fine, SIZE, interpolation=cv2.INTER_AREA)
    return np.asarray(image, np.uint8), board_to_image


def _pose(rng: np.random.Generator, grid_m: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A board pose in front of the rig, tilted up to 30 deg, its centre near the axis."""
    rotation = cv2.Rodrigues(np.deg2rad(rng.uniform(-30, 30, 3)) * np.array([1, 1, 0.3]))[0]
    distance = rng.uniform(0.55, 0.85)
    centre = np.array([rng.uniform(-0.05, 0.05) + BASELINE_M / 2, rng.uniform(-0.04, 0.04)])
    centre = np.append(centre, distance)
    return rotation, centre - rotation @ np.array([grid_m[0] / 2, grid_m[1] / 2, 0.0])


@pytest.mark.parametrize("size", [(8, 6), (6, 8), (5, 4), (11, 8)])
def test_a_legacy_board_is_found_with_its_spec_marked_legacy(size: tuple[int, int]) -> None:
    # OpenCV < 4.6's boards of even ROWS were found in no image: no spec could say legacy
    columns, rows = size
    square_m = 0.04
    texture = _printed(columns, rows, square_m, legacy=True)
    rotation = cv2.Rodrigues(np.array([0.3, -0.25, 0.1]))[0]
    grid = (columns * square_m, rows * square_m)
    t = np.array([0.0, 0.0, 0.6]) - rotation @ np.array([grid[0] / 2, grid[1] / 2, 0.0])
    image, board_to_image = _view(texture, square_m, rotation, t)
    spec = f"charuco:{columns}x{rows}:{square_m}:{0.75 * square_m}"
    assert detect_corners(image, parse_board_spec(spec)) is None  # the current pattern's spec
    board = parse_board_spec(f"{spec}:legacy")
    detection = detect_corners(image, board)
    assert detection is not None and len(detection) == board.num_corners
    np.testing.assert_array_equal(detection.ids, np.arange(board.num_corners))
    # where the board's geometry puts each corner id (the outer corner is the origin)
    xy = board.object_points()[detection.ids, :2]
    truth = cv2.perspectiveTransform(xy.reshape(-1, 1, 2), board_to_image).reshape(-1, 2)
    error = np.linalg.norm(detection.corners - truth, axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.35 and error.max() < 1.0  # as the current pattern


def test_the_legacy_marker_is_parsed_written_and_refused_on_a_chessboard() -> None:
    board = parse_board_spec("charuco:8x6:0.05:0.0375:DICT_5X5_100:legacy")
    assert board.legacy and board.dictionary == "DICT_5X5_100" and board.marker_m == 0.0375
    assert board.spec() == "charuco:8x6:0.05:0.0375:DICT_5X5_100:legacy"
    assert parse_board_spec(board.spec()) == board
    assert parse_board_spec("charuco:8x6:0.05:0.0375:LEGACY") == board  # default dictionary
    assert not parse_board_spec("charuco:8x6:0.05:0.0375").legacy
    assert board.charuco().getLegacyPattern()
    assert not parse_board_spec("charuco:8x6:0.05:0.0375").charuco().getLegacyPattern()
    with pytest.raises(RectifyError, match=r"expected chessboard:COLSxROWS:SQUARE_M$"):
        parse_board_spec("chessboard:9x6:0.05:legacy")
    with pytest.raises(RectifyError, match=r"expected charuco:.*\[:DICT\]\[:legacy\]$"):
        parse_board_spec("charuco:8x6:0.05:legacy")


def _recording(path: Path, legacy: bool, views: int = 8) -> Path:
    """A left/right recording at 4 Hz of an 8x6 board printed by OpenCV, seen by both cameras."""
    square_m = 0.05
    texture = _printed(8, 6, square_m, legacy)
    rng = np.random.default_rng(3)
    to_cam1 = cv2.Rodrigues(np.array([0.002, -0.003, 0.001]))[0]
    for folder in ("left", "right"):
        (path / folder).mkdir(parents=True)
    for view in range(views):
        rotation, t = _pose(rng, (8 * square_m, 6 * square_m))
        stamp = 1_700_000_000_000_000_000 + view * 250_000_000
        left, _ = _view(texture, square_m, rotation, t)
        shifted = to_cam1 @ t + np.array([-BASELINE_M, 0.0, 0.0])
        right, _ = _view(texture, square_m, to_cam1 @ rotation, shifted)
        write_image(path / "left" / f"{stamp}.png", left)
        write_image(path / "right" / f"{stamp}.png", right)
    return path


def test_a_legacy_board_found_in_no_view_is_said_to_need_the_legacy_marker(
    tmp_path: Path,
) -> None:
    # it said "DICT_5X5 markers are seen, so check COLSxROWS ... and the dictionary's size"
    recording = _recording(tmp_path / "legacy", legacy=True)
    spec = "charuco:8x6:0.05:0.0375:DICT_5X5_100"
    with pytest.raises(RectifyError) as caught:
        calibrate_recording(recording, parse_board_spec(spec), "pinhole-radtan")
    message = str(caught.value)
    assert "found in 0 cam0 and 0 cam1 views); " in message and "check COLSxROWS" not in message
    assert "the board is the legacy pattern (OpenCV < 4.6): add :legacy to --board" in message
    assert f"({spec}:legacy)" in message and "\n" not in message
    calibration = calibrate_recording(
        recording, parse_board_spec(f"{spec}:legacy"), "pinhole-radtan"
    )
    assert calibration.result.counts["both_detected"] == 8
    rig = calibration.rig
    assert rig.cam0.intrinsics[0] == pytest.approx(K[0, 0], rel=0.01)
    assert rig.baseline_m == pytest.approx(BASELINE_M, rel=0.01)
    # and the other way round: a current board given :legacy is told to drop it
    current = _recording(tmp_path / "current", legacy=False, views=3)
    with pytest.raises(RectifyError, match=r"not the legacy pattern .*: drop :legacy"):
        calibrate_recording(current, parse_board_spec(f"{spec}:legacy"), "pinhole-radtan")
