"""Bounded memory: peak resident memory of ingest and dataset-build must not grow with frames.

    .venv/bin/python -m benchmarks.bench_memory [--out DIR] [--frames 500 2000]

Simulates the rain sample at half resolution (360x270: the memory question
does not depend on the frame size, and this keeps 2,000 frames affordable)
into recordings of each ``--frames`` length, then runs, each in its own
process so that its peak is its own, ``lenspair capture-ingest`` (one worker)
and ``lenspair dataset-build`` on it, and reports each process's peak
resident set size (``ru_maxrss`` from ``wait4``).

The target: the peak of the longest recording is at most 1.15x that of the
shortest, per stage (a per-frame list of records is expected; a per-frame
image buffer is not). ``restore`` joins when it exists. 2,000 frames take
several minutes per stage on two shared cores.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

SCENE = Path(__file__).resolve().parents[1] / "calib_samples" / "rain.yaml"
TARGET_RATIO = 1.15


def _small_scene(path: Path, frames: int) -> Path:
    scene = yaml.safe_load(SCENE.read_text())
    for camera in ("cam0", "cam1"):
        scene["rig"][camera]["intrinsics"] = [v / 2 for v in scene["rig"][camera]["intrinsics"]]
        scene["rig"][camera]["resolution"] = [360, 270]
    scene["recording"]["frames"] = frames
    scene["obstructed"]["effects"]["raindrops"] = {"count": 12, "radius_px": [3.0, 11.0]}
    path.write_text(yaml.safe_dump(scene))
    return path


def _peak_mib(argv: list[str]) -> tuple[float, float]:
    """Run ``lenspair ARGV`` in a child process; returns (peak RSS MiB, seconds)."""
    started = time.monotonic()
    child = subprocess.Popen(
        [sys.executable, "-m", "lenspair", *argv],
        env={**os.environ, "LENSPAIR_QUIET": "1"},
        stdout=subprocess.DEVNULL,
    )
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise RuntimeError(f"lenspair {' '.join(argv)} exited with {child.returncode}")
    return usage.ru_maxrss / 1024, time.monotonic() - started  # ru_maxrss is KiB on Linux


def main(argv: list[str] | None = None) -> int:
    """Measure and print the table; returns 1 when memory grows past the target."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--frames", type=int, nargs="+", default=[500, 2000])
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="lenspair-memory-") as scratch:
        root = Path(scratch)
        for frames in args.frames:
            scene = _small_scene(root / f"scene{frames}.yaml", frames)
            recording = root / f"rec{frames}"
            subprocess.run(
                [sys.executable, "-m", "lenspair", "simulate", str(scene), "--out", str(recording)],
                env={**os.environ, "LENSPAIR_QUIET": "1"},
                stdout=subprocess.DEVNULL,
                check=True,
            )
            ingested = root / f"ingested{frames}"
            stages = {
                "capture-ingest": [
                    "capture-ingest",
                    str(recording),
                    "--out",
                    str(ingested),
                    "--size",
                    "240x160",
                ],
                "dataset-build": [
                    "dataset-build",
                    str(ingested / recording.name),
                    "--out",
                    str(root / f"ds{frames}"),
                ],
            }
            for stage, command in stages.items():
                peak, seconds = _peak_mib(command)
                rows.append({"stage": stage, "frames": frames, "peak_mib": peak, "s": seconds})
    low, high = min(args.frames), max(args.frames)
    print(f"| stage | peak RSS at {low} frames | at {high} frames | ratio |")
    print("|---|---|---|---|")
    worst = 0.0
    for stage in ("capture-ingest", "dataset-build"):
        first = next(r for r in rows if r["stage"] == stage and r["frames"] == low)
        last = next(r for r in rows if r["stage"] == stage and r["frames"] == high)
        ratio = last["peak_mib"] / first["peak_mib"]
        worst = max(worst, ratio)
        print(f"| {stage} | {first['peak_mib']:.0f} MiB | {last['peak_mib']:.0f} MiB | "
              f"{ratio:.3f}x |")  # fmt: skip
    print(f"\ntarget: ratio <= {TARGET_RATIO} per stage; worst {worst:.3f}x")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        payload = {"rows": rows, "worst_ratio": worst, "target_ratio": TARGET_RATIO}
        (args.out / "memory.json").write_text(json.dumps(payload, indent=2) + "\n")
    return 0 if worst <= TARGET_RATIO else 1


if __name__ == "__main__":
    sys.exit(main())
