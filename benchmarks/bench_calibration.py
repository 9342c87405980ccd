"""Stereo calibration time for 30 board views: detection, calibration, and the whole workflow.

``python -m benchmarks.bench_calibration [--out DIR] [--views N] [--repeats K]``

Views are rendered once (not timed) with :class:`tests.rectify.board_renderer.BoardRenderer`
for an Alphasense-like rig (720x540, f ~ 350 px, B = 0.11 m). Timed, as the
median of ``--repeats`` runs: corner detection in all 2N images, then
:func:`lenspair.rectify.calibration.calibrate_from_detections` (both single-camera
calibrations, stereo calibration, outlier rounds, rectification and row
disagreement), and their sum per run (``detect_calibrate_ms``: the median of
the sums, not the sum of the two medians). Then the whole ``lenspair calibrate`` workflow,
:func:`lenspair.rectify.recording_calibration.calibrate_recording`, on the same
views written as a left/right folder recording (PNG reads, pairing, detection
and calibration); its ratio to detection + calibration is the cost of reading
a recording. Accuracy columns come from the last run, against the truth.
"""

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lenspair.commands.argtypes import positive_int
from lenspair.core.imagewrite import write_image
from lenspair.rectify.boards import Board, parse_board_spec
from lenspair.rectify.calib_types import CalibrationModel
from lenspair.rectify.calibration import calibrate_from_detections, detect_views
from lenspair.rectify.projection import project_rays
from lenspair.rectify.recording_calibration import calibrate_recording
from lenspair.rectify.rig import CameraModel, DistortionModel, StereoRig
from tests.rectify.board_renderer import BoardRenderer

CASES: tuple[tuple[str, CalibrationModel], ...] = (
    ("chessboard:9x6:0.06", "pinhole-equi"),
    ("charuco:7x5:0.1:0.075:DICT_4X4_50", "pinhole-equi"),
    ("chessboard:9x6:0.06", "pinhole-radtan"),
    ("charuco:7x5:0.1:0.075:DICT_4X4_50", "pinhole-radtan"),
)
DISTORTION: dict[DistortionModel, tuple[float, float, float, float]] = {
    "radtan": (-0.28, 0.075, 0.0004, -0.0003),
    "equidistant": (-0.0095, 0.0036, -0.0049, 0.0015),
}


def make_rig(model: DistortionModel) -> StereoRig:
    """cam1 on cam0's right, slightly rotated."""
    cam0 = CameraModel((350.2, 349.8, 361.3, 268.4), model, DISTORTION[model], (720, 540))
    cam1 = CameraModel((351.6, 351.1, 357.9, 271.2), model, DISTORTION[model], (720, 540))
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.radians([0.3, -0.4, 0.2]))[0]
    T[:3, 3] = -T[:3, :3] @ np.array([0.11, 0.0, 0.0])
    return StereoRig(cam0, cam1, T)


def render_views(board: Board, rig: StereoRig, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` stereo views of the whole board, fully inside both images."""
    rng = np.random.default_rng(0)
    renderers = BoardRenderer(board, rig.cam0), BoardRenderer(board, rig.cam1)
    objects = board.object_points()
    views: list[tuple[np.ndarray, np.ndarray]] = []
    while len(views) < count:
        direction = np.array([*rng.uniform([-0.5, -0.35], [0.5, 0.35]), 1.0])
        R = cv2.Rodrigues(np.array([*rng.normal(0, 0.3, 2), rng.uniform(-0.3, 0.3)]))[0]
        t = direction / np.linalg.norm(direction) * rng.uniform(0.6, 1.2) - R @ objects.mean(0)
        R1, t1 = rig.R @ R, rig.R @ t + rig.t
        pixels = [
            project_rays(rig.cam0, objects @ R.T + t),
            project_rays(rig.cam1, objects @ R1.T + t1),
        ]
        if not all(
            np.isfinite(p).all() and p.min() > 30 and p[:, 0].max() < 690 and p[:, 1].max() < 510
            for p in pixels
        ):
            continue
        views.append(
            (
                renderers[0].render(cv2.Rodrigues(R)[0], t),
                renderers[1].render(cv2.Rodrigues(R1)[0], t1),
            )
        )
    return views


def run_case(spec: str, model: CalibrationModel, count: int, repeats: int) -> dict[str, Any]:
    """Time detection and calibration of one board/model case."""
    board = parse_board_spec(spec)
    truth = make_rig("equidistant" if model == "pinhole-equi" else "radtan")
    views = render_views(board, truth, count)
    stages = ("detect", "calibrate", "recording")
    wall: dict[str, list[float]] = {stage: [] for stage in stages}
    cpu: dict[str, list[float]] = {stage: [] for stage in stages}
    with tempfile.TemporaryDirectory() as folder:
        recording = Path(folder)
        for index, (image0, image1) in enumerate(views):  # 20 Hz, not timed
            t_ns = 1_700_000_000_000_000_000 + index * 50_000_000
            write_image(recording / "left" / f"{t_ns}.png", image0)
            write_image(recording / "right" / f"{t_ns}.png", image1)
        for _ in range(repeats):
            for stage in stages:
                start, start_cpu = time.perf_counter(), time.process_time()
                if stage == "detect":
                    detections = detect_views(views, board)
                elif stage == "calibrate":
                    result = calibrate_from_detections(detections, board, model, ((720, 540),) * 2)
                else:
                    calibrate_recording(recording, board, model, max_views=0)
                wall[stage].append(time.perf_counter() - start)
                cpu[stage].append(time.process_time() - start_cpu)
    focal = max(
        abs(found.camera.intrinsics[i] / true.intrinsics[i] - 1)
        for found, true in zip(result.cameras, (truth.cam0, truth.cam1), strict=True)
        for i in (0, 1)
    )
    return {
        "board": spec,
        "model": model,
        "views": count,
        "both_detected": result.counts["both_detected"],
        "detect_ms": 1e3 * statistics.median(wall["detect"]),
        "detect_cpu_ms": 1e3 * statistics.median(cpu["detect"]),
        "calibrate_ms": 1e3 * statistics.median(wall["calibrate"]),
        "calibrate_cpu_ms": 1e3 * statistics.median(cpu["calibrate"]),
        "detect_calibrate_ms": 1e3
        * statistics.median(d + c for d, c in zip(wall["detect"], wall["calibrate"], strict=True)),
        "recording_ms": 1e3 * statistics.median(wall["recording"]),
        "recording_cpu_ms": 1e3 * statistics.median(cpu["recording"]),
        "stereo_rms_px": result.stereo_rms_px,
        "row_disagreement_px": result.row_disagreement_px,
        "focal_error_pct": 100 * focal,
        "baseline_error_pct": 100 * abs(result.rig.baseline_m / truth.baseline_m - 1),
        "repeats": repeats,
        "opencv_threads": cv2.getNumThreads(),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; prints a Markdown table, writes calibration.json with --out."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_calibration", description=__doc__
    )
    parser.add_argument("--out", type=Path, default=None, help="folder for calibration.json")
    parser.add_argument(
        "--views", type=positive_int, default=30, help="stereo views per case (default 30)"
    )
    parser.add_argument(
        "--repeats", type=positive_int, default=3, help="timed runs per case (median)"
    )
    args = parser.parse_args(argv)
    rows = [run_case(spec, model, args.views, args.repeats) for spec, model in CASES]
    print(
        f"Stereo calibration of {args.views} views (720x540), median of {args.repeats} runs, "
        f"OpenCV {cv2.__version__}; wall ms (process CPU ms).\n"
    )
    print("| board | model | found in both | detection ms | calibration ms | workflow ms "
          "| workflow / (detection + calibration) | stereo RMS px "
          "| rows px | focal err % | baseline err % |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        ratio = r["recording_ms"] / (r["detect_ms"] + r["calibrate_ms"])
        print(f"| {r['board']} | {r['model']} | {r['both_detected']}/{r['views']} | "
              f"{r['detect_ms']:.0f} ({r['detect_cpu_ms']:.0f}) | "
              f"{r['calibrate_ms']:.0f} ({r['calibrate_cpu_ms']:.0f}) | "
              f"{r['recording_ms']:.0f} ({r['recording_cpu_ms']:.0f}) | {ratio:.2f} | "
              f"{r['stereo_rms_px']:.3f} | {r['row_disagreement_px']:.3f} | "
              f"{r['focal_error_pct']:.3f} | {r['baseline_error_pct']:.3f} |")  # fmt: skip
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        payload = {"opencv": cv2.__version__, "cases": rows}
        (args.out / "calibration.json").write_text(json.dumps(payload, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
