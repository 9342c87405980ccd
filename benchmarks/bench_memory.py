"""Bounded memory: peak resident memory of ingest, dataset-build and restore vs frames.

    .venv/bin/python -m benchmarks.bench_memory [--out DIR] [--frames 500 2000]

Simulates the rain sample at half resolution (360x270: the memory question
does not depend on the frame size, and this keeps 2,000 frames affordable)
into a recording of each ``--frames`` length, then runs on it, each in its
own process so that its peak is its own:

* ``lenspair capture-ingest --workers 1`` (the recording -> pairs),
* ``lenspair dataset-build`` (those pairs -> a split dataset),
* ``lenspair restore`` with the shipped mono GEA weights
  (``lenspair/model/weights/gea_ours_mono.pt``) on the recording,

and reports each process's peak resident set size (``ru_maxrss`` from
``wait4``, which covers the process and the children it waited for) and, per
command, the ratio of the peak at the most frames to the peak at the fewest,
measured in the same run. Linux starts a child's ``ru_maxrss`` at its
parent's resident size at the fork, so a heavy parent would hide the
children's peaks: when ``python -m benchmarks`` ran every benchmark in one
process, this one ran after the network benchmarks, with torch loaded and over
1 GiB resident, and every command then read the same 1,232 MiB. Each command
is therefore started by a small launcher process (a bare Python, about 10 MiB)
that spawns it and reports its ``ru_maxrss``, whatever this process holds.

The target: that ratio is at most 1.15 per command (a per-frame list of
records is expected; a per-frame image buffer is not). Children run with one
torch/OpenMP thread. 2,000 frames take several minutes per command on two
shared cores.
"""

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from lenspair.commands.argtypes import positive_int

SCENE = Path(__file__).resolve().parents[1] / "calib_samples" / "rain.yaml"
TARGET_RATIO = 1.15
COMMANDS = ("capture-ingest", "dataset-build", "restore")
WEIGHTS = "gea_ours_mono.pt"  # lenspair.model.training.pretrained.WEIGHTS_FILES[1]
ENV = {
    **os.environ,
    "LENSPAIR_QUIET": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    # every build measures its pairs (the shorter recording's frames begin the longer one's:
    # read back from the user's cache, the longer build would do less work per frame)
    "LENSPAIR_CACHE_DIR": "",
}


def _small_scene(path: Path, frames: int) -> Path:
    scene = yaml.safe_load(SCENE.read_text())
    for camera in ("cam0", "cam1"):
        scene["rig"][camera]["intrinsics"] = [v / 2 for v in scene["rig"][camera]["intrinsics"]]
        scene["rig"][camera]["resolution"] = [360, 270]
    scene["recording"]["frames"] = frames
    scene["obstructed"]["effects"]["raindrops"] = {"count": 12, "radius_px": [3.0, 11.0]}
    path.write_text(yaml.safe_dump(scene))
    return path


# Spawns ARGV with its stdout on /dev/null, waits, prints "<ru_maxrss KiB> <exit code>".
_LAUNCHER = """
import os, sys
null = [(os.POSIX_SPAWN_OPEN, 1, os.devnull, os.O_WRONLY, 0)]
pid = os.posix_spawn(sys.argv[1], sys.argv[1:], os.environ, file_actions=null)
_, status, usage = os.wait4(pid, 0)
print(usage.ru_maxrss, os.waitstatus_to_exitcode(status))
"""


def _peak_mib(argv: list[str]) -> tuple[float, float]:
    """Run ``lenspair ARGV`` in a child process; returns (peak RSS MiB, seconds).

    The child is spawned by a bare launcher, not by this process, so its peak
    does not start at this process's size (see the module's docstring).
    """
    started = time.monotonic()
    command = [sys.executable, "-m", "lenspair", *argv]
    launched = subprocess.run(
        [sys.executable, "-I", "-S", "-c", _LAUNCHER, *command],
        env=ENV,
        stdout=subprocess.PIPE,
        text=True,
        check=True,
    )
    peak_kib, code = (int(word) for word in launched.stdout.split())
    if code != 0:
        raise RuntimeError(f"lenspair {' '.join(argv)} exited with {code}")
    return peak_kib / 1024, time.monotonic() - started  # ru_maxrss is KiB on Linux


def _package_folder(name: str) -> Path:
    """Where an installed package lives, found without importing it (it imports torch)."""
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError(f"{name} is not installed")
    return Path(next(iter(spec.submodule_search_locations)))


def _commands(root: Path, recording: Path, frames: int) -> dict[str, list[str]]:
    """The measured command lines on the ``frames``-long recording, in run order."""
    ingested = root / f"ingested{frames}"
    weights = _package_folder("lenspair.model") / "weights" / WEIGHTS
    return {
        "capture-ingest": ["capture-ingest", str(recording), "--out", str(ingested),
                           "--size", "240x160", "--workers", "1"],
        "dataset-build": ["dataset-build", str(ingested / recording.name),
                          "--out", str(root / f"ds{frames}")],
        "restore": ["restore", str(weights), str(recording), "--out", str(root / f"rs{frames}"),
                    "--device", "cpu"],
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Measure and print the table; returns 1 when memory grows past the target."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument(
        "--frames", type=positive_int, nargs=2, default=[500, 2000], metavar=("FEW", "MANY")
    )
    args = parser.parse_args(argv)
    few, many = sorted(args.frames)
    if few < 1 or few == many:
        parser.error("--frames: two different positive frame counts")
    rows = []
    with tempfile.TemporaryDirectory(prefix="lenspair-memory-") as scratch:
        root = Path(scratch)
        for frames in (few, many):
            scene = _small_scene(root / f"scene{frames}.yaml", frames)
            recording = root / f"rec{frames}"
            subprocess.run(
                [sys.executable, "-m", "lenspair", "simulate", str(scene), "--out", str(recording)],
                env=ENV,
                stdout=subprocess.DEVNULL,
                check=True,
            )
            for command, line in _commands(root, recording, frames).items():
                peak, seconds = _peak_mib(line)
                rows.append({"command": command, "frames": frames, "peak_mib": peak, "s": seconds})
                print(f"{command} on {frames} frames: {peak:.0f} MiB, {seconds:.0f} s", flush=True)
    print(f"\n| command | peak RSS at {few} frames | at {many} frames | ratio |")
    print("|---|---|---|---|")
    ratios = {}
    for command in COMMANDS:
        first = next(r for r in rows if r["command"] == command and r["frames"] == few)
        last = next(r for r in rows if r["command"] == command and r["frames"] == many)
        ratios[command] = last["peak_mib"] / first["peak_mib"]
        print(f"| {command} | {first['peak_mib']:.0f} MiB | {last['peak_mib']:.0f} MiB | "
              f"{ratios[command]:.3f}x |")  # fmt: skip
    worst = max(ratios.values())
    print(f"\ntarget: ratio <= {TARGET_RATIO} per command; worst {worst:.3f}x")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        payload = {"rows": rows, "ratios": ratios, "worst_ratio": worst}
        payload |= {"target_ratio": TARGET_RATIO, "threads": 1, "runs": 1}  # ENV: one thread
        (args.out / "memory.json").write_text(json.dumps(payload, indent=2) + "\n")
    return 0 if worst <= TARGET_RATIO else 1


if __name__ == "__main__":
    sys.exit(main())
