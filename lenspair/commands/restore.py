"""Restore images, folders, recordings and bags with a trained network: the same format out.

  lenspair restore runs/rain/checkpoints/best.pt photos/ --out photos_clean/
  lenspair restore model.onnx run_01/ --out run_01_clean/ --camera cam1
  lenspair restore best.pt rain_run/ --out clean_run/ --suffix /restored   # ROS 2 bag folder

INPUT is an image, a folder of images (recursive; the tree and file names are
kept), an EuRoC/ASL recording (data.csv, sensor.yaml and every other file
copied; the chosen camera's images restored), a ROS 1 .bag or a ROS 2 bag
(.db3 or .mcap; every message copied, restored images on the same topics or on
<topic><suffix>, headers and log times unchanged). Images keep their bit
depth, channels, orientation, colour profile and EXIF (an image file's alpha
channel is written back unchanged beside the restored colour; 16-bit frames of
10- or 12-bit values are restored on the full scale and written back in the
camera's words; a Bayer bag frame is demosaiced, restored in colour, and
sampled back into its mosaic); restored JPEG files and JPEG CompressedImage
messages are written at --jpeg-quality (default 95). The model is a lenspair
checkpoint (torch, CPU or CUDA) or an ONNX file from `lenspair export` (ONNX
Runtime; any size runs whole, as with a checkpoint; an ONNX file of a fixed
size, from an earlier lenspair, runs other sizes on tiles of its size, with a
warning, and the report records the tile as forced_tile).

Outputs keep the input's names under OUT: an image goes to OUT/<image name>,
a folder's images to OUT/<path inside the folder>, an EuRoC/ASL recording to
OUT/mav0/... (left/right folders to OUT/left/ and OUT/right/), a ROS 1 bag to
OUT/<bag name>.bag, a ROS 2 bag folder to the folder OUT/<its name>/ (a bare
.db3 or .mcap file to OUT/<its name without the suffix>/).

Any size works (padded to a multiple of 4 and cropped back, as eval does);
--tile N runs large images in overlapping N x N tiles blended without seams.
Unreadable frames, and frames too large for memory (the report says which
--tile fits), are copied unchanged, named on stderr (one line each, the
first 20) and listed in OUT/restore_report.json (the run goes on; when no
frame at all could be restored it ends with exit code 2 and the first
reason); a bag whose camera topics hold no message is refused (exit 2);
a non-empty OUT is refused unless --resume, which continues a killed run and
writes the same bytes as an uninterrupted one (a bag the run finished is kept
while its files are unchanged).
"""

import argparse
import logging

from lenspair.commands.argtypes import (
    add_device_option,
    add_topics_option,
    detector_file,
    input_path,
    out_folder,
    positive_int,
)
from lenspair.core.errors import ConfigError
from lenspair.model.inference.options import (
    CAMERA_CHOICES,
    CUDA_BATCH_SIZE,
    DEFAULT_BATCH_SIZE,
    DEFAULT_JPEG_QUALITY,
    DEFAULT_OVERLAP,
    MAX_JPEG_QUALITY,
    PRECISIONS,
    default_batch_size,
)

log = logging.getLogger(__name__)


def jpeg_quality(text: str) -> int:
    """Argparse type: ``--jpeg-quality``, an integer from 1 to :data:`MAX_JPEG_QUALITY`."""
    return positive_int(text, MAX_JPEG_QUALITY)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``restore``."""
    parser.add_argument("model", type=input_path, help="checkpoint (.pt) or ONNX model (.onnx)")
    parser.add_argument("input", type=input_path, help="image, folder, EuRoC/ASL recording or bag")
    parser.add_argument(
        "--out",
        type=out_folder,
        required=True,
        help="output folder (empty or new); outputs keep the input's names: OUT/<image "
        "name>, OUT/<path inside the folder>, OUT/mav0/... for a EuRoC recording, OUT/<bag "
        "name> for a bag (a ROS 2 bag: the folder OUT/<bag folder name>/)",
    )
    parser.add_argument(
        "--camera",
        choices=CAMERA_CHOICES,
        default="auto",
        help="recordings and bags: camera(s) to restore (auto: the obstructed one in "
        "rig.yaml, else every camera the recording holds)",
    )
    parser.add_argument(
        "--suffix",
        default="",
        help="bags: write restored images to <topic><suffix> (e.g. /restored) beside the "
        "originals instead of replacing them",
    )
    parser.add_argument(
        "--batch-size",
        type=int,
        default=None,
        help=f"frames per network call ({DEFAULT_BATCH_SIZE} on the CPU, where batching is "
        f"no faster and gives exactly Restorer's bytes; {CUDA_BATCH_SIZE} on a GPU)",
    )
    parser.add_argument("--tile", type=int, help="tile side in pixels for large images (off)")
    parser.add_argument(
        "--overlap",
        type=int,
        default=DEFAULT_OVERLAP,
        help=f"tile overlap in pixels ({DEFAULT_OVERLAP})",
    )
    parser.add_argument(
        "--jpeg-quality",
        type=jpeg_quality,
        default=DEFAULT_JPEG_QUALITY,
        metavar="Q",
        help=f"quality 1-{MAX_JPEG_QUALITY} of every restored JPEG: image files and JPEG "
        f"CompressedImage messages in bags (default {DEFAULT_JPEG_QUALITY}); PNG, TIFF and "
        "other outputs are unaffected. An input's own quality is not matched: OpenImageIO "
        "cannot read it from the file",
    )
    add_device_option(parser)
    parser.add_argument(
        "--precision",
        choices=PRECISIONS,
        default="auto",
        help="auto (bf16 on a CPU with avx512_bf16/AMX where it measures faster than fp32, "
        "else fp32; fp32 on CUDA), fp32, bf16 "
        "or fp16 (CUDA); an ONNX model runs at the precision it was exported at (fp32, or int8 "
        "from export --int8)",
    )
    add_topics_option(parser)
    parser.add_argument("--resume", action="store_true", help="continue a killed run in OUT")
    parser.add_argument(
        "--only-obstructed",
        type=detector_file,
        metavar="DETECTOR",
        help="restore only frames this anomaly detector (lenspair train-detector, or "
        "detector.pt: the bundled one) calls obstructed; copy the others unchanged",
    )


def run(args: argparse.Namespace) -> int:
    """Restore; prints the summary line; returns the exit code."""
    # Imported here, not at module level: they load torch, which --help must not.
    from lenspair.core.device import resolve_device
    from lenspair.model.inference.backends import open_backend
    from lenspair.model.inference.input_checks import check_input
    from lenspair.model.inference.judge import default_judge
    from lenspair.model.inference.pipeline import restore_input
    from lenspair.model.inference.report import REPORT_NAME
    from lenspair.model.inference.restore_options import RestoreOptions, check_options

    device = resolve_device(args.device)
    options = RestoreOptions(
        camera=args.camera,
        batch_size=default_batch_size(device.type) if args.batch_size is None else args.batch_size,
        tile=args.tile,
        overlap=args.overlap,
        suffix=args.suffix,
        resume=args.resume,
        topics=args.topics,
        jpeg_quality=args.jpeg_quality,
    )
    check_options(options)  # before the model loads: a bad option is the only line
    checked = check_input(args.input, args.out, options)  # and so is a mistyped path or topic
    judge = default_judge(args.only_obstructed, device) if args.only_obstructed else None
    backend = open_backend(args.model, device, args.precision)
    report = restore_input(args.input, args.out, backend, options, judge, checked)
    for line in report.problem_lines():
        log.warning("%s", line)
    print(report.summary())
    if report.failed and not (report.restored or report.resumed or report.skipped):
        # every frame failed: a script must not read this run as done (exit 0)
        first = next((p["reason"] for p in report.problems if p.get("frame")), "see the report")
        raise ConfigError(
            f"none of the {report.failed} frame(s) could be restored (the first: {first}); "
            f"each is listed in {args.out / REPORT_NAME}"
        )
    return 0
