import cv2
import numpy as np
import pytest

from lenspair.rectify.boards import Board, parse_board_spec
from lenspair.rectify.corner_detection import detect_corners
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.projection import project_rays
from lenspair.rectify.rig import CameraModel
from tests.rectify.board_renderer import BoardRenderer, board_texture

CAMERA = CameraModel(
    (350.0, 351.0, 360.0, 270.0), "equidistant", (0.01, -0.002, 0.001, -0.0005), (720, 540)
)


def test_parse_chessboard_and_charuco_specs() -> None:
    board = parse_board_spec("chessboard:9x6:0.025")
    assert (board.kind, board.columns, board.rows, board.square_m) == ("chessboard", 9, 6, 0.025)
    assert board.grid == (9, 6) and board.num_corners == 54
    charuco = parse_board_spec("ChArUco:8X6:0.04:0.03:5x5_100")
    assert charuco.dictionary == "DICT_5X5_100" and charuco.marker_m == 0.03
    assert charuco.grid == (7, 5) and charuco.num_corners == 35
    assert parse_board_spec("charuco:8x6:0.04:0.03").dictionary == "DICT_5X5_100"
    assert parse_board_spec(charuco.spec()) == charuco


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("checker:9x6:0.02", r"unknown board type 'checker'; expected chessboard:COLSxROWS"),
        ("chessboard:9x6", r"expected chessboard:COLSxROWS:SQUARE_M"),
        ("chessboard:9by6:0.02", r"COLSxROWS must look like 9x6, got '9by6'"),
        ("chessboard:9x6:abc", r"SQUARE_M must be a length in metres, got 'abc'"),
        ("chessboard:9x6:25", r"did you give millimetres"),
        ("chessboard:9x6:1e-9", r"1e-09 m is under a millimetre"),  # OpenCV's ill-conditioned
        ("chessboard:1x6:0.02", r"at least 3x3 inner corners, got 1x6"),
        # cv2.findChessboardCorners raised "should have bigger than 2": a traceback
        ("chessboard:2x5:0.02", r"at least 3x3 inner corners, got 2x5"),
        ("chessboard:99999999999x6:0.06", r"at most 200 along a side"),  # an OpenCV traceback
        ("charuco:8x6:0.04", r"expected charuco:COLSxROWS:SQUARE_M:MARKER_M\[:DICT\]"),
        ("charuco:8x6:0.04:0.05", r"expected 0 < MARKER_M < SQUARE_M = 0.04"),
        ("charuco:8x6:0.04:0.03:DICT_9X9_1", r"unknown 'DICT_9X9_1'; valid: DICT_4X4_100"),
        ("charuco:20x20:0.04:0.03:DICT_4X4_50", r"needs 200 markers, DICT_4X4_50 has 50"),
    ],
)
def test_bad_board_specs_say_what_is_wrong(spec: str, message: str) -> None:
    with pytest.raises(RectifyError, match=message):
        parse_board_spec(spec)


@pytest.mark.parametrize("square", ["nan", "inf", "-25"])
def test_a_square_size_that_is_no_length_gets_no_millimetre_hint(square: str) -> None:
    with pytest.raises(RectifyError, match=r"expected 0 < SQUARE_M < 1") as caught:
        parse_board_spec(f"chessboard:9x6:{square}")
    assert "millimetres" not in str(caught.value)


def test_chessboard_symmetries_are_rotations_of_the_grid() -> None:
    board = parse_board_spec("chessboard:4x3:0.1")
    perms = board.symmetries()
    assert len(perms) == 2 and list(perms[0]) == list(range(12))
    assert list(perms[1]) == list(range(11, -1, -1))  # a 180 deg turn reverses the numbering
    assert len(parse_board_spec("chessboard:5x5:0.1").symmetries()) == 4
    assert len(parse_board_spec("charuco:5x4:0.1:0.07").symmetries()) == 1


def test_detect_chessboard_in_a_warped_image() -> None:
    board = parse_board_spec("chessboard:7x5:0.03")
    texture, board_to_texture = board_texture(board, pixels_per_square=40)
    H = np.array([[0.9, 0.12, 60.0], [-0.05, 0.85, 40.0], [1e-4, 2e-4, 1.0]])
    image = cv2.warpPerspective(texture, H, (640, 480), flags=cv2.INTER_AREA, borderValue=120)
    detection = detect_corners(image, board)
    assert detection is not None and len(detection) == board.num_corners
    xy = board.object_points()[:, :2] @ board_to_texture[:2, :2].T + board_to_texture[:2, 2]
    truth = cv2.perspectiveTransform(xy.reshape(-1, 1, 2), H).reshape(-1, 2)
    error = np.linalg.norm(detection.corners - truth, axis=1)
    if error.max() > 5:  # the detector may number a chessboard from the opposite corner
        error = np.linalg.norm(detection.corners[::-1] - truth, axis=1)
    assert error.max() < 0.25


@pytest.mark.parametrize("bits", [16, 12, 10])
def test_a_board_in_16_bit_words_is_found_whatever_bits_the_camera_fills(bits: int) -> None:
    # mono16 from a Mono10/Mono12 camera holds 0..1023 or 0..4095: the top byte
    # of those is all but 0, and calibrate found no board in a single frame
    board = parse_board_spec("chessboard:7x5:0.03")
    texture, _ = board_texture(board, pixels_per_square=40)
    H = np.array([[0.9, 0.12, 60.0], [-0.05, 0.85, 40.0], [1e-4, 2e-4, 1.0]])
    image = cv2.warpPerspective(texture, H, (640, 480), flags=cv2.INTER_AREA, borderValue=120)
    wide = (image.astype(np.uint16) * 257) >> (16 - bits)  # full scale -> 2**bits - 1
    detection, reference = detect_corners(wide, board), detect_corners(image, board)
    assert detection is not None and reference is not None
    assert len(detection) == len(reference) == board.num_corners
    assert np.abs(detection.corners - reference.corners).max() < 0.05


@pytest.mark.parametrize("spec", ["chessboard:9x6:0.05", "charuco:10x7:0.05:0.037"])
def test_detect_board_seen_through_a_fisheye_lens(spec: str) -> None:
    board = parse_board_spec(spec)
    renderer = BoardRenderer(board, CAMERA)
    rotation = cv2.Rodrigues(np.array([0.25, -0.3, 0.1]))[0]
    t = np.array([0.05, 0.0, 0.75]) - rotation @ board.object_points().mean(axis=0)
    image = renderer.render(cv2.Rodrigues(rotation)[0], t)
    detection = detect_corners(image, board)
    assert detection is not None and len(detection) >= 0.9 * board.num_corners
    truth = project_rays(CAMERA, board.object_points() @ rotation.T + t)[detection.ids]
    error = np.linalg.norm(detection.corners - truth, axis=1)
    if board.kind == "chessboard" and error.max() > 5:
        error = np.linalg.norm(detection.corners[::-1] - truth, axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.2
    assert detection.corners.dtype == np.float32 and detection.ids.dtype == np.int32


@pytest.mark.parametrize("pixels_per_square", [7, 10, 12])
def test_a_far_chessboard_with_small_squares_is_found(pixels_per_square: int) -> None:
    # squares of 12 px or less: cv2's FAST_CHECK alone rejected these boards
    board = parse_board_spec("chessboard:9x6:0.025")
    texture, board_to_texture = board_texture(board, pixels_per_square=pixels_per_square)
    noise = np.random.default_rng(0).normal(0, 4, (720, 1280))
    image = np.clip(128 + noise, 0, 255).astype(np.uint8)
    y, x = 300, 500
    image[y : y + texture.shape[0], x : x + texture.shape[1]] = texture
    detection = detect_corners(image, board)
    assert detection is not None and len(detection) == board.num_corners
    xy = board.object_points()[:, :2] @ board_to_texture[:2, :2].T + board_to_texture[:2, 2]
    truth = xy + np.array([x, y])
    error = np.linalg.norm(detection.corners - truth, axis=1)
    if error.max() > 5:  # numbered from the opposite corner
        error = np.linalg.norm(detection.corners[::-1] - truth, axis=1)
    assert error.max() < 0.3


def test_no_board_gives_none() -> None:
    blank = np.full((240, 320), 128, np.uint8)
    assert detect_corners(blank, parse_board_spec("chessboard:9x6:0.05")) is None
    assert detect_corners(blank, parse_board_spec("charuco:5x4:0.05:0.04")) is None


@pytest.mark.parametrize(
    "image",
    [
        np.zeros((240, 320, 1), np.uint8),
        np.zeros((240, 320, 4), np.uint8),
        np.zeros((240, 320), np.float32),
        np.zeros((2, 240, 320), np.uint8),
    ],
    ids=["one-channel", "rgba", "float", "stack"],
)
def test_an_image_it_cannot_read_is_a_one_line_error(image: np.ndarray) -> None:
    with pytest.raises(
        RectifyError, match=rf"uint8/uint16 .* got {image.dtype} \({image.shape[0]}"
    ):
        detect_corners(image, parse_board_spec("chessboard:9x6:0.05"))


def test_board_is_validated_on_construction() -> None:
    with pytest.raises(RectifyError, match="marker size"):
        Board("charuco", 5, 4, 0.05, None, "DICT_5X5_100")


@pytest.mark.parametrize("spec", ["chessboard:6x4:0.05", "charuco:6x5:0.05:0.035"])
def test_printed_board_puts_corners_at_object_points(spec: str) -> None:
    board = parse_board_spec(spec)
    pixels_per_square = 24
    image = board.printed_image(pixels_per_square)
    across, down = board.squares
    assert image.shape == ((down + 2) * pixels_per_square, (across + 2) * pixels_per_square)
    assert image.dtype == np.uint8 and set(np.unique(image)) <= {0, 255}
    assert image[0].min() == 255 and image[:, 0].min() == 255  # white quiet zone
    width, height = board.grid_size_m
    assert (width, height) == pytest.approx((across * 0.05, down * 0.05))
    points = board.object_points(grid_origin=True)
    shift = points - board.object_points()
    np.testing.assert_allclose(shift, shift[:1].repeat(len(points), axis=0))
    for x, y, _ in points:
        col = round(x / board.square_m * pixels_per_square) + pixels_per_square
        row = round(y / board.square_m * pixels_per_square) + pixels_per_square
        quad = image[row - 2 : row + 2, col - 2 : col + 2].astype(int)
        assert quad[0, 0] == quad[3, 3] and quad[0, 3] == quad[3, 0] and quad[0, 0] != quad[0, 3]
    # the printed board is what the detector finds (through the test renderer's texture)
    texture, _ = board_texture(board, pixels_per_square=40)
    detection = detect_corners(cv2.copyMakeBorder(texture, 20, 20, 20, 20, 0, value=255), board)
    assert detection is not None and len(detection) == board.num_corners


@pytest.mark.parametrize("stated_m", [0.03, 0.02, 0.035])
def test_charuco_markers_are_measured_on_the_image_whatever_size_the_spec_states(
    stated_m: float,
) -> None:
    """The measure is the printed marker's (0.03 m), not the spec's, within a few per cent."""
    printed = parse_board_spec("charuco:8x6:0.04:0.03")
    texture, _ = board_texture(printed, pixels_per_square=60)
    H = np.array([[0.8, 0.1, 50.0], [-0.06, 0.78, 40.0], [1e-4, 1.5e-4, 1.0]])
    image = cv2.warpPerspective(texture, H, (620, 480), flags=cv2.INTER_AREA, borderValue=120)
    stated = parse_board_spec(f"charuco:8x6:0.04:{stated_m}")
    detection = detect_corners(image, stated)
    assert detection is not None and detection.marker_m is not None
    assert detection.marker_m == pytest.approx(0.03, rel=0.06)
    chessboard = parse_board_spec("chessboard:7x5:0.03")
    found = detect_corners(board_texture(chessboard, pixels_per_square=40)[0], chessboard)
    assert found is not None and found.marker_m is None


def test_a_charuco_board_object_is_built_once_per_spec(capfd: pytest.CaptureFixture[str]) -> None:
    # OpenCV warns at each construction of a thin-bordered board: once an image, 72 lines
    spec = "charuco:7x5:0.1:0.09:DICT_4X4_50"
    first = parse_board_spec(spec).charuco()
    assert parse_board_spec(spec).charuco() is first
    assert parse_board_spec("charuco:7x5:0.1:0.08:DICT_4X4_50").charuco() is not first
    capfd.readouterr()
    for _ in range(3):
        parse_board_spec(spec).charuco()
    assert "Marker border" not in capfd.readouterr().err


@pytest.mark.parametrize("marker_m", [0.06, 0.07, 0.08])
def test_charuco_corners_are_refined_closer_to_the_truth_than_opencv_finds_them(
    marker_m: float,
) -> None:
    # the refinement window must stay clear of the markers' edges, which pull
    # the corner: one reaching them left corners farther off than OpenCV's own
    board = parse_board_spec(f"charuco:7x5:0.1:{marker_m}")
    renderer = BoardRenderer(board, CAMERA)
    rng = np.random.default_rng(1)
    parameters = cv2.aruco.CharucoParameters()
    parameters.tryRefineMarkers = True
    opencv = cv2.aruco.CharucoDetector(board.charuco(), parameters, cv2.aruco.DetectorParameters())
    ours, theirs = [], []
    for distance in (0.9, 1.1, 1.3, 1.5, 1.8):
        rotation = cv2.Rodrigues(rng.uniform(-0.35, 0.35, 3))[0]
        t = np.array([0.0, 0.0, distance]) - rotation @ board.object_points().mean(axis=0)
        image = renderer.render(cv2.Rodrigues(rotation)[0], t)
        image = np.clip(image + rng.normal(0, 2, image.shape), 0, 255).astype(np.uint8)
        truth = project_rays(CAMERA, board.object_points() @ rotation.T + t)
        detection = detect_corners(image, board)
        corners, ids, _, _ = opencv.detectBoard(image)
        assert detection is not None and ids is not None
        ours.append(np.linalg.norm(detection.corners - truth[detection.ids], axis=1).mean())
        theirs.append(np.linalg.norm(corners.reshape(-1, 2) - truth[ids.ravel()], axis=1).mean())
    assert np.mean(ours) < min(np.mean(theirs), 0.1)
