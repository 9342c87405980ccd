"""Judge frames with a trained detector: obstructed or clean, by what, and where.

  lenspair detect MODEL INPUT [--out DIR] [--device auto|cpu|cuda] [--threshold 0.5]

INPUT is what restore reads: one image, a
folder of images (recursive; left/ + right/ folders included), an EuRoC/ASL
recording or a ROS 1/ROS 2 bag (both cameras are judged; --topics names the
bag's two image topics when they cannot be told apart). Writes
DIR/detections.csv and detections.json (one row per frame: probability that
the glass is obstructed, kind among clean/rain/dust/dirt, share of tiles
covered, the probability of each kind; unreadable frames are listed with
their error) and DIR/contact_sheet.png (frames spread over the input, covered
tiles in red). Frames are decoded one batch at a time, so a long recording
needs no more memory than a short one. Prints how many frames were called
obstructed, per kind, and a warning when a bag stops part-way, and one for
each file of a folder INPUT that may hold frames but is not judged (a bag, a
killed recorder's .bag.active too, a video, a camera raw file, an image format
that is not read), as restore names them, and one for each folder of a
recording's images that none of its cameras holds (mav0/cam2). When no frame
at all could be judged, the two tables are written (no contact sheet: it has
no frame to show) and the command ends with exit code 2 and the first reason.

Example:
  lenspair detect runs/detector/detector.pt rec/rain --out detect_rain
"""

import argparse
import logging
import sys
from collections import Counter
from pathlib import Path

from lenspair.commands.argtypes import (
    add_device_option,
    add_topics_option,
    detector_file,
    input_path,
    open_fraction,
    out_folder,
)
from lenspair.core.device import resolve_device
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import check_writable, inside_refusal
from lenspair.core.wording import counted

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``detect``."""
    parser.add_argument(
        "model",
        type=detector_file,
        help="detector checkpoint from train-detector (detector.pt: the bundled one)",
    )
    parser.add_argument("input", type=input_path, help="image, folder of images, recording or bag")
    parser.add_argument(
        "--out",
        type=out_folder,
        help="output folder, outside the input and, for one image, not the image's own "
        "folder (default: detect_<input name>, without a file's suffix, beside the input "
        "when the current folder is inside it)",
    )
    add_device_option(parser)
    parser.add_argument(
        "--threshold",
        type=open_fraction,
        default=0.5,
        help="a frame is called obstructed above this probability (0.5)",
    )
    parser.add_argument("--batch-size", type=int, default=8, help="frames per network call (8)")
    parser.add_argument(
        "--sheet-frames", type=int, default=12, help="frames on the contact sheet (12)"
    )
    add_topics_option(parser)


def _default_out(source: Path) -> Path:
    """``detect_<input name>`` here, or beside the input when here is inside it.

    A file's name without its suffix (``frame.png`` -> ``detect_frame``): a folder
    named like an image or a bag is taken for one.
    """
    resolved = source.resolve()
    name = f"detect_{resolved.stem if resolved.is_file() else resolved.name}"
    here = Path.cwd().resolve()
    inside = source.is_dir() and here.is_relative_to(source.resolve())
    return source.resolve().parent / name if inside else Path(name)


def run(args: argparse.Namespace) -> int:
    """Judge the frames of INPUT; returns the exit code."""
    # torch and the bag readers load when the command runs, so --help stays fast
    from lenspair.capture.bag_frames import bag_overview
    from lenspair.capture.frames import DETECT_OUTPUT, detect_input, frame_files, iter_frames
    from lenspair.capture.recording import present_cameras
    from lenspair.capture.recording_types import FrameProblem
    from lenspair.model.detection.report import detect_frames
    from lenspair.model.detection.train import load_detector
    from lenspair.model.detection.unjudged import unjudged_files, unjudged_images

    if args.batch_size < 1 or args.sheet_frames < 0:
        raise ConfigError("--batch-size must be >= 1 and --sheet-frames >= 0")
    kind = detect_input(args.input)  # a bad INPUT fails before anything is written
    network = load_detector(args.model, resolve_device(args.device))
    if args.out is None:  # the default passes --out's checks too: a file by its name
        try:
            out = out_folder(str(_default_out(args.input)))
        except argparse.ArgumentTypeError as exc:
            raise ConfigError(f"the default --out {exc}") from None
    else:
        out = args.out
    why = "a later run would judge the contact sheet as a frame"
    if (problem := inside_refusal(out, args.input, "the input", why)) is not None:
        raise ConfigError(problem)
    # One image: its own folder would mix the sheet with the frames. A folder below it stays
    # allowed: the default (detect_<name> here) is one whenever the image is here.
    if kind == "image" and out.resolve() == args.input.resolve().parent:
        raise ConfigError(
            f"--out {out}: the folder that holds {args.input}; {why} there, so choose "
            "another folder"
        )
    table = out / DETECT_OUTPUT
    check_writable(table)  # a read-only --out is said before judging, not after
    if table.is_file():  # cheap to make again, but maybe another model's
        log.warning("%s: replacing the detections of an earlier run there", out)
    # Files are counted from their listing (cheap); a bag's count is only known once read.
    bag = kind in ("rosbag1", "rosbag2")
    cameras = present_cameras(args.input)  # both, or the one a mono recording holds
    files = [] if bag else frame_files(args.input, kind, cameras)
    total = None if bag else len(files)
    problems: list[str] = []
    if bag:
        overview = bag_overview(args.input, cameras, args.topics)
        if empty := overview.nothing_to_read(args.input):
            raise ConfigError(f"{empty}: nothing to judge")
        problems += overview.others
    dropped: list[FrameProblem] = []  # images the listing left out or could not find: rows too
    frames = iter_frames(args.input, cameras, problems, args.topics, dropped)
    verdicts = detect_frames(
        network, frames, out, args.batch_size, args.sheet_frames, args.threshold, total, dropped,
        args.input,
    )  # fmt: skip
    unjudged = unjudged_files(args.input, kind, files)  # a bag or a video among the images
    outside = unjudged_images(args.input, kind, cameras, files)  # mav0/cam2: a folder a line
    problems += unjudged + [group.note("detect", "not judged") for group in outside]
    for problem in problems:
        print(f"lenspair detect: warning: {problem}", file=sys.stderr)
    judged = [v for v in verdicts if v.error is None]
    counts = Counter(v.kind for v in judged)
    obstructed = sum(1 for v in judged if v.obstructed)
    listed_kinds = ", ".join(f"{kind} {count}" for kind, count in sorted(counts.items()))
    kinds = f"; {listed_kinds}" if listed_kinds else ""  # none judged: no empty "; ;"
    others = (
        f"; {counted(len(unjudged), 'file')} that may hold frames not judged (warnings above)"
        if unjudged
        else ""
    )
    if outside:
        images = counted(sum(group.images for group in outside), "image")
        others += f"; {images} outside the recording's cameras not judged (warnings above)"
    print(
        f"{counted(len(judged), 'frame')} judged ({len(verdicts) - len(judged)} not: unreadable "
        "or left out by the listing): "
        f"{obstructed} obstructed{kinds}{others}; see {table}"
    )
    if verdicts and not judged:
        # no frame judged: a script must not read this run as done (exit 0), as restore's
        first = next(v for v in verdicts if v.error is not None)
        reason = first.error if first.name in str(first.error) else f"{first.name}: {first.error}"
        raise ConfigError(
            f"none of the {counted(len(verdicts), 'frame')} could be judged (the first: "
            f"{reason}); each is listed in {table}"
        )
    return 0


def interrupt_hint(args: argparse.Namespace) -> str:
    """After Ctrl-C: detect writes its files at its end; nothing is resumed."""
    del args
    return "nothing was written; rerun to judge the frames again"
