r"""Calibrate a stereo rig from a recording of a calibration board.

Pairs the two cameras' frames by timestamp, finds the board's corners in each
(sub-pixel), calibrates each camera alone, then the pair with the intrinsics
fixed, using only frames where both cameras see the board, then refines both
cameras' intrinsics with the rig over those frames (kept only where each
camera's own frames still fit them; --fixed-intrinsics skips it: each camera's
focal error then goes into the baseline, many times over with a far board).
Views with a reprojection error far above the median are rejected, and named.
Prints the per-camera and stereo RMS reprojection errors, the intrinsics and
the baseline with their 1-sigma deviations, and the rectified row
disagreement (RMS of the row differences of matched corners after
rectification), writes Kalibr's camchain to --out and a JSON report beside it
(camchain.yaml -> camchain.report.json; its "warnings" keep what the run warned
about: a marker size off, too little tilt, poor coverage, a camera fitting far
worse). The workflow is the library function
lenspair.rectify.recording_calibration.calibrate_recording.

A rig that is not side by side (cam1 above or below cam0, or in front of or
behind it) is calibrated and written all the same, with a warning that names
its baseline: capture-ingest rectifies side-by-side rigs only. Frames of a
board held still count once: a calibration needs the board at five distinct
poses or more, seen by each camera and by both together. A camera fit with
fy/fx above 2.5 or below 1/2.5 is refused as diverged (anamorphic lenses,
binning and interlaced fields stay within it). A camera whose median view
error, as an angle (pixels over fx, so the two may differ in resolution), is
over five times the other's, and over 0.5 px, is warned about, not refused: a
thermal camera's blurred corners fit worse legitimately.

Boards (sizes in metres):
  chessboard:COLSxROWS:SQUARE_M               COLS x ROWS inner corners
  charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT][:legacy]
                                              COLS x ROWS squares, DICT default DICT_5X5_100
A ChArUco board printed by OpenCV < 4.6 (or by a tool that follows it) has the
legacy pattern, which differs for an even number of ROWS (its top-left square
is white): end the spec with :legacy. A board found in no view is checked
against the other pattern, and the error says which one the frames show.
ChArUco markers are also measured on the images: a MARKER_M more than 15 %
away from what they measure is reported (a wrong one biases the focal length).
SQUARE_M alone sets the metric scale: a square size 10 % off gives a baseline
10 % off, and no image can tell; measure the printed board. Also reported: a
chessboard spec for a board that carries ArUco markers, and a lens model the
other one fits far better (pinhole-radtan for a fisheye).

Models (Kalibr's names): pinhole-radtan (k1 k2 p1 p2), pinhole-equi (fisheye k1..k4).

Frames are paired by timestamp, each with the other camera's nearest within
half a frame period. Cameras without a common clock that disagree by more
than half a period pair every frame with its neighbour, and the views are
refused as the cameras' poses disagree: when the median gap reaches a quarter
of a period, calibrate warns (log and the report's "warnings"), as
capture-ingest does, and its error names the gap; --time-offset MS pairs on
cam0's clock.

Example:
  lenspair calibrate runs/board_01 --board chessboard:9x6:0.05 --model pinhole-equi \
      --out runs/board_01.camchain.yaml
"""

import argparse
from pathlib import Path

from lenspair.capture.folders import IMAGE_SUFFIXES
from lenspair.capture.rosbag import is_bag_name
from lenspair.commands.argtypes import (
    add_time_offset_option,
    add_topics_option,
    float_at_least,
    input_path,
    out_file,
)
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import check_writable, make_folder, remove_made
from lenspair.rectify.boards import parse_board_spec
from lenspair.rectify.calib_types import MODELS, CalibrationOptions, parse_model
from lenspair.rectify.recording_calibration import calibrate_recording, write_calibration


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``lenspair calibrate``."""
    parser.add_argument(
        "recording",
        type=input_path,
        metavar="BOARD_RECORDING",
        help="stereo recording of the board (EuRoC/ASL folder, ROS bag, left/right folders)",
    )
    parser.add_argument("--board", required=True, metavar="SPEC", help="board spec, see above")
    parser.add_argument("--model", required=True, choices=sorted(MODELS), help="camera model")
    parser.add_argument("--out", required=True, type=out_file, help="camchain YAML to write")
    parser.add_argument(
        "--max-views",
        type=int,
        default=100,
        metavar="N",
        help="use at most N frame pairs, evenly spread over the pairs (default 100; 0 = all)",
    )
    add_topics_option(parser)
    parser.add_argument(
        "--outlier-factor",
        type=float_at_least(1.0),
        default=3.0,
        metavar="X",
        help="reject views whose error exceeds X times the median view error and 0.5 px "
        "(a floor: views under it are never rejected), while at least 5 views remain "
        "(default 3)",
    )
    parser.add_argument(
        "--fixed-intrinsics",
        action="store_true",
        help="keep each camera's own intrinsics: no joint refinement with the rig (the "
        "baseline then carries both cameras' focal errors)",
    )
    add_time_offset_option(parser, "calibrate", "view names")


def _check_out(recording: Path, out: Path) -> list[Path]:
    """Refuse an ``--out`` that is the recording or one of the files it is read from.

    Also checks, before the calibration runs, that ``out``'s folder can be
    made and written to.

    Returns:
        The folders it made for ``out``, innermost first (a run that fails
        removes them).

    Raises:
        ConfigError: ``out`` is a file of the recording, or its folder cannot be made.
        OSError: the file system refuses to write there; it names ``out``.
    """
    target, source = out.resolve(), recording.resolve()
    inside = source.is_dir() and source in target.parents
    read = (
        target.name in _RECORDING_FILES
        or target.suffix.lower() in IMAGE_SUFFIXES
        or is_bag_name(target)  # a .bag.active too
    )
    beside = source.parent / f"{source.name}.camchain.yaml"  # resolved: "." has no parent
    if target == source or (inside and read):
        raise ConfigError(
            f"--out {out}: is a file of the recording {recording} (its frames, index or rig "
            f"file); write the calibration elsewhere, e.g. --out {beside}"
        )
    # any other file already there (its truth, its scene) is overwritten only when it is a
    # calibration an earlier run wrote, told by its report beside it
    if inside and target.exists() and not target.with_suffix(".report.json").is_file():
        raise ConfigError(
            f"--out {out}: a file of the recording {recording} that no calibrate wrote; "
            f"write the calibration elsewhere, e.g. --out {beside}"
        )
    # its folder is made now, not after the calibration: a place it cannot be made
    # (a typo, another user's folder) was a traceback once everything had run
    try:
        made = make_folder(out.parent)
    except OSError as exc:
        raise ConfigError(
            f"--out {out}: cannot make its folder {out.parent} ({exc.strerror or exc})"
        ) from None
    # and written to now: a read-only file system or another user's folder refused the
    # camchain (naming its temporary) only after the whole calibration had run
    check_writable(out)
    return made


_RECORDING_FILES = frozenset({"data.csv", "rig.yaml", "metadata.yaml", "sensor.yaml"})


def interrupt_hint(args: argparse.Namespace) -> str:
    """What to do after Ctrl-C: calibrate writes only at its end; nothing is resumed."""
    del args
    return "nothing was written; rerun to calibrate again"


def run(args: argparse.Namespace) -> int:
    """Run ``lenspair calibrate``; returns the exit code."""
    made = _check_out(args.recording, args.out)
    try:
        calibration = calibrate_recording(
            args.recording,
            parse_board_spec(args.board),
            parse_model(args.model),
            topics=args.topics,
            max_views=args.max_views,
            options=CalibrationOptions(
                outlier_factor=args.outlier_factor, refine_jointly=not args.fixed_intrinsics
            ),
            time_offset_ns=round(args.time_offset * 1e6),
        )
        report_path = write_calibration(calibration, args.out)
    except BaseException:  # a failed or interrupted run: "nothing was written", no folder either
        remove_made(made)
        raise
    for line in calibration.summary():
        print(line)
    print(f"wrote {args.out} and {report_path}")
    return 0
