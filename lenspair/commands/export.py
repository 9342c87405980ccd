"""Export a checkpoint to ONNX and/or TorchScript, checked against torch.

  lenspair export CKPT --onnx model.onnx [--torchscript model.pt] [--size 540x360]

The exported network takes one image (N, C, H, W) float32 in [0, 1] of the
given size (batch dynamic in ONNX) and returns the restored image. Each file
is run on a seeded random image and compared with torch (the largest absolute
difference is printed) and timed at batch 1. Checking and timing ONNX needs
onnxruntime (a dependency of lenspair; reinstall it); without it the file is written
and the output says it was not checked. A JSON report goes next to the
first file (<name>.export.json).
"""

import argparse
import json
from pathlib import Path

from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import atomic_write_text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``export``."""
    parser.add_argument("checkpoint", type=Path, help="checkpoint (.pt) from lenspair train")
    parser.add_argument("--onnx", type=Path, help="ONNX file to write")
    parser.add_argument("--torchscript", type=Path, help="TorchScript file to write")
    parser.add_argument("--size", default="540x360", help="WIDTHxHEIGHT of the input (540x360)")


def run(args: argparse.Namespace) -> int:
    """Export and check; returns the exit code."""
    # Imported here, not at the top: keeps torch out of `lenspair export --help`.
    from lenspair.model.evaluation.export import export_checkpoint, parse_size

    if args.onnx is None and args.torchscript is None:
        raise ConfigError("give --onnx FILE and/or --torchscript FILE")
    checks = export_checkpoint(args.checkpoint, args.onnx, args.torchscript, parse_size(args.size))
    for check in checks:
        print(check.summary())
    first = Path(checks[0].path)
    report = first.with_name(first.name + ".export.json")
    payload = {"checkpoint": str(args.checkpoint), "exports": [c.as_dict() for c in checks]}
    atomic_write_text(report, json.dumps(payload, indent=2) + "\n")
    print(f"wrote {report}")
    return 0
