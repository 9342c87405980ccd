"""Measure PSNR/SSIM and latency of a checkpoint on paired images.

  lenspair eval CKPT --data DIR [--split test] [--device auto|cpu|cuda]
                [--convention skimage-gaussian|deraindrop-y] [--out EVAL_DIR]
  lenspair eval CKPT --describe

Example: lenspair eval runs/gea/checkpoints/best.pt --data DS --precision int8 --calibration DS

DIR is any paired layout lenspair reads (a dataset and its --split, a folder
with input/ + target/, or a Raindrop split such as test_a). Each whole image
is restored at batch 1 and scored against its target, after rounding the
output to the target's bit depth. Writes EVAL_DIR/per_image.csv, metrics.json,
metrics.md (means, and per difficulty when the dataset manifest has it) and
contact_sheet.png (input | output | target; easy/medium/hard rows). Every
table names its metric convention: skimage-gaussian (scikit-image, Gaussian
SSIM) or deraindrop-y (DeRaindrop's Y-channel, 7x7 window protocol). An
identical output gives PSNR = inf: kept per image, capped at 100 dB in means.
A pair that cannot be read (a truncated file, input and target of different
sizes) costs only itself: it is named in a one-line warning and listed in
metrics.md and metrics.json, and the others are scored.

Latency is measured as deployed: one image of the data's size, batch 1,
after warm-up, median and p90 of --latency-runs runs, thread count stated;
on the CPU, and on CUDA when the device is CUDA; a precision other than fp32
is timed beside fp32, what it saves beside what it costs. EVAL_DIR defaults to
RUN/eval_<checkpoint>_<data>[_<split>][_<precision>][_<convention>] for
RUN/checkpoints/<checkpoint>.pt, and to <checkpoint>_eval_<data>... beside any
other checkpoint file (the precision named unless fp32, the convention
unless skimage-gaussian; _2, _3, ... after it for a dataset of the same name
elsewhere).
--describe prints the parameter count and FLOPs at 540x360 and exits.

--precision fp32 (default: the reference numbers), auto (bf16 on a CPU with
avx512_bf16/AMX where a short timing finds it faster than fp32, else fp32;
fp32 on CUDA, where bf16/fp16 autocast measured slower for these networks;
never an emulated precision), bf16, fp16
(CUDA) or int8 (CPU only; ONNX Runtime static quantisation calibrated on 16
obstructed images of --calibration DS, its train split for a dataset;
default: another split of --data than the scored one when it is a dataset,
train first, then val, then the others, passing over a split that holds no
pairs; where there is none, a paired folder or no other split with pairs,
the evaluated images themselves, which flatters int8 and is said so). A
reduced precision is also scored against
the fp32 output ("agreement with the fp32 output"): what it costs in
accuracy, beside what it saves in time.
"""

import argparse
import itertools
from pathlib import Path
from typing import TYPE_CHECKING

from lenspair.commands.argtypes import (
    DEFAULT_SPLIT,
    add_convention_option,
    add_device_option,
    input_path,
    out_folder,
    split_name,
    timed_runs,
)
from lenspair.core.device import resolve_device
from lenspair.core.errors import ConfigError, first_line
from lenspair.core.fsutil import check_writable, inside_refusal, read_json_field
from lenspair.dataset.errors import DatasetError

if TYPE_CHECKING:  # torch-free at import, so that --help stays fast
    from lenspair.model.training.pairs import PairSource


DATASET_ARGUMENTS = ("data", "calibration")
"""Arguments naming datasets this command reads: ``lenspair.cli`` holds their locks meanwhile."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``eval``."""
    parser.add_argument("checkpoint", type=input_path, help="checkpoint (.pt) from lenspair train")
    parser.add_argument("--data", type=input_path, help="paired images to score")
    parser.add_argument(
        "--split",
        type=split_name,
        help=f"split of a dataset root ({DEFAULT_SPLIT}); a paired folder is scored whole",
    )
    add_device_option(parser)
    add_convention_option(parser)
    parser.add_argument(
        "--out",
        type=out_folder,
        metavar="EVAL_DIR",
        help="report folder (default: RUN/eval_<checkpoint>_<data>[_<split>][_<precision>]"
        "[_<convention>] for RUN/checkpoints/<checkpoint>.pt, <checkpoint>_eval_<data>... "
        "beside any other checkpoint; _2, _3, ... for a namesake dataset elsewhere)",
    )
    parser.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16", "fp16", "int8"),
        default="fp32",
        help="inference precision (fp32; auto: bf16 on a CPU with avx512_bf16/AMX where it "
        "measures faster than fp32, else fp32; fp32 on CUDA; int8: ONNX Runtime on the CPU)",
    )
    parser.add_argument(
        "--calibration",
        type=input_path,
        metavar="DS",
        help="int8: paired images to calibrate the quantisation on (not a camera calibration)",
    )
    parser.add_argument(
        "--latency-runs",
        type=timed_runs,
        default=30,
        help="timed runs per figure (30; 0: no timing)",
    )
    parser.add_argument("--describe", action="store_true", help="print params and FLOPs only")


def default_out(
    checkpoint: Path,
    data: Path,
    split: str | None,
    precision: str = "fp32",
    convention: str = "skimage-gaussian",
) -> Path:
    """Where an evaluation goes without ``--out``: a folder per checkpoint, data, precision, metric.

    ``RUN/eval_<stem>_<data>[_<split>][_<precision>][_<convention>]`` for
    ``RUN/checkpoints/<stem>.pt``, else ``<stem>_eval_<data>...`` beside the
    checkpoint; ``split`` is None for a paired folder, which has none, the
    precision is named unless it is fp32 (the reference) and the convention
    unless it is the default (``deraindrop-y`` beside the default no longer
    replaces it). Evaluating
    ``last.pt``, other data, or at int8 no longer replaces the evaluation of
    ``best.pt``; nor does a dataset of the same name elsewhere, whose
    evaluation (told by ``metrics.json``'s ``data_path``) takes the first
    free ``_2``, ``_3``, ... after the name.
    """
    checkpoint = Path(checkpoint)
    what = Path(data).resolve().name + (f"_{split}" if split else "")
    what += f"_{precision}" if precision != "fp32" else ""
    what += f"_{convention}" if convention != "skimage-gaussian" else ""
    if checkpoint.parent.name == "checkpoints":
        base = checkpoint.parent.parent / f"eval_{checkpoint.stem}_{what}"
    else:
        base = checkpoint.with_name(f"{checkpoint.stem}_eval_{what}")
    # A namesake dataset elsewhere (other/DS) gets its own folder: _2, _3, ...
    scored = str((Path(data) if split is None else Path(data) / split).resolve())
    for number in itertools.count(1):
        out = base if number == 1 else base.with_name(f"{base.name}_{number}")
        earlier = read_json_field(out / "metrics.json", "data_path")
        if not out.exists() or earlier in (None, "", scored):
            return out
    raise AssertionError("unreachable")  # itertools.count never ends


def run(args: argparse.Namespace) -> int:
    """Evaluate (or describe) a checkpoint; returns the exit code."""
    # Imported here, not at the top: keeps torch out of `lenspair eval --help`.
    from lenspair.model.checkpoint import load_model
    from lenspair.model.evaluation.evaluate import evaluate_checkpoint
    from lenspair.model.evaluation.report import markdown_report, write_report
    from lenspair.model.networks.complexity import describe

    if args.describe:
        loaded = load_model(args.checkpoint, "cpu")
        channels = loaded.config.model.channels or 1
        summary = describe(loaded.network, (channels, 360, 540))
        model = loaded.config.model
        print(
            f"{args.checkpoint}: {model.variant}, width {model.width:g}, "
            f"{model.num_blocks} residual blocks, {channels} channel(s)"
        )
        print(f"parameters: {summary.parameters:,}")
        print(f"FLOPs: {summary.gflops:.3f} GFLOPs at 540x360 (2 FLOPs per multiply-add)")
        if args.data is None:
            return 0
    if args.data is None:
        raise ConfigError("give --data DIR (paired images), or --describe")
    if not Path(args.data).exists():  # before the precision line: the error alone
        raise ConfigError(f"--data {args.data}: no such folder")
    device = resolve_device(args.device)
    # here, not at the top: keeps `lenspair eval --help` from importing torch
    from lenspair.dataset.layouts import IMAGE_FOLDERS, detect_layout, split_folders
    from lenspair.model.precision import choose_precision
    from lenspair.model.training.pairs import open_eval_pairs

    # the pairs scored: a paired folder itself, or a dataset's split (DS/eval_* is fine)
    plain = detect_layout(args.data) is not None  # a paired folder: no split in its name
    if plain and args.split not in (None, Path(args.data).name):  # DS/test --split test: fine
        raise ConfigError(
            f"--split {args.split}: {args.data} is a paired folder, scored whole; leave "
            "--split out, or give the dataset root whose split it is"
        )
    args.split = args.split or DEFAULT_SPLIT
    scored = Path(args.data) if plain else args.data / args.split
    why = "its contact sheet would be read as an unpaired image next time"
    # the other splits' image folders too: DS/train/input took the report, and the
    # next train or int8 calibration refused the dataset over an unpaired file
    others = [] if plain else [
        (args.data / name / kind, "the image folder")
        for name in split_folders(args.data) if args.data / name != scored
        for kind in IMAGE_FOLDERS
    ]  # fmt: skip
    for folder, what in [(scored, "the pairs scored"), *others]:
        if args.out is not None and (problem := inside_refusal(args.out, folder, what, why)):
            raise ConfigError(problem)

    # loaded once, here: a wrong file (the arguments swapped) gets its error alone
    loaded = load_model(args.checkpoint, device)
    decision = choose_precision(args.precision, device, "infer")
    if args.calibration is not None and decision.precision != "int8":
        raise ConfigError(
            f"--calibration DS is for --precision int8; this evaluation runs at "
            f"{decision.precision}, so add --precision int8 or leave it out"
        )
    print(decision.summary())
    calibration = None
    if args.calibration is not None:
        calibration = open_eval_pairs(args.calibration, "train")
        if len(calibration) == 0:  # a split that dataset-build left empty
            folder = getattr(calibration, "root", args.calibration)
            raise ConfigError(
                f"--calibration {args.calibration}: {folder} holds no pairs to calibrate on; "
                "give a paired folder that does (another split's folder)"
            )
    elif decision.precision == "int8":
        calibration = _default_calibration(args.data, args.split)
    if args.out is not None:
        out = args.out
    else:
        split = None if plain else args.split
        out = default_out(args.checkpoint, args.data, split, decision.precision, args.convention)
    check_writable(out / "eval.json")  # a read-only --out is said before the scoring, not after
    result = evaluate_checkpoint(
        loaded,
        args.data,
        args.split,
        device,
        convention=args.convention,
        precision=decision.precision,
        latency_runs=args.latency_runs,
        calibration=calibration,
        precision_reason=decision.reason,
    )
    result.data_path = str(scored.resolve())
    files = write_report(result, out)
    print(markdown_report(result))
    print("wrote " + ", ".join(str(path) for path in files.values()))
    return 0


def _default_calibration(data: Path, split: str) -> "PairSource | None":
    """int8 without --calibration: another split of ``data`` than the scored one, with pairs.

    Calibrating on the scored images would flatter int8, so another split is
    taken: train first, then val, then the others by name. A split that holds
    no pairs (dataset-build leaves one of a small dataset empty) or cannot be
    read is passed over, and a line names it and why. Where there is none (a
    plain paired folder, or no other split with pairs) the evaluated images
    are used and a line says so.
    """
    # here, not at the top: these import torch, and `lenspair eval --help` should not
    from lenspair.dataset.layouts import detect_layout, split_folders
    from lenspair.model.training.pairs import open_eval_pairs

    other = "no other split"
    if detect_layout(Path(data)) is None:
        others = sorted(
            (name for name in split_folders(data) if name != split),
            key=lambda name: (name != "train", name != "val", name),  # train, val, others
        )
        for name in others:
            try:
                pairs = open_eval_pairs(data, name)
            except DatasetError as exc:
                print(f"int8: not calibrated on {data} split {name}: {first_line(exc)}")
                continue
            if len(pairs) == 0:
                print(f"int8: not calibrated on {data} split {name}: it holds no pairs")
                continue
            print(f"int8: calibrated on {data} split {name} (--calibration to choose)")
            return pairs
        other = "no other split with pairs" if others else other
    print(
        f"int8: calibrated on the evaluated images themselves ({other}): its accuracy "
        "is optimistic; pass --calibration DS to calibrate on other images"
    )
    return None


def interrupt_hint(args: argparse.Namespace) -> str:
    """After Ctrl-C: eval writes its files at its end; nothing is resumed."""
    del args
    return "nothing was written; rerun to evaluate again"
