"""Export a checkpoint to ONNX and/or TorchScript, checked against torch.

  lenspair export CKPT --onnx model.onnx [--torchscript model.pt] [--size 540x360]
  lenspair export CKPT --onnx model.onnx --int8 --calibration DS [--split train]

Example: lenspair export runs/gea/checkpoints/best.pt --onnx gea.onnx --int8 --calibration DS

The exported network takes one image (N, C, H, W) float32 in [0, 1] of any
size (H, W >= 8; batch, height and width dynamic in ONNX) and returns the
restored image, whole, as the checkpoint does. --size is where each file is
checked and timed: it is run on a seeded random image and a flat one at that
size and at a second size with odd sides (about half; a size too small to
halve, 3 pixels larger) and compared with torch (the largest absolute
difference is printed), and timed at batch 1 at that size. Checking and
timing ONNX needs onnxruntime (a dependency of lenspair; reinstall it);
without it the file is written and the output says it was not checked. A
JSON report goes next to the first file, its whole name and .export.json
(model.onnx.export.json).

--int8 also writes <name>.int8.onnx: ONNX Runtime static quantisation (QDQ,
int8 weights per channel, uint8 activations) calibrated on 16 obstructed
images of DS (any paired layout; --split picks a dataset's split), checked
against the fp32 network on the one with the most contrast, through a probe
model calibrated on the other 15 (PSNR of its output against the fp32
output), and timed against it, at --size. Like the fp32 file it takes any
size; its ranges are calibrated on the images resized to --size. int8 runs
natively on CPUs with VNNI (avx512_vnni, avx_vnni, AMX); the precision
decision is printed (lenspair.model.precision).
"""

import argparse
import json
import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING

from lenspair.commands.argtypes import input_path, out_file, size, split_name
from lenspair.core.errors import ConfigError
from lenspair.core.folderlock import lock_file
from lenspair.core.fsutil import atomic_write_text
from lenspair.core.leftovers import remove_leftovers
from lenspair.model.errors import ModelError

log = logging.getLogger(__name__)

MIN_INPUT_SIDE = 8
"""The network's smallest input side (``lenspair.model.networks.padding.MIN_SIDE``; not
imported: ``--help`` would load torch)."""

if TYPE_CHECKING:  # torch-free at import, so that --help stays fast
    import numpy as np

    from lenspair.model.checkpoint import LoadedModel


DATASET_ARGUMENTS = ("calibration",)
"""Arguments naming datasets this command reads: ``lenspair.cli`` holds their locks meanwhile."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``export``."""
    parser.add_argument("checkpoint", type=input_path, help="checkpoint (.pt) from lenspair train")
    parser.add_argument("--onnx", type=out_file, help="ONNX file to write")
    parser.add_argument("--torchscript", type=out_file, help="TorchScript file to write")
    parser.add_argument(
        "--size",
        type=size(MIN_INPUT_SIDE),
        default=(540, 360),
        metavar="WxH",
        help="size the export is checked against torch and timed at (and traced at, ONNX "
        "rounded up to a multiple of 4); the model takes any size (540x360)",
    )
    parser.add_argument(
        "--int8", action="store_true", help="also write NAME.int8.onnx (needs --calibration)"
    )
    parser.add_argument(
        "--calibration",
        type=input_path,
        metavar="DS",
        help="paired images to calibrate --int8's quantisation on (not a camera calibration)",
    )
    parser.add_argument(
        "--split",
        type=split_name,
        help="split of DS to calibrate on (train; DS a paired folder: all of it)",
    )


def run(args: argparse.Namespace) -> int:
    """Export and check; returns the exit code."""
    # Imported here, not at the top: keeps torch out of `lenspair export --help`.
    from lenspair.model.checkpoint import load_model

    if args.onnx is None and args.torchscript is None:
        raise ConfigError("give --onnx FILE and/or --torchscript FILE")
    if args.int8 and (args.onnx is None or args.calibration is None):
        raise ConfigError("--int8 needs --onnx FILE and --calibration DS (paired images)")
    if args.calibration is not None and not args.int8:
        raise ConfigError("--calibration DS is for --int8 only; add --int8 or leave it out")
    if args.split is not None and args.calibration is None:
        raise ConfigError("--split is the split of --calibration DS; give both, or neither")
    check_outputs(args)
    for path in _outputs(args).values():  # what a killed export left beside its files
        remove_leftovers(path.parent, path.name)
    size = (args.size[1], args.size[0])  # (height, width)
    calibration = None
    if args.int8:  # a bad DS or split fails here, before any file is written
        # likewise: loads torch
        from lenspair.dataset.layouts import detect_layout
        from lenspair.model.training.pairs import open_eval_pairs

        if args.split is not None and detect_layout(args.calibration) is not None:
            raise ConfigError(
                f"--split {args.split}: {args.calibration} is a paired folder, not a dataset "
                "with splits; all its pairs calibrate: leave --split out"
            )
        calibration = open_eval_pairs(args.calibration, args.split or "train")
        if len(calibration) == 0:  # a split that dataset-build left empty
            option = f"--calibration {args.calibration}"
            option += f" --split {args.split}" if args.split is not None else ""
            folder = getattr(calibration, "root", args.calibration)
            raise ConfigError(
                f"{option}: {folder} holds no pairs to calibrate on; choose another split"
            )
    # loaded before anything is removed: a checkpoint that cannot be read changes nothing
    loaded = load_model(args.checkpoint, "cpu")
    images, calibrated_on = None, None
    if calibration is not None:  # decoded before too: unreadable images change nothing
        from lenspair.model.evaluation.quantize import calibration_images  # torch, as above

        images = calibration_images(calibration, loaded.config.model.channels or 1, size)
        calibrated_on = {  # in the report: what the int8 ranges were fitted to
            "data": str(getattr(calibration, "root", args.calibration)),  # the split's folder
            "images": len(images),
            "size": [size[1], size[0]],  # WxH, as --size: the ranges fit frames of this size
        }
    report = report_path(args)
    lock = report.with_name(f".{report.name}.lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    taken = ConfigError(
        f"{report.parent / report.name.removesuffix('.export.json')}: another export is "
        "writing it; wait for it to finish or write another file"
    )
    # one export of these files at a time: two at once left one's ONNX under the other's
    # report (a G network beside a report naming the GEA checkpoint and its check)
    try:
        descriptor = lock_file(lock, "export")
    except OSError as exc:  # a folder that refuses files: named by the file asked for
        first = args.onnx if args.onnx is not None else args.torchscript
        raise OSError(exc.errno, exc.strerror or str(exc), str(first)) from None
    if descriptor is None:
        raise taken
    try:
        return _export(args, loaded, size, images, calibrated_on, report)
    finally:
        # removed while held, so that no file is left beside the exports (a failed export
        # leaves nothing); a third export in the instant between could take the lock of
        # the removed file beside a fourth's new one: a window of microseconds, not seconds
        lock.unlink(missing_ok=True)
        os.close(descriptor)  # releases the lock


def _export(
    args: argparse.Namespace,
    loaded: "LoadedModel",
    size: tuple[int, int],
    images: "list[np.ndarray] | None",
    calibrated_on: dict[str, object] | None,
    report: Path,
) -> int:
    """Write the exports and their report, checked (:func:`run`, holding the lock)."""
    # Imported here, not at the top: keeps torch out of `lenspair export --help`.
    from lenspair.model.evaluation.export import export_checkpoint

    # what this export replaces goes first, its report first of all: stopped midway, an
    # export left its new ONNX beside the last export's int8 model and report. That int8
    # model goes without --int8 too: beside the new ONNX it read as its quantised twin
    stale_int8 = int8_path(args.onnx) if args.onnx is not None else None
    if stale_int8 is not None and stale_int8.exists() and not args.int8:
        log.warning("%s: removed: the int8 model of the ONNX file this export replaces", stale_int8)
    for path in (report, *([stale_int8] if stale_int8 is not None else [])):
        path.unlink(missing_ok=True)
    checks = export_checkpoint(loaded, args.onnx, args.torchscript, size)
    for check in checks:
        print(check.summary())
    payload: dict[str, object] = {
        "checkpoint": str(args.checkpoint),
        "exports": [c.as_dict() for c in checks],
    }
    if images is not None:
        payload["int8"] = _export_int8(args, size, loaded, images) | {"calibration": calibrated_on}
    atomic_write_text(report, json.dumps(payload, indent=2) + "\n")
    print(f"wrote {report}")
    return 0


def check_outputs(args: argparse.Namespace) -> None:
    """Refuse an output that is the checkpoint, two that are one file, or a misleading suffix.

    Raises:
        ConfigError: naming the option and the file, before anything is written.
    """
    if args.onnx is not None and args.onnx.suffix.lower() != ".onnx":
        raise ConfigError(
            f"--onnx {args.onnx}: name it {args.onnx.name}.onnx; restore and eval tell "
            "ONNX models by their suffix"
        )
    if args.torchscript is not None and args.torchscript.suffix.lower() == ".onnx":
        raise ConfigError(
            f"--torchscript {args.torchscript}: restore and eval would take it for an ONNX "
            f"model; name it {args.torchscript.stem}.pt"
        )
    seen: dict[Path, str] = {Path(args.checkpoint).resolve(): "the checkpoint"}
    for option, path in _outputs(args).items():
        if (other := seen.get(path.resolve())) is not None:
            raise ConfigError(
                f"{option} {path}: the same file as {other}, which it would overwrite; "
                "choose another name"
            )
        seen[path.resolve()] = f"{option} {path}"
        if path.is_file() and _is_checkpoint(path):  # .pt is a run's suffix too (last.pt)
            raise ConfigError(
                f"{option} {path}: a lenspair checkpoint or detector, which the export would "
                "overwrite (a run could no longer resume from it); choose another name"
            )


def _is_checkpoint(path: Path) -> bool:
    """Whether ``path`` is a lenspair training checkpoint or detector (read safely, tensors only).

    A detector (``train-detector``'s ``detector.pt``) was taken for any other file and
    overwritten by ``--torchscript`` without a word.
    """
    # torch: not for --help
    from lenspair.model.checkpoint import load_checkpoint
    from lenspair.model.detection.train import load_detector

    for load in (load_checkpoint, load_detector):
        try:
            load(path)
        except ModelError:
            continue
        return True
    return False


def _outputs(args: argparse.Namespace) -> dict[str, Path]:
    """Every file the export writes, by the option (or role) that names it."""
    outputs = {"--onnx": args.onnx, "--torchscript": args.torchscript}
    if args.int8 and args.onnx is not None:
        outputs["the --int8 model"] = int8_path(args.onnx)
    outputs["the report"] = report_path(args)
    return {option: Path(path) for option, path in outputs.items() if path is not None}


def int8_path(onnx: Path) -> Path:
    """Where ``--int8`` writes its model: ``NAME.int8.onnx`` beside ``NAME.onnx``."""
    return onnx.with_name(onnx.stem + ".int8.onnx")


def report_path(args: argparse.Namespace) -> Path:
    """The JSON report: ``<first file>.export.json`` (the ONNX file, else TorchScript)."""
    first = args.onnx if args.onnx is not None else args.torchscript
    return Path(first).with_name(Path(first).name + ".export.json")


def _export_int8(
    args: argparse.Namespace,
    size: tuple[int, int],
    loaded: "LoadedModel",
    images: "list[np.ndarray]",
) -> dict[str, object]:
    import dataclasses

    # here, not at the top: keeps `lenspair export --help` from importing torch
    import torch

    # likewise: these import torch
    from lenspair.model.evaluation.quantize import check_int8
    from lenspair.model.precision import choose_precision

    decision = choose_precision("int8", torch.device("cpu"), "infer")
    print(decision.summary())
    channels = loaded.config.model.channels or 1
    log.info(
        "int8: calibrating %s on %d images of %s, then checking and timing it (minutes)",
        int8_path(args.onnx),
        len(images),
        args.calibration,
    )
    check = check_int8(loaded.network, channels, int8_path(args.onnx), size, images)
    print(check.summary())
    return {**dataclasses.asdict(check), "precision": decision.as_dict()}


def interrupt_hint(args: argparse.Namespace) -> str:
    """After Ctrl-C: the report is written last, so files without one are unfinished."""
    return f"files without {report_path(args).name} are unfinished; rerun to export again"
