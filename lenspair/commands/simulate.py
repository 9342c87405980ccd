"""Render a scene spec into a stereo recording with ground truth.

Writes the EuRoC/ASL layout (mav0/cam0, mav0/cam1 with data.csv, data/<t_ns>.png
and sensor.yaml), rig.yaml, the true calibration camchain.yaml, the resolved
scene.yaml, and truth/ (clear/ and mask/ frames of the obstructed camera and
geometry.json with the far-plane homography, planes and poses).

Scene specs are documented in calib_samples/README.md; a bundled one can be
named without its path, from any folder; examples:

    lenspair simulate rain --out rec_rain
    lenspair simulate chessboard --out boards --frames 27 --seed 3
    lenspair simulate my_scene.yaml --out rec_mine

The same spec and seed always give byte-identical output.
"""

import argparse
import logging
from pathlib import Path

from lenspair.commands.argtypes import out_folder, positive_int, random_seed
from lenspair.core.errors import ConfigError
from lenspair.core.samples import file_or_sample, sample_names
from lenspair.simulate.errors import SimulateError
from lenspair.simulate.recording import check_output_folder, simulate_recording
from lenspair.simulate.spec import load_scene, with_overrides

log = logging.getLogger(__name__)


def _scene(text: str) -> Path:
    return file_or_sample(text, ".yaml")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the ``simulate`` arguments."""
    parser.add_argument(
        "scene",
        type=_scene,
        help="scene spec YAML file, or a bundled one by name (rain, heavy_rain, "
        "dust_swapped, chessboard, ...; calib_samples/README.md)",
    )
    parser.add_argument("--out", type=out_folder, required=True, help="new or empty output folder")
    parser.add_argument("--frames", type=positive_int, help="number of frames (overrides the spec)")
    parser.add_argument(
        "--seed", type=random_seed, help="random seed (overrides the spec; 0 .. 2**32-1)"
    )


def interrupt_hint(args: argparse.Namespace) -> str:
    """What to do after Ctrl-C: an interrupted recording is rendered over, not resumed."""
    del args
    return "a rerun renders the recording again from its start"


def run(args: argparse.Namespace) -> int:
    """Load the spec, apply overrides, render; returns the exit code."""
    check_output_folder(args.out)
    if not args.scene.exists():
        scenes = [Path(name).stem for name in sample_names(".yaml") if "camchain" not in name]
        raise ConfigError(
            f"{args.scene}: neither a scene spec file nor a bundled scene ({', '.join(scenes)})"
        )
    spec = with_overrides(load_scene(args.scene), frames=args.frames, seed=args.seed)
    try:
        summary = simulate_recording(spec, args.out, base_dir=args.scene.parent)
    except SimulateError as exc:  # what the spec asks cannot be rendered (a board's poses)
        if str(exc).startswith(str(args.scene)):
            raise
        raise SimulateError(f"{args.scene}: {exc}") from None
    print(
        f"simulate: {summary.frames} frames -> {summary.out_dir} "
        f"(cam0 {summary.images[0]} images, cam1 {summary.images[1]}; "
        f"{summary.seconds_per_pair * 1000:.0f} ms to render a frame pair, not counting writing)"
    )
    return 0
