"""Turn a stereo recording into registered (obstructed, clean) pairs for training.

Reads an EuRoC/ASL folder, a ROS1/ROS2 bag or left/ + right/ folders, pairs
the two cameras by timestamp, rectifies both views, registers the clean view
onto the obstructed one (a homography from features pooled over the
recording, checked and refined per frame), crops both to --size and writes

  OUT/<recording>/input/<t_ns>.png    obstructed view (the model input)
  OUT/<recording>/target/<t_ns>.png   clean view, registered onto the input
  OUT/<recording>/mask/<t_ns>.png     255 where the pair is not trustworthy
  OUT/<recording>/pairs.jsonl         one line per obstructed frame, kept or rejected
  OUT/<recording>/report.json         counts, calibration, homography, crop, timings
  OUT/<recording>/registration.json   the homography and its inputs (a rerun reuses it)
  OUT/<recording>/qa.png              input | target | difference | mask, a few frames

Which camera is obstructed comes from rig.yaml beside the recording or
--obstructed; the calibration from --calib, else rig.yaml's 'calibration',
else camchain.yaml beside the recording, else a EuRoC recording's own
sensor.yaml files, else a bag's own camera_info topics. Where the calibration
names a bag's two topics (a camchain's rostopic keys) they take its cam0/cam1
order, and they choose the two cameras among topics whose names tell none;
--topics naming them the other way round is refused.
The declared side is checked
against the images: by default by comparing fine detail (a hint only: dust and
defocused drops remove detail, sharp drops add it, so dataset-build only warns on
its mismatches; undetermined on defocused rain), with
--detector MODEL (from train-detector, or detector.pt: the bundled one; on
--device, the GPU when there is one) by judging each camera's views; report.json's
side_check gives the inferred side and its confidence. Rerunning resumes an interrupted
run and leaves finished outputs untouched; a rerun with another calibration, side, --size,
--time-offset (or, from Python, other registration thresholds: ingest_recording's
estimation and verify settings) processes the frames again and says how many, naming the first
setting that differs (was X, now Y). One run at a time writes
OUT/<recording>: a second one is refused at once, and so is a run while dataset-build
reads the folder (and dataset-build while a run writes it).

Exit codes: 0 when at least one pair was kept; 2 on an error in the recording, the
calibration or the options (one line naming the file or option), when no usable pair
remains, or when another capture-ingest (or a dataset-build) holds OUT/<recording>; 1 when the file
system refuses a write (read-only folder, full disk: one line naming the path); 130
after Ctrl-C and 143 after SIGTERM (rerun to resume).
"""

import argparse
from pathlib import Path

from lenspair.capture.ingest import ingest_recording
from lenspair.commands.argtypes import (
    add_device_option,
    add_time_offset_option,
    add_topics_option,
    detector_file,
    input_path,
    out_folder,
    size,
    worker_count,
)
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import inside_refusal


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``lenspair capture-ingest``."""
    parser.add_argument("recording", type=input_path, help="recording folder or bag")
    parser.add_argument("--out", type=out_folder, required=True, help="output root folder")
    parser.add_argument(
        "--calib",
        type=input_path,
        action="append",
        default=[],
        metavar="FILE",
        help="calibration file: Kalibr camchain, OpenCV FileStorage, ROS camera_info or "
        "EuRoC sensor.yaml (repeat for several files; per-camera files in the order cam0, "
        "cam1); default: rig.yaml's, else "
        "camchain.yaml, else the EuRoC recording's sensor.yaml files, else a bag's first "
        "CameraInfo of each camera's camera_info topic",
    )
    parser.add_argument(
        "--obstructed", choices=("cam0", "cam1"), default=None, help="override rig.yaml"
    )
    parser.add_argument(
        "--workers", type=worker_count, default=1, help="worker processes (default 1)"
    )
    add_topics_option(parser)
    parser.add_argument(
        "--size", type=size(), default=(540, 360), metavar="WxH", help="crop size (540x360)"
    )
    parser.add_argument(
        "--detector",
        type=detector_file,
        metavar="MODEL",
        help="check the obstructed side with a detector (detector.pt: the bundled one)",
    )
    add_device_option(parser, "--detector")
    add_time_offset_option(parser, "ingest", "pairs")


def run(args: argparse.Namespace) -> int:
    """Ingest one recording; returns the exit code."""
    why = "restore and detect would read the ingested pairs back as frames of the recording"
    if (problem := inside_refusal(args.out, args.recording, "the recording", why)) is not None:
        raise ConfigError(problem)
    if args.detector is None and args.device != "auto":  # said, not ignored
        raise ConfigError(
            f"--device {args.device} places the side check's detector: give --detector MODEL "
            "(detector.pt: the bundled one), or leave --device out"
        )
    side_detector = None
    if args.detector is not None:
        # here, not at the top: only --detector needs torch, which ingest does not load otherwise
        from lenspair.core.device import resolve_device
        from lenspair.model.detection.judge import obstructed_probability
        from lenspair.model.detection.train import load_detector

        device = resolve_device(args.device)
        side_detector = obstructed_probability(load_detector(args.detector, device))
    report = ingest_recording(
        args.recording,
        args.out,
        calibration=tuple(args.calib),
        obstructed=args.obstructed,
        topics=args.topics,
        size=args.size,
        workers=args.workers,
        side_detector=side_detector,
        time_offset_ns=round(args.time_offset * 1e6),
    )
    counts = report.counts  # a side-check mismatch was already logged as a warning
    print(
        f"{report.recording_id}: kept {counts['kept']} of {counts['kept'] + counts['rejected']} "
        f"{report.obstructed} frames ({counts['masked']} with a mask); "
        f"crop {report.crop}; wrote {Path(args.out) / report.recording_id}"
    )
    for reason, count in report.rejection_reasons.items():
        print(f"  rejected {count}: {reason}")
    for problem in report.recording_problems:  # of the whole recording (a cut bag), no frame
        print(f"  recording: {problem}")
    if report.exposure is not None:  # its warnings, if any, were logged
        exposure = report.exposure
        print(
            f"  exposure: target/input grey ratio {exposure.median:.2f} "
            f"({exposure.low:.2f}-{exposure.high:.2f}, 10th-90th percentile)"
        )
    if args.detector is not None:
        print(f"  side check: {report.side_check.get('message', '')}")
    return 0
