"""Restore throughput against the network's own batch-1 latency (the I/O overhead ratio).

``python -m benchmarks.bench_restore [--frames 40] [--out DIR]``: the default
network (GEA, mono, width 1, untrained weights: speed does not depend on
them), 540x360 8-bit frames. In one run it measures

* the network's batch-1 latency as ``eval`` reports it
  (:func:`lenspair.model.evaluation.latency.measure_latency`: channels-last,
  tuned allocator, median of timed runs), before and after the restore runs
  (the median of both is the reference);
* ``lenspair restore`` on a folder of ``--frames`` PNGs and on a ROS 2 bag
  (db3) holding the same frames plus a non-image topic, at batch 1 and 4:
  wall time for the whole run (decode, inference, encode, write) -> frames/s.

The **I/O overhead ratio** is ``(1 / frames per second) / latency``: 1.0 means
reading and writing cost nothing beyond the network (the goal is <= 1.2).
The machine is shared, so absolute times are noisy; the ratio is taken from
numbers measured minutes apart in the same process. Budget: about
``frames x 4 runs x latency`` plus two latency measurements (~1 min on 2 cores).
"""

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from lenspair.commands.argtypes import positive_int
from lenspair.core.imagewrite import write_image
from lenspair.model.checkpoint import build_network
from lenspair.model.evaluation.latency import measure_latency
from lenspair.model.inference.backends import TorchBackend, deploy
from lenspair.model.inference.pipeline import restore_input
from lenspair.model.inference.restore_options import RestoreOptions
from lenspair.model.training.config import ModelConfig

HEIGHT, WIDTH = 360, 540
GOAL = 1.2


def _frames(count: int, seed: int = 0) -> list[np.ndarray]:
    """Smooth random 8-bit mono frames (PNG compresses them like camera images)."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(count):
        noise = rng.random((HEIGHT, WIDTH), dtype=np.float32)
        smooth = cv2.GaussianBlur(noise, (0, 0), 3.0)
        smooth = (smooth - smooth.min()) / (np.ptp(smooth) + 1e-6)
        frames.append(np.rint(smooth * 255).astype(np.uint8))
    return frames


def _write_db3(path: Path, frames: list[np.ndarray]) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        image = writer.add_connection("/cam1/image_raw", "sensor_msgs/msg/Image", typestore=store)
        status = writer.add_connection("/status", "std_msgs/msg/String", typestore=store)
        for index, frame in enumerate(frames):
            t_ns = 1_700_000_000_000_000_000 + index * 50_000_000
            stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam1")
            message = types["sensor_msgs/msg/Image"](
                header=header,
                height=HEIGHT,
                width=WIDTH,
                encoding="mono8",
                is_bigendian=0,
                step=WIDTH,
                data=frame.reshape(-1),
            )
            writer.write(image, t_ns, store.serialize_cdr(message, "sensor_msgs/msg/Image"))
            text = types["std_msgs/msg/String"](data=f"frame {index}")
            writer.write(status, t_ns + 1, store.serialize_cdr(text, "std_msgs/msg/String"))
    return path


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print a table (and JSON); returns 0."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--frames", type=positive_int, default=40)
    parser.add_argument("--runs", type=positive_int, default=20, help="timed latency runs (20)")
    parser.add_argument("--out", type=Path, help="folder for restore.json")
    args = parser.parse_args(argv)
    os.environ.setdefault("LENSPAIR_QUIET", "1")
    device = torch.device("cpu")
    network = deploy(build_network(ModelConfig(variant="GEA", channels=1)), device)
    backend = TorchBackend(network, 1, device)
    latencies = [measure_latency(network, 1, device, (HEIGHT, WIDTH), runs=args.runs).median_ms]
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as temp:
        root = Path(temp)
        frames = _frames(args.frames)
        for index, frame in enumerate(frames):
            write_image(root / "folder" / f"{index:04d}.png", frame)
        inputs = {"folder": root / "folder", "db3 bag": _write_db3(root / "bag", frames)}
        for name, source in inputs.items():
            for batch_size in (1, 4):
                out = root / f"out_{len(runs)}"
                start = time.perf_counter()
                report = restore_input(source, out, backend, RestoreOptions(batch_size=batch_size))
                seconds = time.perf_counter() - start
                runs.append(
                    {
                        "input": name,
                        "batch_size": batch_size,
                        "frames": report.restored,
                        "seconds": round(seconds, 3),
                        "frames_per_second": round(report.restored / seconds, 2),
                        "ms_per_frame": round(1000 * seconds / report.restored, 2),
                    }
                )
    latencies.append(measure_latency(network, 1, device, (HEIGHT, WIDTH), runs=args.runs).median_ms)
    latency = statistics.median(latencies)
    for run in runs:
        run["io_overhead_ratio"] = round(float(run["ms_per_frame"]) / latency, 3)
    result = {
        "network": "GEA mono width 1, 540x360, fp32, CPU channels-last",
        "threads": torch.get_num_threads(),
        "batch1_latency_ms": [round(value, 2) for value in latencies],
        "goal_ratio": GOAL,
        "load_average": os.getloadavg(),
        "runs": runs,
    }
    text = json.dumps(result, indent=2)
    print(text)
    print(f"\n| input | batch | frames/s | ms/frame | x batch-1 latency ({latency:.1f} ms) |")
    print("|---|---|---|---|---|")
    for run in runs:
        verdict = "ok" if float(run["io_overhead_ratio"]) <= GOAL else f"> {GOAL}"
        print(
            f"| {run['input']} | {run['batch_size']} | {run['frames_per_second']} | "
            f"{run['ms_per_frame']} | {run['io_overhead_ratio']} ({verdict}) |"
        )
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "restore.json").write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
