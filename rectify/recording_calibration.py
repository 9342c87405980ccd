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
(:func:`lenspair.capture.pairing.pair_frames`; cam1's stamps less
``time_offset_ns``, on cam0's clock, as ``capture-ingest --time-offset`` pairs
them, with its warning when the pairs are far apart), at most ``max_views`` pairs
evenly spread over the pairs (by index) are read, the board's corners are found in each image
and :func:`lenspair.rectify.calibration.calibrate_from_detections` calibrates
each camera alone, then the pair. A frame that cannot be read is recorded in
:attr:`RecordingCalibration.unreadable`, not fatal. ``lenspair calibrate``,
the demo (through that command) and ``benchmarks/bench_calibration.py`` call
this module.
"""

import logging
import statistics
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lenspair.capture.pairing import (
    FramePair,
    PairingResult,
    clock_offset_warning,
    estimate_period_ns,
    pair_frames,
)
from lenspair.capture.recording import open_recording
from lenspair.capture.recording_types import Recording
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import atomic_write_texts, json_text
from lenspair.core.progress import progress
from lenspair.core.spread import spread_indices
from lenspair.rectify.boards import Board
from lenspair.rectify.calib_types import CalibrationModel, CalibrationOptions, CalibrationResult
from lenspair.rectify.calibration import calibrate_from_detections
from lenspair.rectify.corner_detection import Detection, detect_corners, marker_family, spec_hint
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
        warnings: what pairing and reading the views warned about (the
            calibration's own are in ``result``); both go to the report.
        time_offset_ns: how far cam1's clock was taken to run ahead of
            cam0's (``--time-offset``); view names keep the recorded stamps.
    """

    recording: Path
    result: CalibrationResult
    rig: StereoRig
    frames: dict[str, int]
    view_names: list[str]
    unreadable: list[str] = field(default_factory=list)
    listing: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    time_offset_ns: int = 0

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
        report["time_offset_ns"] = self.time_offset_ns
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


def _clock_hint(pairing: PairingResult) -> str:
    """For a failed calibration: the pairs' median gap, when the cameras' clocks may differ.

    Cameras whose clocks differ by over half a frame period pair each frame
    with the other camera's neighbour, and the views were refused as "poses
    disagree", with no word of the clocks nor of ``--time-offset``. The
    offset is the median gap, or the gap less or plus one period (timestamps
    tell it only modulo the period): both are named.
    """
    period = pairing.period_ns
    if clock_offset_warning(pairing.pairs, period) is None or not period:
        return ""
    gap = statistics.median(pair.dt_ns for pair in pairing.pairs)
    other = gap - period if gap > 0 else gap + period
    return (
        f"; cam1's frames pair {gap / 1e6:+.1f} ms from cam0's on median, "
        f"{abs(gap) / period:.0%} of the frame period: the cameras' clocks may differ, "
        "pairing each frame with the other camera's neighbour; give how far cam1's clock "
        f"runs ahead of cam0's (--time-offset {gap / 1e6:.1f} or {other / 1e6:.1f})"
    )


def _pair(
    recording_path: Path, stamps: tuple[list[int], list[int]], time_offset_ns: int
) -> tuple[PairingResult, str | None]:
    """Pair the frames on cam0's clock: the pairing and the clock-offset warning, if any.

    Raises:
        RectifyError: the offset leaves no pair where the stamps pair without it.
    """
    shifted1 = [t - time_offset_ns for t in stamps[1]]  # on cam0's clock
    pairing = pair_frames(stamps[0], shifted1)
    if not pairing.pairs and time_offset_ns and pair_frames(*stamps).pairs:
        # the offset moved every frame out of reach: the one cause worth naming
        raise RectifyError(
            f"{recording_path}: --time-offset {time_offset_ns / 1e6:g} ms leaves no cam0 frame "
            "within pairing tolerance of a cam1 frame (without it they pair): the offset is "
            "how far cam1's clock runs ahead of cam0's, in milliseconds"
        )
    warning = clock_offset_warning(pairing.pairs, pairing.period_ns)
    if warning is not None:
        warning = f"{recording_path}: {warning}"
        log.warning("%s", warning)
    return pairing, warning


_HINT_VIEWS = 5
"""Frames kept, spread in time, to say why a board found in no view was not found."""


def calibrate_recording(
    recording_path: Path,
    board: Board,
    model: CalibrationModel,
    topics: tuple[str, str] | None = None,
    max_views: int = 100,
    options: CalibrationOptions | None = None,
    time_offset_ns: int = 0,
) -> RecordingCalibration:
    """Calibrate a stereo rig from a recording of a board (see the module docstring).

    Args:
        recording_path: any layout :func:`lenspair.capture.recording.open_recording`
            reads (EuRoC/ASL folder, ROS bag, left/right folders).
        board: the board seen.
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        topics: bags only: ``(cam0_topic, cam1_topic)``; None picks them.
        max_views: at most this many frame pairs, evenly spread over them (0: all).
        options: outlier rejection and rectification settings.
        time_offset_ns: how far cam1's clock runs ahead of cam0's (ns): cam1's
            stamps less it are paired with cam0's (``--time-offset``).

    Returns:
        The calibration; nothing is written (see :func:`write_calibration`).

    Raises:
        RectifyError: ``max_views`` negative, no pairs (or none left by
            ``time_offset_ns``), a camera with no readable frame, or too few
            views with the board.
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
    pairing, offset_warning = _pair(recording_path, (stamps0, stamps1), time_offset_ns)
    pairs = [pairing.pairs[i] for i in spread_indices(len(pairing.pairs), max_views)]
    if not pairs:
        raise RectifyError(f"{recording_path}: no cam0/cam1 frames could be paired by timestamp")
    warnings: list[str] = [offset_warning] if offset_warning else []  # said, kept for the report
    detections: list[list[Detection | None]] = []
    unreadable: list[str] = []
    sizes: list[list[tuple[int, int] | None]] = []  # per pair, per camera (None: unread)
    where: list[list[str]] = []
    first_problem: list[str] = ["", ""]  # per camera: why its first unread frame was not read
    looked_for_markers = False
    samples: list[np.ndarray] = []  # a few frames read, for a hint when the board is not found
    sampled = set(spread_indices(len(pairs), _HINT_VIEWS))
    for row, pair in enumerate(progress(pairs, "detecting board", total=len(pairs), unit="pair")):
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
            if not samples or (index == 0 and row in sampled):  # the first read, then spread
                samples.append(image)
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
    names = [f"t0={p.t0_ns} t1={p.t1_ns + time_offset_ns}" for p in pairs]  # as recorded
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
        # a miscounted board is found in a few views or none; seen by both cameras, the
        # frames may also be paired out of step
        hint = spec_hint(samples, board)
        hint = hint or ("" if min(views) == 0 else _clock_hint(pairing))
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
        Path(recording_path),
        result,
        rig,
        frames,
        names,
        unreadable,
        listing,
        warnings,
        time_offset_ns,
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
