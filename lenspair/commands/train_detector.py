"""Train the small anomaly detector (obstructed?, which kind, where) from paired data.

  lenspair train-detector [DS ...] --out RUN [--recordings REC ...] [--synthetic N]
                          [--simulated-set DIR] [--hard N] [--steps N] [--minutes M]
                          [--device auto|cpu|cuda] [--workers N]

Sources (any mix): lenspair datasets DS (their train split: obstructed views
are positives, with a map from the registered pair; clean views negatives;
their val and test splits are scored), simulated recordings (--recordings, exact
truth/mask), synthetic rain/dust/dirt over clean images (--synthetic N
frames, over --clean-images DIR or the simulator's textures), and
--simulated-set DIR, a small multi-kind set of simulated recordings rendered
there (clean, rain, dust, dirt; its last recording of each kind is held out
and scored; a rerun keeps recordings rendered with the same --set-per-kind,
--set-frames and --seed and renders the others again: the textures of each
recording follow from the number per kind). --hard N adds N hard cases made from the clean
views of the training recordings, so it needs --recordings or --simulated-set
(defocused, dark or bright, low-texture clean frames; dust darkening the whole
frame, light rain: see lenspair.model.detection.hard_cases). --workers N renders and reads samples
in N processes (the samples do not depend on it); --device picks where to
train and score. Training stops after --steps steps or --minutes minutes,
whichever comes first; --minutes alone sets no step limit, and neither
gives 600 steps. Writes RUN/detector.pt, RUN/scores.md and scores.json
(accuracy, F1, per-kind confusion, tile IoU), RUN/run.json.

Example (a few CPU minutes):
  lenspair train-detector --simulated-set sims --synthetic 400 --out runs/detector --minutes 4
"""

import argparse
import sys

from lenspair.commands.argtypes import (
    add_device_option,
    input_path,
    non_negative_int,
    out_folder,
    positive_int,
    random_seed,
    size,
    worker_count,
)
from lenspair.core.device import resolve_device
from lenspair.core.durations import minutes
from lenspair.core.errors import ConfigError

MIN_INPUT_SIDE = 8
"""The detector's tile stride (``lenspair.model.networks.detector.TILE_STRIDE``; not
imported: ``--help`` would load torch)."""


MAX_INPUT_SIDE = 1920
"""The largest side frames are judged at (a full-HD frame's width: the detector scales
every frame down to its input size, so a larger one adds memory, not sight); the
detector's own ``MAX_INPUT_SIDE``, not imported: ``--help`` would load torch."""

MAX_STEP_PIXELS = 256 * 270 * 180
"""The most pixels one training step may hold (``--batch-size`` x ``--input-size``):
256 frames of the default size, a few GB of activations. A batch of 100000 or an
input of 100000x100000 ended in an allocator's traceback after the data was gathered."""

SET_PER_KIND = 3
"""Recordings per kind of ``--simulated-set`` when ``--set-per-kind`` is not given."""

SET_FRAMES = 6
"""Frames per recording of ``--simulated-set`` when ``--set-frames`` is not given."""

MAX_SET_PER_KIND = 100
"""The most recordings per kind: recording ``k`` of kind ``i`` is seeded ``seed + 100 i + k``
(:func:`lenspair.model.detection.simset.kind_set_specs`), so 100 keeps every seed distinct."""

STEPS = 600
"""Optimiser steps when neither ``--steps`` nor ``--minutes`` is given."""


MAX_SYNTHETIC = 1_000_000
"""The most synthetic frames ``--synthetic`` makes (they are held in memory while training)."""


def set_per_kind(text: str) -> int:
    """Argparse type of ``--set-per-kind``: 2 to :data:`MAX_SET_PER_KIND` (2**31-1 ran forever).

    Two at least: the last recording of each kind is held out, the others trained on.
    """
    value = positive_int(text, MAX_SET_PER_KIND)
    if value < 2:
        raise argparse.ArgumentTypeError(
            f"expected 2 or more (one recording of each kind is held out), got {text!r}"
        )
    return value


def frame_count(text: str) -> int:
    """Argparse type of ``--synthetic``: a number of frames (>= 0), not a folder.

    ``train --synthetic DIR`` takes a folder; here the folder goes in ``--clean-images``.
    """
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(
            f"expected a number of frames (0 or more), got {text!r}; the folder of clean "
            "images they are made from goes in --clean-images DIR"
        )
    if value > MAX_SYNTHETIC:  # held in memory: 1e19 ended in a MemoryError traceback
        raise argparse.ArgumentTypeError(f"expected at most {MAX_SYNTHETIC} frames, got {text!r}")
    return value


def _minutes(text: str) -> float:
    """Argparse type of --minutes: ``"4"``, ``"4m"``, ``"90s"`` or ``"1h"``, in minutes."""
    try:
        return minutes(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


DATASET_ARGUMENTS = ("datasets",)
"""Arguments naming datasets this command reads: ``lenspair.cli`` holds their locks meanwhile."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``train-detector``."""
    parser.add_argument(
        "datasets", type=input_path, nargs="*", metavar="DS", help="lenspair datasets"
    )
    parser.add_argument(
        "--out", type=out_folder, required=True, metavar="RUN", help="output folder"
    )
    parser.add_argument(
        "--recordings",
        type=input_path,
        nargs="+",
        default=[],
        metavar="REC",
        help="simulated recordings (lenspair simulate) to train on, with their exact masks",
    )
    parser.add_argument(
        "--test-recordings",
        type=input_path,
        nargs="+",
        default=[],
        metavar="REC",
        help="simulated recordings to score the detector on, never trained on",
    )
    parser.add_argument(
        "--synthetic",
        type=frame_count,
        default=0,
        metavar="N",
        help="synthetic frames to train on, made from clean images (--clean-images): a "
        "quarter each clean, rain, dust and dirt (the simulator's effects, drawn at random), "
        "every one's exposure varied and a third blurred (default 0: none)",
    )
    parser.add_argument(
        "--clean-images",
        type=input_path,
        metavar="DIR",
        help="folder of clean images the --synthetic frames are made from: its first 200 "
        "images, a dataset's train targets only (default: the simulator's textures)",
    )
    parser.add_argument(
        "--simulated-set",
        type=out_folder,
        metavar="DIR",
        help="render or reuse a simulated set in this folder",
    )
    parser.add_argument(
        "--set-per-kind",
        type=set_per_kind,
        help=f"recordings per kind, 2 to {MAX_SET_PER_KIND} ({SET_PER_KIND})",
    )
    parser.add_argument(
        "--set-frames",
        type=positive_int,
        help=f"frames per recording ({SET_FRAMES}; the set holds at most {MAX_SYNTHETIC} frames)",
    )
    parser.add_argument(
        "--steps",
        type=positive_int,
        metavar="N",
        help=f"stop training after N optimiser steps (default: {STEPS}, or no step limit "
        "with --minutes; with both, whichever comes first)",
    )
    parser.add_argument("--batch-size", type=positive_int, default=8, help="frames per step (8)")
    parser.add_argument(
        "--minutes",
        type=_minutes,
        metavar="TIME",
        help="stop training after this much time: minutes, or 90s, 5m, 1h as train's "
        "--max-seconds takes (default: no time limit; with --steps, whichever comes first)",
    )
    parser.add_argument("--seed", type=random_seed, default=0, help="random seed (0)")
    parser.add_argument("--threads", type=worker_count, default=1, help="CPU threads (1)")
    parser.add_argument(
        "--hard", type=non_negative_int, default=0, metavar="N", help="hard cases (0)"
    )
    add_device_option(parser)
    parser.add_argument(
        "--workers", type=worker_count, default=1, help="processes making samples (1)"
    )
    parser.add_argument(
        "--input-size",
        type=size(MIN_INPUT_SIDE, MAX_INPUT_SIDE),
        default=(270, 180),
        metavar="WxH",
        help="size frames are judged at (270x180; width first, as every lenspair size; "
        f"sides {MIN_INPUT_SIDE} to {MAX_INPUT_SIDE})",
    )


def interrupt_hint(args: argparse.Namespace) -> str:
    """What to do after Ctrl-C: training keeps no checkpoint; a rendered set is kept.

    Nothing is written to RUN before the training ends, so the same command
    again trains from step 0; only ``--simulated-set`` resumes, keeping the
    recordings it finished (:func:`lenspair.model.detection.simset.simulate_kind_set`).
    """
    again = "training keeps no checkpoint: the same command again trains from the start"
    if args.simulated_set is None:
        return again
    return f"{again}, reusing the recordings already rendered in {args.simulated_set}"


def run(args: argparse.Namespace) -> int:
    """Train a detector; returns the exit code."""
    # here, not at the top: keeps `--help` from importing torch
    from lenspair.model.detection.run import DetectorSources, run_training
    from lenspair.model.detection.score import scores_markdown
    from lenspair.model.detection.simset import SCENE_KINDS
    from lenspair.model.detection.train import DetectorTraining
    from lenspair.model.networks.detector import DetectorSpec

    if args.minutes is not None and args.minutes <= 0:
        raise ConfigError("--minutes must be > 0")
    unused = [
        f"{option} is used only with {needs}"
        for option, given, needs, present in (
            ("--clean-images", args.clean_images, "--synthetic N", args.synthetic > 0),
            ("--set-per-kind", args.set_per_kind, "--simulated-set", args.simulated_set),
            ("--set-frames", args.set_frames, "--simulated-set", args.simulated_set),
        )
        if given is not None and not present
    ]
    if unused:  # said, not ignored
        raise ConfigError("; ".join(unused))
    per_kind = SET_PER_KIND if args.set_per_kind is None else args.set_per_kind
    set_frames = SET_FRAMES if args.set_frames is None else args.set_frames
    kinds = len(SCENE_KINDS)
    if args.simulated_set is not None and kinds * per_kind * set_frames > MAX_SYNTHETIC:
        raise ConfigError(
            f"--simulated-set of {kinds} kinds x {per_kind} recordings x {set_frames} frames "
            f"is over {MAX_SYNTHETIC} frames; lower --set-per-kind or --set-frames"
        )
    width, height = args.input_size
    if args.batch_size * width * height > MAX_STEP_PIXELS:
        raise ConfigError(
            f"--batch-size {args.batch_size} of --input-size {width}x{height} is "
            f"{args.batch_size * width * height:.3g} pixels a step, over {MAX_STEP_PIXELS:.3g} "
            "(256 frames of 270x180); lower either"
        )
    steps = args.steps
    if steps is None and args.minutes is None:
        steps = STEPS
    # --minutes alone: the time budget decides (the default steps ended a 5-minute run in 15 s)
    sources = DetectorSources(
        datasets=tuple(args.datasets),
        recordings=tuple(args.recordings),
        test_recordings=tuple(args.test_recordings),
        synthetic=args.synthetic,
        clean_folder=args.clean_images,
        simulated_set=args.simulated_set,
        set_per_kind=per_kind,
        set_frames=set_frames,
        hard=args.hard,
    )
    try:
        settings = DetectorTraining(
            steps=steps,
            batch_size=args.batch_size,
            seed=args.seed,
            max_seconds=None if args.minutes is None else 60.0 * args.minutes,
            threads=args.threads,
        )
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    spec = DetectorSpec(input_size=(height, width))
    device = resolve_device(args.device)
    scores = run_training(args.out, sources, spec, settings, device=device, workers=args.workers)
    for name, result in scores.items():
        sys.stdout.write(scores_markdown(name, result) + "\n")
    print(f"wrote {args.out / 'detector.pt'}")
    return 0
