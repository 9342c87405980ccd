"""Benchmark of ``capture-ingest``: cost per pair against the I/O floor of the same run.

    .venv/bin/python -m benchmarks.bench_ingest [--out DIR] [--frames 40] [--runs 3]

Simulates the rain sample (``calib_samples/rain.yaml``) into a temporary
folder, ingests it once (which estimates and caches the homography), then
times, in interleaved rounds:

* ``io floor``: per pair, what any ingest must do: decode both raw frames,
  one composed ``cv2.remap`` per view, encode both outputs as PNG;
* ``ingest w1``: the per-frame stage of :func:`lenspair.capture.ingest.ingest_recording`
  with one process (remap, verify, refine, write, hash, journal), into a
  fresh folder that holds only the cached homography;
* ``ingest w2``: the same with two worker processes (pool start included).

The target is ``ingest w1 / io floor <= 2.5``. Medians of ``--runs`` rounds;
the ratio is the median of the per-round ratios. The one-off per-recording
setup (homography from pooled features, crop, maps) is reported apart. The
Markdown table goes to stdout and, with ``--out``, to ``ingest.md``
beside ``ingest.json``.
"""

import argparse
import json
import os
import platform
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingest_registration import REGISTRATION_FILE
from lenspair.capture.ingested import read_pairs
from lenspair.capture.recording import load_frame, open_recording
from lenspair.capture.rigfile import read_rig_file
from lenspair.cli import main as lenspair_main
from lenspair.commands.argtypes import positive_int
from lenspair.core.imagewrite import write_image
from lenspair.rectify.crop import Crop
from lenspair.rectify.rectification import StereoRectification
from lenspair.rectify.remap import apply, input_map, target_map
from lenspair.rectify.rig import read_kalibr

SCENE = Path(__file__).resolve().parents[1] / "calib_samples" / "rain.yaml"


def _io_floor(recording: Path, out_dir: Path, scratch: Path) -> tuple[float, int]:
    """Seconds for decode + remap + encode of every kept pair; returns (seconds, pairs)."""
    report = json.loads((out_dir / "report.json").read_text())
    registration = json.loads((out_dir / REGISTRATION_FILE).read_text())
    rig = read_kalibr(recording / "camchain.yaml")
    rectification = StereoRectification.from_rig(rig)
    obstructed = read_rig_file(recording / "rig.yaml").obstructed
    clean = "cam0" if obstructed == "cam1" else "cam1"
    crop = Crop(*report["crop"])
    matrix = np.asarray(registration["matrix"])
    grid_in = input_map(
        lambda p: rectification.rectified_to_raw(obstructed, p).astype(np.float64), crop
    )
    grid_target = target_map(
        lambda p: rectification.rectified_to_raw(clean, p).astype(np.float64),  # type: ignore[arg-type]
        matrix,
        crop,
    )
    opened = open_recording(recording)
    frames = {camera: {f.t_ns: f for f in opened.frames[camera]} for camera in ("cam0", "cam1")}
    pairs = [
        (frames[obstructed][r.t_ns], frames[clean][r.t_clean_ns])
        for r in read_pairs(out_dir / "pairs.jsonl")
        if r.status == "kept" and r.t_clean_ns is not None
    ]
    start = time.perf_counter()
    for frame_in, frame_target in pairs:
        image_in = apply(load_frame(frame_in), grid_in)
        image_target = apply(load_frame(frame_target), grid_target)
        write_image(scratch / "input" / f"{frame_in.t_ns}.png", image_in)
        write_image(scratch / "target" / f"{frame_in.t_ns}.png", image_target)
    return time.perf_counter() - start, len(pairs)


def _ingest_frames(recording: Path, cached: Path, out: Path, workers: int) -> tuple[float, int]:
    """Seconds of the per-frame stage of a fresh ingest (homography from the cache)."""
    rec_dir = out / recording.name
    rec_dir.mkdir(parents=True)
    shutil.copy(cached, rec_dir / REGISTRATION_FILE)
    report = ingest_recording(recording, out, workers=workers)
    return report.timings_s["frames"], report.counts["pairs"]


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; returns 0."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_ingest", description=__doc__)
    parser.add_argument("--out", type=Path, default=None, help="folder for JSON and Markdown")
    parser.add_argument(
        "--frames", type=positive_int, default=40, help="simulated frames (default 40)"
    )
    parser.add_argument("--runs", type=positive_int, default=3, help="timed rounds (default 3)")
    args = parser.parse_args(argv)
    os.environ.setdefault("LENSPAIR_QUIET", "1")
    with tempfile.TemporaryDirectory(prefix="bench_ingest_") as tmp:
        root = Path(tmp)
        recording = root / "rain"
        simulate = ["simulate", str(SCENE), "--out", str(recording), "--frames", str(args.frames)]
        if lenspair_main(simulate) != 0:
            return 1
        first = ingest_recording(recording, root / "first")
        out_dir = root / "first" / recording.name
        setup_s = sum(first.timings_s[k] for k in ("open", "homography", "maps", "side_check"))
        floors, ones, twos, ratios = [], [], [], []
        pairs = 0
        for run in range(args.runs):
            floor_s, pairs = _io_floor(recording, out_dir, root / f"floor{run}")
            one_s, _ = _ingest_frames(recording, out_dir / REGISTRATION_FILE, root / f"w1_{run}", 1)
            two_s, _ = _ingest_frames(recording, out_dir / REGISTRATION_FILE, root / f"w2_{run}", 2)
            floors.append(floor_s / pairs)
            ones.append(one_s / pairs)
            twos.append(two_s / pairs)
            ratios.append(one_s / floor_s)
    result = {
        "benchmark": "ingest",
        "scene": str(SCENE.name),
        "frames": args.frames,
        "pairs": pairs,
        "runs": args.runs,
        "io_floor_ms_per_pair": 1000 * statistics.median(floors),
        "ingest_w1_ms_per_pair": 1000 * statistics.median(ones),
        "ingest_w2_ms_per_pair": 1000 * statistics.median(twos),
        "ratio_w1_to_floor": statistics.median(ratios),
        "target_ratio": 2.5,
        "pairs_per_s_w1": 1.0 / statistics.median(ones),
        "pairs_per_s_w2": 1.0 / statistics.median(twos),
        "setup_s": setup_s,
        "setup_homography_s": first.timings_s["homography"],
        "cpu_count": os.cpu_count(),
        "machine": platform.platform(),
    }
    table = "\n".join(
        [
            f"capture-ingest, {pairs} pairs of {args.frames} simulated rain frames, "
            f"medians of {args.runs} runs",
            "",
            "| stage | ms per pair | pairs/s | x io floor |",
            "|---|---:|---:|---:|",
            f"| io floor (decode + remap + encode) | {result['io_floor_ms_per_pair']:.1f} | "
            f"{1000 / result['io_floor_ms_per_pair']:.1f} | 1.00 |",
            f"| ingest --workers 1 | {result['ingest_w1_ms_per_pair']:.1f} | "
            f"{result['pairs_per_s_w1']:.1f} | {result['ratio_w1_to_floor']:.2f} (target <= 2.5) |",
            f"| ingest --workers 2 | {result['ingest_w2_ms_per_pair']:.1f} | "
            f"{result['pairs_per_s_w2']:.1f} | - |",
            "",
            f"One-off setup per recording: {setup_s:.1f} s "
            f"(homography from pooled features {result['setup_homography_s']:.1f} s).",
        ]
    )
    print(table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "ingest.json").write_text(json.dumps(result, indent=2) + "\n")
        (args.out / "ingest.md").write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
