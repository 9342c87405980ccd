"""Training throughput of the full GAN step, fp32 against mixed precision.

``python -m benchmarks.bench_training [--out DIR] [--device cpu|cuda] [--steps N]``:
GEA (width 1, 9 residual blocks), mono, batch 8, 256 px crops, the whole
training step of :class:`lenspair.model.training.step.Trainer` (G/E/A forward, PatchGAN on
real and fake, LSGAN + feature matching + L2 — the perceptual term only if
VGG19 weights are configured — two Adam updates, the NaN/Inf guard).

fp32 and mixed precision (bf16 autocast on the CPU, fp16 autocast with a
GradScaler on CUDA) are timed round-robin after warm-up, so a load spike
from other processes hits both alike; the median step time is quoted as
steps/s and images/s, with the mixed/fp32 speed ratio. Inference latency as
deployed (batch 1, 540x360, :mod:`lenspair.model.evaluation.latency`) is measured on the same
device at every precision. The load average at start and end is recorded.
"""

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import torch

from lenspair.model.evaluation.latency import measure_latency
from lenspair.model.training.config import DataConfig, ModelConfig, RunConfig, TrainConfig
from lenspair.model.training.step import Trainer


def _config(amp: bool, batch: int) -> RunConfig:
    return RunConfig(
        model=ModelConfig(variant="GEA", channels=1),
        data=DataConfig(),
        train=TrainConfig(batch_size=batch, amp=amp, tensorboard=False),
    )


def _batch(batch: int, crop: int, device: torch.device) -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    target = torch.rand(batch, 1, crop, crop, generator=generator)
    keep = (torch.rand(batch, 1, crop, crop, generator=generator) > 0.1).float()
    return {
        "input": (target * keep).to(device),
        "target": target.to(device),
        "valid": torch.ones(batch, 1, crop, crop, device=device),
    }


def measure(device: torch.device, steps: int, warmup: int, batch: int, crop: int) -> dict[str, Any]:
    """Median training step time of fp32 and mixed precision, plus inference latency."""
    trainers = {"fp32": Trainer(_config(False, batch), device)}
    mixed = Trainer(_config(True, batch), device)
    trainers[mixed.precision] = mixed
    data = _batch(batch, crop, device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for trainer in trainers.values():
        for _ in range(warmup):
            trainer.train_step(data)
    times: dict[str, list[float]] = {name: [] for name in trainers}
    for _ in range(steps):
        for name, trainer in trainers.items():
            sync()
            start = time.perf_counter()
            trainer.train_step(data)
            sync()
            times[name].append(time.perf_counter() - start)
    medians = {name: statistics.median(values) for name, values in times.items()}
    network = trainers["fp32"].model
    precisions = ["fp32", "bf16"] + (["fp16"] if device.type == "cuda" else [])
    latency = [
        measure_latency(network, 1, device, (360, 540), p, warmup=3, runs=max(10, steps)).as_dict()
        for p in precisions
    ]
    mixed_name = mixed.precision
    return {
        "device": str(device) if device.type == "cpu" else torch.cuda.get_device_name(device),
        "threads": torch.get_num_threads(),
        "batch": batch,
        "crop": crop,
        "steps": steps,
        "warmup": warmup,
        "step_seconds_median": medians,
        "steps_per_second": {name: 1.0 / value for name, value in medians.items()},
        "images_per_second": {name: batch / value for name, value in medians.items()},
        "mixed_over_fp32_speed": medians["fp32"] / medians[mixed_name],
        "latency_batch1_540x360": latency,
    }


def _table(result: dict[str, Any]) -> str:
    lines = [
        f"Training step, GEA mono, batch {result['batch']}, crop {result['crop']}, "
        f"{result['device']}, {result['threads']} threads, median of {result['steps']} steps",
        "",
        "| precision | s/step | steps/s | images/s |",
        "| --- | ---: | ---: | ---: |",
    ]
    for name, seconds in result["step_seconds_median"].items():
        lines.append(
            f"| {name} | {seconds:.3f} | {1 / seconds:.3f} | {result['batch'] / seconds:.2f} |"
        )
    lines += [
        "",
        f"mixed precision / fp32 speed: {result['mixed_over_fp32_speed']:.2f}x",
        "",
        "| inference | median ms | p90 ms |",
        "| --- | ---: | ---: |",
    ]
    for lat in result["latency_batch1_540x360"]:
        lines.append(
            f"| {lat['device']} {lat['precision']} 540x360 batch 1 | "
            f"{lat['median_ms']:.1f} | {lat['p90_ms']:.1f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; prints a Markdown table, writes JSON with ``--out``."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_training", description=__doc__
    )
    parser.add_argument("--out", type=Path, default=None, help="folder for training.json")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--steps", type=int, default=5, help="timed steps per precision")
    parser.add_argument("--warmup", type=int, default=2, help="untimed steps per precision")
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--crop", type=int, default=256)
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (torch default)")
    args = parser.parse_args(argv)
    if args.device == "cuda" and not torch.cuda.is_available():
        print("bench_training: --device cuda but no CUDA device is available", file=sys.stderr)
        return 1
    if args.threads:
        torch.set_num_threads(args.threads)
    load_start = os.getloadavg()
    result = measure(torch.device(args.device), args.steps, args.warmup, args.batch, args.crop)
    result["load_average_start"] = load_start
    result["load_average_end"] = os.getloadavg()
    result["torch"] = str(torch.__version__)
    print(_table(result))
    print(f"\nload average: start {load_start[0]:.1f}, end {result['load_average_end'][0]:.1f}")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "training.json").write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
