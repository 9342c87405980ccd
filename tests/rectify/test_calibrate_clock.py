"""calibrate and a clock offset between the cameras: ``--time-offset`` and the warning.

A synthetic left/right board recording at 4 Hz whose cam1 file names run
ahead of cam0's, as cameras without a common clock name their frames.
"""

import json
import logging
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from lenspair.cli import main
from lenspair.core.imagewrite import write_image
from lenspair.rectify.boards import parse_board_spec
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.recording_calibration import RecordingCalibration, calibrate_recording
from tests.rectify.board_renderer import board_texture

BOARD = parse_board_spec("chessboard:9x6:0.04")
K = np.array([[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
PERIOD_NS = 250_000_000  # 4 Hz
START_NS = 1_700_000_000_000_000_000
VIEWS = 12


def _render(
    texture: np.ndarray, board_to_texture: np.ndarray, rotation: np.ndarray, t: np.ndarray
) -> np.ndarray:
    """The board at pose ``(rotation, t)`` through a pinhole camera, drawn at 4x and averaged."""
    s = 4
    upscale = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1.0]])
    board_to_image = K @ np.column_stack([rotation[:, 0], rotation[:, 1], t])
    warp = upscale @ board_to_image @ np.linalg.inv(board_to_texture)
    fine = cv2.warpPerspective(
        texture, warp, (SIZE[0] * s, SIZE[1] * s), flags=cv2.INTER_LINEAR, borderValue=110
    )
    return np.asarray(cv2.resize(fine, SIZE, interpolation=cv2.INTER_AREA), np.uint8)


def _record(path: Path, cam1_ahead_ns: int) -> Path:
    """Write the recording: the same views, cam1's stamps ``cam1_ahead_ns`` late."""
    texture, board_to_texture = board_texture(BOARD, pixels_per_square=60)
    centre = BOARD.object_points().mean(axis=0)
    to_cam1 = cv2.Rodrigues(np.array([0.002, -0.003, 0.001]))[0]
    rng = np.random.default_rng(11)
    for folder in ("left", "right"):
        (path / folder).mkdir(parents=True)
    for view in range(VIEWS):
        rotation = cv2.Rodrigues(np.deg2rad(rng.uniform(-30, 30, 3)) * np.array([1, 1, 0.3]))[0]
        where = np.array(
            [rng.uniform(-0.04, 0.09), rng.uniform(-0.04, 0.04), rng.uniform(0.6, 0.9)]
        )
        t = where - rotation @ centre
        stamp = START_NS + view * PERIOD_NS
        left = _render(texture, board_to_texture, rotation, t)
        moved = to_cam1 @ t + np.array([-0.1, 0.0, 0.0])
        right = _render(texture, board_to_texture, to_cam1 @ rotation, moved)
        write_image(path / "left" / f"{stamp}.png", left)
        write_image(path / "right" / f"{stamp + cam1_ahead_ns}.png", right)
    return path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    """The recording with cam1's clock 0, 100 and 150 ms ahead of cam0's."""
    root = tmp_path_factory.mktemp("clock")
    synced = _record(root / "ahead_0", 0)
    shifted = {0: synced}
    for ahead_ms in (100, 150):
        copy = root / f"ahead_{ahead_ms}"
        shutil.copytree(synced / "left", copy / "left")
        (copy / "right").mkdir()
        for frame in sorted((synced / "right").glob("*.png")):
            stamp = int(frame.stem) + ahead_ms * 1_000_000
            shutil.copy(frame, copy / "right" / f"{stamp}.png")
        shifted[ahead_ms] = copy
    return shifted


@pytest.fixture(scope="module")
def reference(recordings: dict[int, Path]) -> RecordingCalibration:
    """The calibration of the recording whose clocks agree."""
    calibration = calibrate_recording(recordings[0], BOARD, "pinhole-radtan")
    assert calibration.result.counts["both_detected"] == VIEWS
    assert not any("clocks may differ" in w for w in calibration.report()["warnings"])
    return calibration


def _same_calibration(calibration: RecordingCalibration, reference: RecordingCalibration) -> None:
    """The same views paired alike: the same fit (to OpenCV's threads' rounding)."""
    for camera in ("cam0", "cam1"):
        ours, theirs = getattr(calibration.rig, camera), getattr(reference.rig, camera)
        np.testing.assert_allclose(ours.intrinsics, theirs.intrinsics, rtol=1e-6)
        np.testing.assert_allclose(ours.distortion, theirs.distortion, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(
        calibration.rig.T_cam1_cam0, reference.rig.T_cam1_cam0, rtol=1e-6, atol=1e-9
    )


def test_clocks_over_half_a_period_apart_are_named_and_paired_with_time_offset(
    recordings: dict[int, Path], reference: RecordingCalibration
) -> None:
    # 150 ms at 4 Hz paired every frame with the next: "16 views refused as the cameras'
    # poses disagree", with no word of the clocks and no option to pair them
    with pytest.raises(RectifyError) as caught:
        calibrate_recording(recordings[150], BOARD, "pinhole-radtan")
    message = str(caught.value)
    assert "views refused as the cameras' poses disagree" in message and "\n" not in message
    assert "cam1's frames pair -100.0 ms from cam0's on median" in message
    assert "(--time-offset -100.0 or 150.0)" in message

    paired = calibrate_recording(
        recordings[150], BOARD, "pinhole-radtan", time_offset_ns=150_000_000
    )
    _same_calibration(paired, reference)
    report = paired.report()
    assert report["time_offset_ns"] == 150_000_000
    assert not any("clocks may differ" in w for w in report["warnings"])
    # views are named by the stamps recorded, which name the files
    t1 = [int(name.split("t1=")[1]) for name in paired.view_names]
    assert t1 == [START_NS + v * PERIOD_NS + 150_000_000 for v in range(VIEWS)]


def test_a_pairing_gap_under_half_a_period_is_warned_as_capture_ingest_does(
    recordings: dict[int, Path],
    reference: RecordingCalibration,
    caplog: pytest.LogCaptureFixture,
) -> None:
    # 100 ms at 4 Hz calibrated without a word, where capture-ingest warned of the same stamps
    with caplog.at_level(logging.WARNING):
        warned = calibrate_recording(recordings[100], BOARD, "pinhole-radtan")
    _same_calibration(warned, reference)
    said = [w for w in warned.report()["warnings"] if "clocks may differ" in w]
    assert len(said) == 1 and "+100.0 ms from cam0's on median" in said[0]
    assert "--time-offset" in said[0] and str(recordings[100]) in said[0]
    assert any("clocks may differ" in record.getMessage() for record in caplog.records)
    assert warned.report()["time_offset_ns"] == 0
    offset = calibrate_recording(
        recordings[100], BOARD, "pinhole-radtan", time_offset_ns=100_000_000
    )
    _same_calibration(offset, reference)
    assert not any("clocks may differ" in w for w in offset.report()["warnings"])


def test_an_offset_that_leaves_no_pair_is_named(recordings: dict[int, Path]) -> None:
    with pytest.raises(RectifyError, match=r"--time-offset 1e\+06 ms leaves no cam0 frame"):
        calibrate_recording(
            recordings[0], BOARD, "pinhole-radtan", time_offset_ns=1_000_000_000_000
        )


def test_the_command_takes_time_offset_in_ms_and_the_report_keeps_it(
    recordings: dict[int, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "camchain.yaml"
    argv = ["calibrate", str(recordings[150]), "--board", BOARD.spec(), "--model"]
    assert main([*argv, "pinhole-radtan", "--out", str(out), "--time-offset", "150"]) == 0
    report = json.loads(out.with_suffix(".report.json").read_text())
    assert report["time_offset_ns"] == 150_000_000
    assert report["counts"]["both_detected"] == VIEWS
    capsys.readouterr()
    with pytest.raises(SystemExit) as refused:  # argparse's refusal, as capture-ingest's
        main([*argv, "pinhole-radtan", "--out", str(out), "--time-offset", "nan"])
    assert refused.value.code == 2
    assert "--time-offset" in capsys.readouterr().err
