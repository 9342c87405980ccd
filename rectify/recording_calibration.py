"""Calibrate a stereo rig from a recording of a calibration board (the ``calibrate`` workflow).

Usage::

    from lenspair.rectify.boards import parse_board_spec
    from lenspair.rectify.recording_calibration import calibrate_recording, write_calibration

    calibration = calibrate_recording(
        Path("runs/board_01"), parse_board_spec("chessboard:9x6:0.05"), "pinhole-equi"
    )
    for line in calibration.summary():
        print(line)
    write_calibration(calibration, Path("runs/board_01/camchain.yaml"))

Steps: the two cameras' frames are paired by timestamp
(:func:`lenspair.capture.pairing.pair_frames`), at most ``max_views`` pairs
evenly spread in time are read, the board's corners are found in each image
and :func:`lenspair.rectify.calibration.calibrate_from_detections` calibrates
each camera alone, then the pair. A frame that cannot be read is recorded in
:attr:`RecordingCalibration.unreadable`, not fatal. ``lenspair calibrate``,
the demo (through that command) and ``benchmarks/bench_calibration.py`` call
this module.
"""

import logging
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lenspair.capture.pairing import FramePair, estimate_period_ns, pair_frames
from lenspair.capture.recording import open_recording
from lenspair.capture.recording_types import Recording
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import atomic_write_texts, json_text
from lenspair.core.progress import progress
from lenspair.core.spread import spread_indices
from lenspair.rectify.boards import Board
from lenspair.rectify.calib_types import CalibrationModel, CalibrationOptions, CalibrationResult
from lenspair.rectify.calibration import calibrate_from_detections
from lenspair.rectify.corner_detection import Detection, detect_corners, marker_family
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import StereoRig, kalibr_text

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class RecordingCalibration:
    """The calibration of one board recording, with what was read to get it.

    Attributes:
        recording: the recording path given.
        result: the calibration (rig, per-camera and stereo errors, rejected views).
        rig: the calibrated rig; for bags it carries the two image topics.
        frames: ``cam0``/``cam1`` frame counts, ``paired``, ``used`` pairs.
        view_names: ``t0=<ns> t1=<ns>`` of each used pair (rejected views
            are named by these).
        unreadable: one line per frame that could not be read.
        listing: one line per problem of the recording's listing (a frame
            ``data.csv`` names that is missing, a repeated or unreadable
            timestamp): frames left out before any was read, or warned about.
        warnings: what reading the views warned about (the calibration's own
            are in ``result``); both go to the report.
    """

    recording: Path
    result: CalibrationResult
    rig: StereoRig
    frames: dict[str, int]
    view_names: list[str]
    unreadable: list[str] = field(default_factory=list)
    listing: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> list[str]:
        """Lines for people: RMS errors, row disagreement, rejected and unreadable frames."""
        lines = self.result.summary()
        lines += [f"unreadable frame: {problem}" for problem in self.unreadable]
        if self.listing:
            lines.append(
                f"{len(self.listing)} problem(s) in the recording's listing (frames.listing in "
                f"the report); the first: {self.listing[0]}"
            )
        return lines

    def report(self) -> dict[str, Any]:
        """Plain JSON-serialisable report (``camchain.report.json``)."""
        report = self.result.report()
        report["recording"] = str(self.recording)
        report["frames"] = {
            **self.frames,
            "unreadable": list(self.unreadable),
            "listing": list(self.listing),
        }
        report["view_names"] = list(self.view_names)
        report["warnings"] = [*self.warnings, *report["warnings"]]
        return report


def _search_again(
    recording: Recording,
    pairs: list[FramePair],
    detections: list[list[Detection | None]],
    sizes: list[list[tuple[int, int] | None]],
    board: Board,
    needed: int,
) -> None:
    """Search the chessboard again, thoroughly, in the frames the quick pass missed.

    The quick check misses boards with squares of about 12 px or less, and a
    thorough search of a frame without a board takes about 20x as long: it is
    spent where the other camera saw the board at that moment, or on every
    miss when too few views are found for the calibration.
    """
    if board.kind != "chessboard":
        return
    both = sum(found[0] is not None and found[1] is not None for found in detections)
    misses = [
        (row, index)
        for row, found in enumerate(detections)
        for index in (0, 1)
        if found[index] is None
        and sizes[row][index] is not None
        and (found[1 - index] is not None or both < needed)
    ]
    for row, index in progress(misses, "searching again", total=len(misses), unit="image"):
        frames = recording.frames["cam0"] if index == 0 else recording.frames["cam1"]
        position = pairs[row].index0 if index == 0 else pairs[row].index1
        image = recording.load(frames[position])
        detections[row][index] = detect_corners(image, board, thorough=True)


def _squares_hint(image: np.ndarray, board: Board) -> str:
    """Why a chessboard may be found in no view: its squares counted, not its inner corners.

    A chessboard spec counts inner corners (OpenCV's, ROS's and Kalibr's
    convention): a board of 10x7 squares is ``chessboard:9x6``. Given as
    ``10x7``, it is found in no view, and that was all that was said.
    """
    if board.kind != "chessboard" or min(board.columns, board.rows) < 4:
        return ""
    corners = replace(board, columns=board.columns - 1, rows=board.rows - 1)
    if detect_corners(image, corners, thorough=False) is None:
        return ""
    return (
        f"; the frames show a chessboard of {corners.columns}x{corners.rows} inner corners: "
        f"the spec counts inner corners, not squares (chessboard:{corners.columns}x"
        f"{corners.rows}:...)"
    )


def _charuco_hint(image: np.ndarray, board: Board) -> str:
    """Why a ChArUco board may be found in no view: its markers' family, or its size.

    The chessboard corners of a ChArUco board are found through its markers;
    a spec naming another marker family, or the squares the other way round
    (ROWSxCOLS), finds none, and said only "found in 0 views".
    """
    if board.kind != "charuco" or board.dictionary is None:
        return ""
    family = marker_family(image)
    if family is None:
        return ""
    seen = family.rsplit("_", 1)[0]  # DICT_4X4
    if not board.dictionary.startswith(f"{seen}_"):
        return (
            f"; the frames show {seen} markers, not {board.dictionary}'s: give the board's "
            "dictionary as the spec's last field"
        )
    return (
        f"; {seen} markers are seen, so check COLSxROWS (squares across, then down, as the "
        "board was generated) and the dictionary's size"
    )


def calibrate_recording(
    recording_path: Path,
    board: Board,
    model: CalibrationModel,
    topics: tuple[str, str] | None = None,
    max_views: int = 100,
    options: CalibrationOptions | None = None,
) -> RecordingCalibration:
    """Calibrate a stereo rig from a recording of a board (see the module docstring).

    Args:
        recording_path: any layout :func:`lenspair.capture.recording.open_recording`
            reads (EuRoC/ASL folder, ROS bag, left/right folders).
        board: the board seen.
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        topics: bags only: ``(cam0_topic, cam1_topic)``; None picks them.
        max_views: at most this many frame pairs, evenly spread in time (0: all).
        options: outlier rejection and rectification settings.

    Returns:
        The calibration; nothing is written (see :func:`write_calibration`).

    Raises:
        RectifyError: ``max_views`` negative, no pairs, a camera with no
            readable frame, or too few views with the board.
        CaptureError: the recording cannot be opened.
    """
    if max_views < 0:
        raise RectifyError(f"max_views (--max-views): expected >= 0, got {max_views}")
    recording = open_recording(recording_path, topics)
    stamps0, stamps1 = recording.timestamps("cam0"), recording.timestamps("cam1")
    needed = (options or CalibrationOptions()).min_views
    if estimate_period_ns(stamps0, stamps1) is None:
        # pair_frames would ask for a pairing tolerance, which calibrate has no
        # option for: what is missing is board views, so that is what is said
        raise RectifyError(
            f"{recording_path}: one timestamp per camera ({len(stamps0)} cam0, "
            f"{len(stamps1)} cam1 frames); calibration needs at least {needed} views "
            "of the board in different poses"
        )
    pairing = pair_frames(stamps0, stamps1)
    pairs = [pairing.pairs[i] for i in spread_indices(len(pairing.pairs), max_views)]
    if not pairs:
        raise RectifyError(f"{recording_path}: no cam0/cam1 frames could be paired by timestamp")
    detections: list[list[Detection | None]] = []
    unreadable: list[str] = []
    sizes: list[list[tuple[int, int] | None]] = []  # per pair, per camera (None: unread)
    where: list[list[str]] = []
    first_problem: list[str] = ["", ""]  # per camera: why its first unread frame was not read
    looked_for_markers = False
    sample: np.ndarray | None = None  # one frame read, for a hint when the board is not found
    warnings: list[str] = []  # said here, and kept for the report
    for pair in progress(pairs, "detecting board", total=len(pairs), unit="pair"):
        found: list[Detection | None] = []
        sizes.append([None, None])
        where.append(["", ""])
        for index, position in enumerate((pair.index0, pair.index1)):
            frame = recording.frames["cam0" if index == 0 else "cam1"][position]
            where[-1][index] = frame.describe()
            try:
                image = recording.load(frame)
            except LenspairError as exc:  # a bad frame is recorded, not fatal
                unreadable.append(str(exc))
                first_problem[index] = first_problem[index] or str(exc)
                found.append(None)
                continue
            sizes[-1][index] = (image.shape[1], image.shape[0])
            sample = image if sample is None else sample
            found.append(detect_corners(image, board, thorough=False))
            if found[-1] is not None and board.kind == "chessboard" and not looked_for_markers:
                looked_for_markers = True  # once, on the first view that shows the board
                if (family := marker_family(image)) is not None:
                    warnings.append(
                        f"{frame.describe()}: the board carries ArUco markers "
                        f"({family.rsplit('_', 1)[0]} family): it is a ChArUco board, and a "
                        "chessboard spec reads its corners biased by them; give --board "
                        "charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT"
                    )
                    log.warning("%s", warnings[-1])
        detections.append(found)
    _search_again(recording, pairs, detections, sizes, board, needed)
    resolutions: list[tuple[int, int]] = []
    for index in (0, 1):
        # a camera's resolution is that of most of its frames: one odd frame
        # (resized, from another session) is left out, not taken for the camera's
        seen = Counter(size[index] for size in sizes if size[index] is not None)
        if not seen:
            raise RectifyError(
                f"{recording_path}: no cam{index} frame could be read ({len(pairs)} tried; "
                f"the first: {first_problem[index]})"
            )
        resolution = seen.most_common(1)[0][0]
        assert resolution is not None  # the Counter holds no None
        resolutions.append(resolution)
        for row, size in enumerate(sizes):
            odd = size[index]
            if odd is not None and odd != resolution:
                unreadable.append(
                    f"{where[row][index]}: {odd[0]}x{odd[1]} px, but most frames of "
                    f"cam{index} are {resolution[0]}x{resolution[1]}; left out"
                )
                detections[row][index] = None
    names = [f"t0={p.t0_ns} t1={p.t1_ns}" for p in pairs]
    try:
        result = calibrate_from_detections(
            [(found[0], found[1]) for found in detections],
            board,
            model,
            (resolutions[0], resolutions[1]),
            names,
            options,
        )
    except RectifyError as exc:  # name the recording and what was found in it
        views = [sum(found[i] is not None for found in detections) for i in (0, 1)]
        hint = ""
        if min(views) == 0 and sample is not None:
            hint = _charuco_hint(sample, board) or _squares_hint(sample, board)
        raise RectifyError(
            f"{recording_path}: {exc} ({len(pairs)} frame pairs examined; the board "
            f"{board.spec()} was found in {views[0]} cam0 and {views[1]} cam1 views){hint}"
        ) from None
    rig = result.rig
    if recording.topics is not None:
        rig = replace(rig, topics=recording.topics, topics_stated=True)
    frames = {
        "cam0": len(recording.frames["cam0"]),
        "cam1": len(recording.frames["cam1"]),
        "paired": len(pairing.pairs),
        "used": len(pairs),
    }
    listing = [str(problem) for problem in recording.problems]
    return RecordingCalibration(
        Path(recording_path), result, rig, frames, names, unreadable, listing, warnings
    )


def write_calibration(calibration: RecordingCalibration, camchain: Path) -> Path:
    """Write Kalibr's camchain to ``camchain`` and the JSON report beside it.

    Both or neither: a refused write (a full disk, a file-size limit) leaves
    the earlier pair as it was, never a camchain beside another run's report.

    Returns:
        The report's path: ``camchain.yaml`` -> ``camchain.report.json``.
    """
    report_path = camchain.with_suffix(".report.json")
    report = json_text(calibration.report())
    atomic_write_texts({report_path: report, camchain: kalibr_text(calibration.rig)})
    return report_path
