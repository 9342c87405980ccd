import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from lenspair.cli import main
from lenspair.core.imageio import read_image
from lenspair.rectify.boards import parse_board_spec
from lenspair.rectify.rig import CameraModel
from lenspair.simulate import boards
from lenspair.simulate.boardspec import BoardSpec
from lenspair.simulate.errors import SimulateError
from lenspair.simulate.recording import simulate_recording
from lenspair.simulate.spec import load_scene, with_overrides

SAMPLES = Path(__file__).resolve().parents[2] / "calib_samples"
WIDTH, HEIGHT = 720, 540


def _render(tmp_path: Path, name: str, frames: int) -> tuple[Path, dict[str, Any]]:
    spec = with_overrides(load_scene(SAMPLES / f"{name}.yaml"), frames=frames)
    out = tmp_path / name
    simulate_recording(spec, out, base_dir=SAMPLES)
    return out, json.loads((out / "truth" / "geometry.json").read_text())


def _views(out: Path, geometry: dict[str, Any]) -> list[tuple[str, np.ndarray, np.ndarray]]:
    views = []
    for frame in geometry["frames"]:
        for camera in ("cam0", "cam1"):
            entry = frame[camera]
            image = read_image(out / "mav0" / camera / "data" / f"{entry['t_ns']}.png")
            views.append((camera, image, np.array(entry["board_corners_px"])))
    return views


def test_chessboard_found_in_every_view_at_its_true_position(tmp_path: Path) -> None:
    # Nine views = one pass over the 3x3 grid of target cells.
    out, geometry = _render(tmp_path, "chessboard", 9)
    board = geometry["board"]
    pattern = (board["cols"], board["rows"])
    errors = []
    corner_regions: set[str] = set()
    for _camera, image, truth in _views(out, geometry):
        assert truth.shape == (54, 2)
        assert truth[:, 0].min() > 0 and truth[:, 0].max() < WIDTH - 1
        assert truth[:, 1].min() > 0 and truth[:, 1].max() < HEIGHT - 1
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(image, pattern, flags=flags)
        assert found
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
        corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)
        # Nearest true corner (the detector's ordering may run either way round).
        distance = np.linalg.norm(corners[:, None, :] - truth[None, :, :], axis=2)
        assert len(set(distance.argmin(axis=1))) == 54
        errors.append(distance.min(axis=1))
        left, right = truth[:, 0] < WIDTH / 4, truth[:, 0] > 3 * WIDTH / 4
        top, bottom = truth[:, 1] < HEIGHT / 4, truth[:, 1] > 3 * HEIGHT / 4
        for name, inside in {"tl": left & top, "tr": right & top, "bl": left & bottom,
                             "br": right & bottom}.items():  # fmt: skip
            if inside.any():
                corner_regions.add(name)
    error = np.concatenate(errors)
    assert np.median(error) < 0.1 and np.percentile(error, 95) < 0.25
    # Views reach every corner region of the image (calibration needs the periphery).
    assert corner_regions == {"tl", "tr", "bl", "br"}


def test_charuco_corners_detected_in_every_view(tmp_path: Path) -> None:
    out, geometry = _render(tmp_path, "charuco", 6)
    board = geometry["board"]
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board["dictionary"]))
    charuco = cv2.aruco.CharucoBoard(
        (board["cols"], board["rows"]), board["square_m"], board["marker_m"], dictionary
    )
    np.testing.assert_allclose(charuco.getChessboardCorners(), board["object_points"], atol=1e-6)
    detector = cv2.aruco.CharucoDetector(charuco)
    errors = []
    for _camera, image, truth in _views(out, geometry):
        corners, ids, _, _ = detector.detectBoard(image)
        assert ids is not None and len(ids) >= 0.6 * len(truth)
        errors.append(np.linalg.norm(corners.reshape(-1, 2) - truth[ids.ravel()], axis=1))
    assert np.median(np.concatenate(errors)) < 0.1


def test_rotated_rig_views_are_upside_down(tmp_path: Path) -> None:
    _, geometry = _render(tmp_path, "chessboard_rotated", 2)
    for frame in geometry["frames"]:
        first0, last0 = np.array(frame["cam0"]["board_corners_px"])[[0, -1]]
        first1, last1 = np.array(frame["cam1"]["board_corners_px"])[[0, -1]]
        # The board's first corner is up-left of its last in cam0, down-right in cam1.
        assert np.all(first0 < last0) and np.all(first1 > last1)


@pytest.mark.parametrize("kind", ["chessboard", "charuco"])
def test_printed_board_matches_object_points(kind: str) -> None:
    board = BoardSpec(kind=kind, cols=5, rows=4, square_m=0.05, pixels_per_square=32)
    image = board.target.printed_image(board.pixels_per_square)
    points = boards.object_points(board)
    across, down = board.target.squares
    assert image.shape == ((down + 2) * 32, (across + 2) * 32)
    # Board-frame metres -> printed pixel edges: one square of white border first.
    for x, y, _ in points:
        col, row = round(x / 0.05 * 32) + 32, round(y / 0.05 * 32) + 32
        quad = image[row - 2 : row + 2, col - 2 : col + 2].astype(int)
        # An inner corner: diagonal neighbours equal, adjacent ones opposite.
        assert quad[0, 0] == quad[3, 3] and quad[0, 3] == quad[3, 0] and quad[0, 0] != quad[0, 3]


@pytest.mark.parametrize("kind", ["chessboard", "charuco"])
def test_scene_board_is_the_calibration_board(kind: str) -> None:
    # the spec a user passes to `lenspair calibrate` for a simulated board names the same board
    marker = 0.03 if kind == "charuco" else None
    spec = BoardSpec(kind=kind, cols=6, rows=5, square_m=0.04, marker_m=marker)
    target = spec.target
    assert parse_board_spec(target.spec()) == target
    # the simulator's frame differs from calibration's only by where the origin is
    shift = boards.object_points(spec) - target.object_points()
    np.testing.assert_allclose(shift, np.tile(shift[0], (len(shift), 1)), atol=1e-12)
    if kind == "charuco":
        expected = target.charuco().getChessboardCorners()
        np.testing.assert_allclose(boards.object_points(spec), expected, atol=1e-7)


def test_a_chessboard_with_marker_settings_is_a_spec_error() -> None:
    # they were accepted and ignored: the user meant a ChArUco board, or a setting does nothing
    with pytest.raises(ValueError, match="a chessboard has no markers"):
        BoardSpec(kind="chessboard", cols=9, rows=6, square_m=0.04, marker_m=0.03)
    with pytest.raises(ValueError, match="a chessboard has no markers"):
        BoardSpec(kind="chessboard", cols=9, rows=6, square_m=0.04, dictionary="DICT_4X4_50")


def test_board_the_calibrator_rejects_is_a_spec_error() -> None:
    with pytest.raises(ValueError, match=r"needs .* markers"):
        BoardSpec(kind="charuco", cols=20, rows=12, square_m=0.02, dictionary="DICT_4X4_50")


def test_impossible_board_poses_are_an_error() -> None:
    camera = CameraModel((350.0, 350.0, 359.5, 269.5), "equidistant", (0.0,) * 4, (720, 540))
    huge = BoardSpec(kind="chessboard", cols=9, rows=6, square_m=0.5, distance_m=(0.5, 0.6))
    with pytest.raises(SimulateError, match="board: no pose"):
        boards.sample_board_poses(
            huge, (camera, camera), (np.eye(4), np.eye(4)), 1, np.random.default_rng(0)
        )


def test_a_pose_grid_beyond_reason_is_refused_at_the_spec() -> None:
    # 100000 x 100000 poses: a 74.5 GiB allocation traceback while rendering
    with pytest.raises(ValueError, match=r"grid: expected sizes 1\.\.100"):
        BoardSpec(kind="chessboard", cols=9, rows=6, square_m=0.06, grid=(100_000, 100_000))


def test_impossible_board_poses_name_the_spec_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = yaml.safe_load((SAMPLES / "chessboard.yaml").read_text())
    data["board"]["margin_px"] = 200.0  # no pose keeps the board that far inside 720x540
    spec = tmp_path / "margin.yaml"
    spec.write_text(yaml.safe_dump(data))
    assert main(["simulate", str(spec), "--out", str(tmp_path / "out"), "--frames", "2"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"lenspair simulate: error: {spec}: board: no pose")
    # nothing written: a folder marked incomplete read as a killed run on the next try
    assert not (tmp_path / "out").exists()


def test_a_negative_margin_is_refused_at_the_spec() -> None:
    # it was accepted and put boards partly outside both images, against its definition
    with pytest.raises(ValueError, match=r"margin_px: expected 0\.\.1000, got -300"):
        BoardSpec(kind="chessboard", cols=9, rows=6, square_m=0.04, margin_px=-300.0)
    assert BoardSpec(kind="chessboard", cols=9, rows=6, square_m=0.04, margin_px=0.0)
