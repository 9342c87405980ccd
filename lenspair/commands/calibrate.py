r"""Calibrate a stereo rig from a recording of a calibration board.

Pairs the two cameras' frames by timestamp, finds the board's corners in each
(sub-pixel), calibrates each camera alone, then the pair with the intrinsics
fixed, using only frames where both cameras see the board. Views with a
reprojection error far above the median are rejected, and named. Prints the
per-camera and stereo RMS reprojection errors and the rectified row
disagreement (RMS of the row differences of matched corners after
rectification), writes Kalibr's camchain to --out and a JSON report beside it
(camchain.yaml -> camchain.report.json).

Boards (sizes in metres):
  chessboard:COLSxROWS:SQUARE_M               COLS x ROWS inner corners
  charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]  COLS x ROWS squares, DICT default DICT_5X5_100

Models (Kalibr's names): pinhole-radtan (k1 k2 p1 p2), pinhole-equi (fisheye k1..k4).

Example:
  lenspair calibrate runs/board_01 --board chessboard:9x6:0.05 --model pinhole-equi \
      --out runs/board_01/camchain.yaml
"""

import argparse
from pathlib import Path

import numpy as np

from lenspair.capture.pairing import pair_frames
from lenspair.capture.recording import open_recording
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import atomic_write_json
from lenspair.core.progress import progress
from lenspair.rectify.boards import Detection, detect_corners, parse_board_spec
from lenspair.rectify.calibration import (
    MODELS,
    CalibrationOptions,
    calibrate_from_detections,
    parse_model,
)
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import StereoRig, write_kalibr


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``lenspair calibrate``."""
    parser.add_argument(
        "recording",
        type=Path,
        metavar="BOARD_RECORDING",
        help="stereo recording of the board (EuRoC/ASL folder, ROS bag, left/right folders)",
    )
    parser.add_argument("--board", required=True, metavar="SPEC", help="board spec, see above")
    parser.add_argument("--model", required=True, choices=sorted(MODELS), help="camera model")
    parser.add_argument("--out", required=True, type=Path, help="camchain YAML to write")
    parser.add_argument(
        "--max-views",
        type=int,
        default=100,
        metavar="N",
        help="use at most N frame pairs, evenly spread in time (default 100; 0 = all)",
    )
    parser.add_argument(
        "--topics", nargs=2, metavar=("CAM0", "CAM1"), help="bags only: the two image topics"
    )
    parser.add_argument(
        "--outlier-factor",
        type=float,
        default=3.0,
        metavar="X",
        help="reject views whose error exceeds X times the median view error (default 3)",
    )


def _spread(count: int, limit: int) -> list[int]:
    """``limit`` indices evenly spread over ``range(count)`` (all when limit is 0)."""
    if limit <= 0 or count <= limit:
        return list(range(count))
    return sorted({round(float(i)) for i in np.linspace(0, count - 1, limit)})


def run(args: argparse.Namespace) -> int:
    """Run ``lenspair calibrate``; returns the exit code."""
    board = parse_board_spec(args.board)
    model = parse_model(args.model)
    if args.max_views < 0:
        raise RectifyError(f"--max-views: expected >= 0, got {args.max_views}")
    recording = open_recording(args.recording, tuple(args.topics) if args.topics else None)
    pairing = pair_frames(recording.timestamps("cam0"), recording.timestamps("cam1"))
    pairs = [pairing.pairs[i] for i in _spread(len(pairing.pairs), args.max_views)]
    if not pairs:
        raise RectifyError(f"{args.recording}: no cam0/cam1 frames could be paired by timestamp")
    detections: list[tuple[Detection | None, Detection | None]] = []
    unreadable: list[str] = []
    resolutions: list[tuple[int, int] | None] = [None, None]
    for pair in progress(pairs, "detecting board", total=len(pairs), unit="pair"):
        found: list[Detection | None] = []
        for index, position in enumerate((pair.index0, pair.index1)):
            frame = recording.frames["cam0" if index == 0 else "cam1"][position]
            try:
                image = recording.load(frame)
            except LenspairError as exc:  # a bad frame is recorded, not fatal
                unreadable.append(str(exc))
                found.append(None)
                continue
            resolutions[index] = resolutions[index] or (image.shape[1], image.shape[0])
            found.append(detect_corners(image, board))
        detections.append((found[0], found[1]))
    if resolutions[0] is None or resolutions[1] is None:
        raise RectifyError(f"{args.recording}: no frame of one camera could be read")
    names = [f"t0={p.t0_ns} t1={p.t1_ns}" for p in pairs]
    options = CalibrationOptions(outlier_factor=args.outlier_factor)
    result = calibrate_from_detections(
        detections, board, model, (resolutions[0], resolutions[1]), names, options
    )
    rig = result.rig
    if recording.topics is not None:
        rig = StereoRig(rig.cam0, rig.cam1, rig.T_cam1_cam0, recording.topics)
    write_kalibr(args.out, rig)
    report_path = args.out.with_suffix(".report.json")
    report = result.report()
    report["recording"] = str(args.recording)
    report["frames"] = {
        "cam0": len(recording.frames["cam0"]),
        "cam1": len(recording.frames["cam1"]),
        "paired": len(pairing.pairs),
        "used": len(pairs),
        "unreadable": unreadable,
    }
    report["view_names"] = names
    atomic_write_json(report_path, report)
    for line in result.summary():
        print(line)
    for problem in unreadable:
        print(f"unreadable frame: {problem}")
    print(f"wrote {args.out} and {report_path}")
    return 0
