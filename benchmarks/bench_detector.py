"""CPU latency of the anomaly detector next to the restoration network, same run.

``python -m benchmarks.bench_detector [--out DIR] [--runs 40] [--threads 1]``:
batch 1, one 540x360 mono frame, ``torch.inference_mode``, fp32, after
warm-up, with the allocator tuned as in :mod:`benchmarks.bench_model`. Three
things are timed round-robin (interleaved, so that load from other processes
hits them alike) and quoted as medians:

* ``GEA``: ``build_model("GEA", 1)`` on the 540x360 frame (the restoration
  network the detector would gate), channels-last as ``eval``, ``restore`` and
  :mod:`benchmarks.bench_model` time it (:func:`benchmarks.machine.as_deployed`);
* ``detector``: the detector's forward pass on the 270x180 copy it judges;
* ``judge``: :func:`lenspair.model.detection.judge.judge` on the 540x360
  ``uint8`` frame, i.e. with the luma conversion and the resize included,
  as a robot would call it.

The figures that matter are the ratios ``detector / GEA`` and
``judge / GEA``: on a shared machine the absolute times move with the load
(recorded at start and end), the ratios much less.
"""

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from benchmarks.machine import as_deployed
from lenspair.commands.argtypes import positive_int
from lenspair.model.detection.judge import judge
from lenspair.model.networks.complexity import describe
from lenspair.model.networks.detector import AnomalyDetector
from lenspair.model.networks.variants import build_model

HEIGHT, WIDTH = 360, 540


def run(runs: int, threads: int) -> dict[str, object]:
    """Time the three configurations; returns medians, ratios and settings."""
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    network = build_model("GEA", 1).eval()
    detector = AnomalyDetector().eval()
    height, width = detector.spec.input_size
    gea, frame = as_deployed(network, torch.rand(1, 1, HEIGHT, WIDTH))  # tunes the allocator
    small = torch.rand(1, 1, height, width)
    image = (np.random.default_rng(0).random((HEIGHT, WIDTH)) * 255).astype(np.uint8)
    calls: dict[str, Callable[[], object]] = {
        "GEA": lambda: gea(frame),
        "detector": lambda: detector(small),
        "judge": lambda: judge(detector, [image]),
    }
    times: dict[str, list[float]] = {name: [] for name in calls}
    load_start = os.getloadavg()[0]
    with torch.inference_mode():
        for index in range(runs + 3):
            for name, call in calls.items():
                start = time.perf_counter()
                call()
                if index >= 3:
                    times[name].append((time.perf_counter() - start) * 1000.0)
    medians = {name: statistics.median(values) for name, values in times.items()}
    return {
        "threads": threads,
        "runs": runs,
        "gea_layout": "channels-last",
        "load_average": [round(load_start, 2), round(os.getloadavg()[0], 2)],
        "median_ms": {k: round(v, 3) for k, v in medians.items()},
        "ratio_detector_to_gea": round(medians["detector"] / medians["GEA"], 4),
        "ratio_judge_to_gea": round(medians["judge"] / medians["GEA"], 4),
        "parameters": {
            "GEA": describe(network, (1, HEIGHT, WIDTH)).parameters,
            "detector": describe(detector, (1, height, width)).parameters,
        },
        "gflops": {
            "GEA": round(describe(network, (1, HEIGHT, WIDTH)).gflops, 3),
            "detector": round(describe(detector, (1, height, width)).gflops, 3),
        },
    }


def markdown(result: dict) -> str:  # type: ignore[type-arg]
    """A table of the result."""
    medians, parameters, gflops = result["median_ms"], result["parameters"], result["gflops"]
    lines = [
        f"Batch 1, 540x360 mono frame, fp32 (GEA channels-last, as deployed), "
        f"{result['threads']} thread(s), "
        f"median of {result['runs']} interleaved runs; load average "
        f"{result['load_average'][0]} -> {result['load_average'][1]}.",
        "",
        "| network | input | params | GFLOPs | median ms | x GEA |",
        "|---|---|---|---|---|---|",
        f"| GEA (restoration) | 540x360 | {parameters['GEA']:,} | {gflops['GEA']} | "
        f"{medians['GEA']:.2f} | 1 |",
        f"| detector (forward) | 270x180 | {parameters['detector']:,} | {gflops['detector']} | "
        f"{medians['detector']:.2f} | {result['ratio_detector_to_gea']:.3f} |",
        f"| detector (judge: luma, resize, forward) | 540x360 uint8 | | | "
        f"{medians['judge']:.2f} | {result['ratio_judge_to_gea']:.3f} |",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Command line: run, print the table, write it and the JSON to ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--out", type=Path, help="folder for detector.md and detector.json")
    parser.add_argument("--runs", type=positive_int, default=40)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    result = run(args.runs, args.threads)
    table = markdown(result)
    print(table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "detector.md").write_text(table)
        (args.out / "detector.json").write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
