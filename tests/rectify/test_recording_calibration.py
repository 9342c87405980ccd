"""The calibrate workflow as a library function: simulated board recordings, bad frames."""

import os
from pathlib import Path

import cv2
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.cli import main
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.core.spread import spread_indices
from lenspair.rectify.boards import parse_board_spec
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.recording_calibration import (
    calibrate_recording,
    write_calibration,
)
from lenspair.rectify.rig import read_kalibr
from lenspair.simulate.recording import simulate_recording
from lenspair.simulate.spec import SceneSpec, load_scene, with_overrides
from tests.file_limits import REFUSALS, refuse_writes, run_with_file_limit

SAMPLES = Path(__file__).resolve().parents[2] / "calib_samples"


def _board_recording(tmp_path: Path, frames: int, scene: str = "chessboard.yaml") -> SceneSpec:
    """Simulate a bundled board scene of ``frames`` frames into ``tmp_path/rec``; its spec."""
    spec = with_overrides(load_scene(SAMPLES / scene), frames=frames)
    simulate_recording(spec, tmp_path / "rec", base_dir=SAMPLES)
    assert spec.board is not None
    return spec


@given(st.integers(0, 500), st.integers(0, 120))
def test_spread_indices_are_even_unique_and_cover_the_ends(count: int, limit: int) -> None:
    indices = spread_indices(count, limit)
    assert indices == sorted(set(indices)) and all(0 <= i < count for i in indices)
    if limit == 0 or count <= limit:
        assert indices == list(range(count))
    else:
        assert len(indices) == limit and indices[0] == 0 and indices[-1] == count - 1


def test_negative_max_views_is_refused_before_reading(tmp_path: Path) -> None:
    board = load_scene(SAMPLES / "chessboard.yaml").board
    assert board is not None
    with pytest.raises(RectifyError, match=r"max_views \(--max-views\): expected >= 0, got -1"):
        calibrate_recording(tmp_path / "missing", board.target, "pinhole-equi", max_views=-1)


@pytest.mark.slow
def test_an_unreadable_frame_is_recorded_not_fatal(tmp_path: Path) -> None:
    spec = _board_recording(tmp_path, 9)
    assert spec.board is not None
    broken = sorted((tmp_path / "rec" / "mav0" / "cam1" / "data").glob("*.png"))[4]
    broken.write_bytes(broken.read_bytes()[:200])  # truncated mid-file
    # the first cam0 frame at another size: it must not set the camera's resolution
    odd = sorted((tmp_path / "rec" / "mav0" / "cam0" / "data").glob("*.png"))[0]
    write_image(odd, cv2.resize(read_image(odd), (640, 480), interpolation=cv2.INTER_AREA))
    # a frame data.csv lists but that is gone: left out by the listing, and it was unsaid
    gone = sorted((tmp_path / "rec" / "mav0" / "cam1" / "data").glob("*.png"))[7]
    gone.unlink()
    model = "pinhole-equi" if spec.rig.cam0.distortion_model == "equidistant" else "pinhole-radtan"

    calibration = calibrate_recording(tmp_path / "rec", spec.board.target, model, max_views=0)

    assert len(calibration.unreadable) == 2 and broken.name in calibration.unreadable[0]
    assert odd.name in calibration.unreadable[1] and "640x480 px" in calibration.unreadable[1]
    assert calibration.rig.cam0.resolution == calibration.rig.cam1.resolution == (720, 540)
    assert calibration.frames == {"cam0": 9, "cam1": 8, "paired": 8, "used": 8}
    assert len(calibration.listing) == 1 and gone.name in calibration.listing[0]
    assert any("problem(s) in the recording's listing" in line for line in calibration.summary())
    assert calibration.result.counts["both_detected"] <= 7
    assert any(broken.name in line for line in calibration.summary())
    report_path = write_calibration(calibration, tmp_path / "out" / "camchain.yaml")
    assert report_path == tmp_path / "out" / "camchain.report.json"
    report = calibration.report()
    assert report["frames"]["unreadable"] == calibration.unreadable
    assert report["frames"]["listing"] == calibration.listing
    assert len(report["view_names"]) == 8 and report["recording"] == str(tmp_path / "rec")
    truth = read_kalibr(tmp_path / "rec" / "camchain.yaml")
    assert read_kalibr(tmp_path / "out" / "camchain.yaml").baseline_m == pytest.approx(
        truth.baseline_m, rel=0.02
    )


def _calibration_error(tmp_path: Path, frames: int) -> tuple[str, str]:
    """Calibrate a board recording of ``frames`` frames: ``(error message, board spec)``."""
    spec = _board_recording(tmp_path, frames)
    assert spec.board is not None
    with pytest.raises(RectifyError) as caught:
        calibrate_recording(tmp_path / "rec", spec.board.target, "pinhole-equi")
    return str(caught.value), spec.board.target.spec()


def test_one_frame_per_camera_says_views_are_missing(tmp_path: Path) -> None:
    message, _ = _calibration_error(tmp_path, frames=1)
    # it used to ask for a pairing tolerance, which calibrate has no option for
    assert "1 cam0, 1 cam1 frames" in message and "at least 5 views" in message
    assert "tolerance" not in message and str(tmp_path / "rec") in message


def test_too_few_board_views_names_the_recording_and_what_was_found(tmp_path: Path) -> None:
    message, board = _calibration_error(tmp_path, frames=3)
    # it said "cam0: only 3 usable board views, need at least 5", naming no recording
    assert message.startswith(f"{tmp_path / 'rec'}: ") and "need at least 5" in message
    assert "3 frame pairs examined" in message and board in message


def test_a_failed_calibration_leaves_no_folder_it_made(tmp_path: Path) -> None:
    # the out's folders were made before the calibration and left behind when it failed,
    # beside "nothing was written"
    spec = _board_recording(tmp_path, 3)  # too few views
    assert spec.board is not None
    (tmp_path / "kept").mkdir()
    out = tmp_path / "kept" / "new" / "sub" / "camchain.yaml"
    argv = ["calibrate", str(tmp_path / "rec"), "--board", spec.board.target.spec()]
    assert main([*argv, "--model", "pinhole-equi", "--out", str(out)]) == 2
    assert not (tmp_path / "kept" / "new").exists()
    assert (tmp_path / "kept").is_dir()  # the user's own folder stays


def test_an_out_that_is_a_file_of_the_recording_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # --out board/mav0/cam0/data.csv overwrote the recording's index, silently
    recording = tmp_path / "rec"
    (recording / "mav0" / "cam0").mkdir(parents=True)
    index = recording / "mav0" / "cam0" / "data.csv"
    index.write_text("#timestamp [ns],filename\n")
    argv = ["calibrate", str(recording), "--board", "chessboard:9x6:0.06", "--model"]
    frames = recording / "mav0" / "cam0" / "data" / "1.png"
    # a killed recorder's bag inside the folder is a file of it too (its suffix is .active)
    for out in (index, frames, recording / "rig.yaml", recording / "run.bag.active"):
        assert main([*argv, "pinhole-equi", "--out", str(out)]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert f"--out {out}: is a file of the recording" in line
    assert index.read_text() == "#timestamp [ns],filename\n"
    truth = recording / "truth" / "geometry.json"  # the simulator's truth: overwritten too
    truth.parent.mkdir()
    truth.write_text("{}")
    assert main([*argv, "pinhole-equi", "--out", str(truth)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"--out {truth}: a file of the recording" in line and "no calibrate wrote" in line
    assert truth.read_text() == "{}"
    # the advice is a path outside the recording: "beside the recording as camchain.yaml"
    # read as the folder's own camchain.yaml, the file the simulator had written there
    assert line.endswith(f"e.g. --out {tmp_path / 'rec.camchain.yaml'}")
    # given as "." from inside it, the advice still names a path outside it
    monkeypatch.chdir(recording)
    assert main(["calibrate", ".", *argv[2:], "pinhole-equi", "--out", "rig.yaml"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(f"e.g. --out {tmp_path / 'rec.camchain.yaml'}")


@pytest.mark.parametrize("code", REFUSALS)
def test_a_read_only_out_is_refused_before_the_calibration_runs(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    code: int,
) -> None:
    """It named ``.c.yaml.<pid>.<random>.tmp``, and only once the whole calibration had run."""
    mounted = tmp_path / "mounted"
    mounted.mkdir()
    refuse_writes(monkeypatch, mounted, code)
    out = mounted / "c.yaml"
    # no recording at all: the refusal comes first, so no minutes are spent calibrating
    argv = ["calibrate", str(tmp_path / "absent"), "--board", "chessboard:9x6:0.06"]
    assert main([*argv, "--model", "pinhole-equi", "--out", str(out)]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == f"lenspair calibrate: error: {out}: {os.strerror(code)}"
    assert list(mounted.iterdir()) == []


def test_a_file_too_large_is_named_and_writes_neither_file(tmp_path: Path) -> None:
    spec = _board_recording(tmp_path, 12)
    assert spec.board is not None

    def argv(out: Path, model: str = "pinhole-equi") -> list[str]:
        board = ["--board", spec.board.target.spec()]  # type: ignore[union-attr]
        return ["calibrate", str(tmp_path / "rec"), *board, "--model", model, "--out", str(out)]

    out = tmp_path / "cal" / "camchain.yaml"
    report = out.with_suffix(".report.json")
    failed = run_with_file_limit(argv(out), 256)  # nothing fits
    assert failed.returncode == 1, failed.stderr
    (line,) = failed.stderr.strip().splitlines()
    assert line in {f"lenspair calibrate: error: {path}: File too large" for path in (out, report)}
    assert not out.parent.exists()  # no temporary left behind, nor the folder it made
    # A limit the camchain fits under and its report does not: the camchain was written
    # without its report. Now neither, named.
    reference = tmp_path / "reference" / "camchain.yaml"
    assert main(argv(reference)) == 0
    sizes = [path.stat().st_size for path in (reference, reference.with_suffix(".report.json"))]
    assert sizes[0] < sizes[1]
    between = run_with_file_limit(argv(out), sum(sizes) // 2)
    assert between.returncode == 1, between.stderr
    (line,) = between.stderr.strip().splitlines()
    assert line == f"lenspair calibrate: error: {report}: File too large"
    assert not out.parent.exists()
    # and the pair of an earlier run (another model) stays a pair
    assert main(argv(out, "pinhole-radtan")) == 0
    earlier = {path: path.read_bytes() for path in (out, report)}
    assert run_with_file_limit(argv(out), sum(sizes) // 2).returncode == 1
    assert {path: path.read_bytes() for path in (out, report)} == earlier
    assert sorted(out.parent.iterdir()) == sorted(earlier)


def test_a_camera_none_of_whose_frames_reads_is_named_with_the_first_reason(
    tmp_path: Path,
) -> None:
    spec = _board_recording(tmp_path, 3)
    assert spec.board is not None
    frames = sorted((tmp_path / "rec" / "mav0" / "cam1" / "data").glob("*.png"))
    for frame in frames:
        frame.write_bytes(b"x\n")
    with pytest.raises(RectifyError) as caught:
        calibrate_recording(tmp_path / "rec", spec.board.target, "pinhole-equi")
    # it said "no frame of one camera could be read": which one, and why, was lost
    message = str(caught.value)
    assert message.startswith(f"{tmp_path / 'rec'}: no cam1 frame could be read (3 tried; ")
    assert f"the first: {frames[0]}" in message and "\n" not in message


@pytest.mark.slow
def test_views_refused_for_disagreeing_poses_are_named_when_too_few_are_left(
    tmp_path: Path,
) -> None:
    # cam1's frames one step out of step with cam0's: the error said only "1 usable view"
    spec = _board_recording(tmp_path, 10)
    assert spec.board is not None
    csv = tmp_path / "rec" / "mav0" / "cam1" / "data.csv"
    header, *rows = csv.read_text().splitlines()
    stamps, files = [r.split(",")[0] for r in rows], [r.split(",")[1] for r in rows]
    shifted = [f"{t},{f}" for t, f in zip(stamps[:-1], files[1:], strict=True)]
    csv.write_text("\n".join([header, *shifted]) + "\n")
    with pytest.raises(RectifyError, match=r"views refused as the cameras' poses disagree"):
        calibrate_recording(tmp_path / "rec", spec.board.target, "pinhole-equi")


@pytest.mark.slow
def test_a_fisheye_calibrated_as_pinhole_radtan_is_doubted_in_the_report(tmp_path: Path) -> None:
    # the baseline came out 5 % short with RMS 0.46 px, and the report said nothing
    spec = _board_recording(tmp_path, 12)
    assert spec.rig.cam0.distortion_model == "equidistant" and spec.board is not None
    wrong = calibrate_recording(tmp_path / "rec", spec.board.target, "pinhole-radtan")
    doubts = [w for w in wrong.report()["warnings"] if "pinhole-equi fits its views" in w]
    assert {w.split(":")[0] for w in doubts} == {"cam0", "cam1"}
    right = calibrate_recording(tmp_path / "rec", spec.board.target, "pinhole-equi")
    assert not any("fits its views" in w for w in right.report()["warnings"])


@pytest.mark.slow
def test_a_charuco_board_given_a_chessboard_spec_is_said_to_be_charuco(tmp_path: Path) -> None:
    # its corners were found, pulled by the markers: focal length 0.6 % off, unsaid
    board = _board_recording(tmp_path, 8, "charuco.yaml").board
    assert board is not None and board.kind == "charuco"
    chessboard = parse_board_spec(f"chessboard:{board.cols - 1}x{board.rows - 1}:{board.square_m}")
    calibration = calibrate_recording(tmp_path / "rec", chessboard, "pinhole-equi")
    said = [w for w in calibration.report()["warnings"] if "carries ArUco markers" in w]
    assert len(said) == 1 and f"({board.dictionary.rsplit('_', 1)[0]} family)" in said[0]
    right = calibrate_recording(tmp_path / "rec", board.target, "pinhole-equi")
    assert not any("ArUco markers" in w for w in right.report()["warnings"])


def test_a_charuco_board_found_in_no_view_is_said_to_have_other_markers_or_another_size(
    tmp_path: Path,
) -> None:
    # both said only "found in 0 cam0 and 0 cam1 views"
    board = _board_recording(tmp_path, 4, "charuco.yaml").board
    assert board is not None and board.marker_m is not None
    family = board.dictionary.rsplit("_", 1)[0]
    other = "DICT_7X7_50" if family != "DICT_7X7" else "DICT_4X4_50"
    size, square = f"{board.cols}x{board.rows}", f"{board.square_m}:{board.marker_m}"
    for spec, said in (
        (f"charuco:{size}:{square}:{other}", f"the frames show {family} markers, not {other}'s"),
        (f"charuco:{board.rows}x{board.cols}:{square}:{board.dictionary}", "check COLSxROWS"),
    ):
        with pytest.raises(RectifyError) as caught:
            calibrate_recording(tmp_path / "rec", parse_board_spec(spec), "pinhole-equi")
        assert "found in 0 cam0 and 0 cam1 views); " in str(caught.value)
        assert said in str(caught.value)


def test_a_chessboard_given_by_its_squares_is_said_to_count_inner_corners(
    tmp_path: Path,
) -> None:
    # 10x7 squares given for a 9x6 board: it said only "found in 0 cam0 and 0 cam1 views"
    board = _board_recording(tmp_path, 4).board
    assert board is not None and board.kind == "chessboard"
    squares = parse_board_spec(f"chessboard:{board.cols + 1}x{board.rows + 1}:{board.square_m}")
    with pytest.raises(RectifyError) as caught:
        calibrate_recording(tmp_path / "rec", squares, "pinhole-equi")
    assert "found in 0 cam0 and 0 cam1 views); " in str(caught.value)
    assert f"a chessboard of {board.cols}x{board.rows} inner corners" in str(caught.value)
    # a corner short, OpenCV finds that sub-grid in a few views: "too few views", no hint
    short = parse_board_spec(f"chessboard:{board.cols - 1}x{board.rows}:{board.square_m}")
    with pytest.raises(RectifyError) as caught:
        calibrate_recording(tmp_path / "rec", short, "pinhole-equi")
    said = str(caught.value)
    assert f"the frames show a chessboard of {board.cols}x{board.rows} inner corners" in said
    assert "counts every inner corner" in said


def test_frames_the_quick_check_missed_are_searched_again_only_where_it_may_pay(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a thorough search of a frame without a board costs about 20x the quick one: it is
    # spent where the other camera saw the board, or everywhere when too few views are found
    import numpy as np

    from lenspair.capture.pairing import FramePair
    from lenspair.rectify import recording_calibration
    from lenspair.rectify.corner_detection import Detection

    board = parse_board_spec("chessboard:9x6:0.05")
    seen = Detection(np.arange(3, dtype=np.int32), np.zeros((3, 2), np.float32))
    searched: list[str] = []

    class Frames:
        def __init__(self) -> None:
            self.frames = {"cam0": ["a0", "b0", "c0"], "cam1": ["a1", "b1", "c1"]}

        def load(self, frame: str) -> str:
            return frame

    def thorough(image: str, board: object, thorough: bool = True) -> Detection:
        assert thorough
        searched.append(image)
        return seen

    monkeypatch.setattr(recording_calibration, "detect_corners", thorough)
    pairs = [FramePair(i, i, 0, 0) for i in range(3)]
    sizes: list[list[tuple[int, int] | None]] = [[(8, 8), (8, 8)]] * 3
    found = [[seen, None], [None, None], [seen, seen]]
    search = recording_calibration._search_again
    search(Frames(), pairs, found, sizes, board, needed=1)  # type: ignore[arg-type]
    assert searched == ["a1"] and found[0] == [seen, seen]
    searched.clear()
    found = [[seen, None], [None, None], [seen, seen]]
    search(Frames(), pairs, found, sizes, board, needed=5)  # type: ignore[arg-type]
    assert searched == ["a1", "b0", "b1"]  # too few views: every miss
