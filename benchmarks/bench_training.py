"""Training throughput of the full GAN step at every precision ``auto`` can choose.

``python -m benchmarks.bench_training [--out DIR] [--device cpu|cuda] [--steps N]``:
GEA (width 1, 9 residual blocks), mono, batch 8, 256 px crops, the whole
training step of :class:`lenspair.model.training.step.Trainer` (G/E/A forward, PatchGAN on
real and fake, LSGAN + feature matching + L2 — the perceptual term only if
VGG19 weights are configured — two Adam updates, the NaN/Inf guard).

Every precision native on the device (:mod:`lenspair.model.precision`: fp32,
and bf16 autocast on a CPU with avx512_bf16/AMX; bf16/fp16 on CUDA by
capability) is timed round-robin after warm-up, so a load spike from other
processes hits all alike; with ``--compile`` also the fastest native one
with the restoration network under ``torch.compile`` (compile time
recorded). Median step time as steps/s, images/s and speed vs fp32, and
whether ``auto``'s choice was the fastest eager precision. Inference is measured
on the same device at every precision (:mod:`lenspair.model.evaluation.latency`):
latency as deployed (batch 1) at 540x360 and 720x480, and throughput at batch 8
(:data:`INFERENCE_SHAPES`). The load average at start and end is recorded.
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
from torch.utils.flop_counter import FlopCounterMode

from benchmarks.machine import peaks as measure_peaks
from lenspair.commands.argtypes import positive_int
from lenspair.model.evaluation.latency import measure_latency
from lenspair.model.precision import choose_precision
from lenspair.model.training.config import DataConfig, ModelConfig, RunConfig, TrainConfig
from lenspair.model.training.step import Trainer

INFERENCE_SHAPES = (((360, 540), 1), ((480, 720), 1), ((360, 540), 8))
"""``((H, W), batch)`` of the inference figures: latency as deployed at the paper's
540x360 and at 720x480 (the Raindrop dataset's size, where the paper times
DeRaindrop), and throughput at batch 8."""


def _config(precision: str, batch: int) -> RunConfig:
    return RunConfig(
        model=ModelConfig(variant="GEA", channels=1),
        data=DataConfig(),
        train=TrainConfig(batch_size=batch, precision=precision, tensorboard=False),  # type: ignore[arg-type]
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


TIE = 0.05
"""Step times within this fraction of each other count as a tie: medians of one run's
rounds move by that much (bf16 and fp32 read 6.22 and 6.26 s on an Intel Xeon whose
bf16 was 0.84x fp32's speed in one-thread CPU time, the load-robust measure)."""


def auto_time_over_fastest(medians: dict[str, float], auto: str) -> float:
    """``auto``'s median step time over the fastest eager precision's (1.0: auto is fastest)."""
    eager = [seconds for name, seconds in medians.items() if "compile" not in name]
    return medians[auto] / min(eager)


def measure(
    device: torch.device, steps: int, warmup: int, batch: int, crop: int, compile_network: bool
) -> dict[str, Any]:
    """Median step time at every precision ``auto`` can choose here, plus inference latency.

    The candidates are the device's native training precisions
    (:func:`lenspair.model.precision.choose_precision`); with
    ``compile_network`` the fastest eager one is timed again with the
    restoration network under ``torch.compile``.
    """
    auto = choose_precision("auto", device, "train")
    candidates = [p for p in auto.native if p != "int8"]
    trainers = {p: Trainer(_config(p, batch), device) for p in candidates}
    compile_seconds = None
    if compile_network:
        fastest_native = auto.precision
        start = time.perf_counter()
        compiled = Trainer(_config(fastest_native, batch), device)
        compiled.network = torch.compile(compiled.network)  # type: ignore[assignment]
        compiled.train_step(_batch(batch, crop, device))
        compile_seconds = time.perf_counter() - start
        trainers[f"{fastest_native} + torch.compile"] = compiled
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
    single = _single_thread_cpu_seconds(trainers, data, steps) if device.type == "cpu" else {}
    network = trainers["fp32"].model
    inference = [  # int8 inference: python -m benchmarks.bench_int8
        p for p in choose_precision("auto", device, "infer").native if p != "int8"
    ]
    runs = max(10, steps)
    latency = [
        measure_latency(network, 1, device, size, p, warmup=3, runs=runs, batch=n).as_dict()
        for size, n in INFERENCE_SHAPES
        for p in inference
    ]
    fastest = min(medians, key=medians.__getitem__)
    auto_vs_fastest = auto_time_over_fastest(medians, auto.precision)
    roofline = (
        _fp32_roofline(trainers["fp32"], data, medians["fp32"], single["fp32"])
        if device.type == "cpu"
        else {}
    )
    return roofline | {
        "device": str(device) if device.type == "cpu" else torch.cuda.get_device_name(device),
        "threads": torch.get_num_threads(),
        "batch": batch,
        "crop": crop,
        "steps": steps,
        "warmup": warmup,
        "precision_auto": auto.as_dict(),
        "step_seconds_median": medians,
        "steps_per_second": {name: 1.0 / value for name, value in medians.items()},
        "images_per_second": {name: batch / value for name, value in medians.items()},
        "speed_vs_fp32": {name: medians["fp32"] / value for name, value in medians.items()},
        "fastest": fastest,
        "auto_over_fastest_eager": auto_vs_fastest,
        "auto_is_fastest_eager": auto_vs_fastest <= 1.0 + TIE,
        "compile_seconds": compile_seconds,
        "single_thread_cpu_seconds": single,
        "single_thread_speed_vs_fp32": {n: single["fp32"] / v for n, v in single.items()},
        "inference": latency,
    }


def _single_thread_cpu_seconds(
    trainers: dict[str, Trainer], data: dict[str, torch.Tensor], steps: int
) -> dict[str, float]:
    """Median CPU time of one step on one thread, per eager precision.

    ``time.thread_time`` counts only this thread's CPU time, so other
    processes sharing the cores disturb it much less than wall time: on a
    loaded 2-core machine, wall-clock bf16 came out 2x slower than fp32 while
    its CPU time was 1.7x faster (threads of an oversubscribed OpenMP team
    wait for each other).
    """
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        cpu: dict[str, list[float]] = {n: [] for n in trainers if "compile" not in n}
        for _ in range(max(2, steps)):
            for name in cpu:
                start = time.thread_time()
                trainers[name].train_step(data)
                cpu[name].append(time.thread_time() - start)
    finally:
        torch.set_num_threads(before)
    return {name: statistics.median(values) for name, values in cpu.items()}


def step_flops(trainer: Trainer, data: dict[str, torch.Tensor]) -> float:
    """FLOPs of one training step (convolutions and matrix products, forward and backward).

    Counted by :class:`torch.utils.flop_counter.FlopCounterMode` over a real
    step (which also trains the trainer one step further).
    """
    with FlopCounterMode(display=False) as counter:
        trainer.train_step(data)
    return float(counter.get_total_flops())


def _fp32_roofline(
    trainer: Trainer, data: dict[str, torch.Tensor], seconds: float, single_seconds: float
) -> dict[str, Any]:
    """The fp32 step against the fp32 peaks measured now, at the run's threads and at one.

    The roofline is the step's FLOPs at the best GEMM-like peak
    (:func:`benchmarks.machine.peaks`); the one-thread figure divides the
    one-thread CPU time by the one-thread peak (CPU time as well).
    """
    flops = step_flops(trainer, data)
    peak = max(measure_peaks(5, time.perf_counter).values())
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        single_peak = max(measure_peaks(5, time.thread_time).values())
    finally:
        torch.set_num_threads(threads)
    return {
        "fp32_step_gflop": flops / 1e9,
        "fp32_peak_gflops": peak,
        "fp32_roofline_seconds": flops / peak / 1e9,
        "fp32_roofline_ratio": seconds / (flops / peak / 1e9),
        "single_thread_fp32_peak_gflops": single_peak,
        "single_thread_fp32_roofline_ratio": single_seconds / (flops / single_peak / 1e9),
    }


def _table(result: dict[str, Any]) -> str:
    lines = [
        f"Training step, GEA mono, batch {result['batch']}, crop {result['crop']}, "
        f"{result['device']}, {result['threads']} threads, median of {result['steps']} steps",
        "",
        "| precision | s/step | steps/s | images/s | speed vs fp32 |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for name, seconds in result["step_seconds_median"].items():
        lines.append(
            f"| {name} | {seconds:.3f} | {1 / seconds:.3f} | {result['batch'] / seconds:.2f} | "
            f"{result['speed_vs_fp32'][name]:.2f}x |"
        )
    compiled = result.get("compile_seconds")
    lines += [
        "",
        f"{result['precision_auto']['reason']}; fastest measured: {result['fastest']}; "
        f"auto is the fastest eager precision (within {TIE:.0%}): "
        f"{result['auto_is_fastest_eager']} "
        f"(auto's step {result['auto_over_fastest_eager']:.2f}x the fastest's time)"
        + (
            "; torch.compile not timed (--compile times it)"
            if compiled is None
            else f"; torch.compile's first step (compilation) took {compiled:.0f} s, not timed"
        ),
        *(
            [
                f"fp32 step: {result['fp32_step_gflop']:.0f} GFLOP (forward and backward, "
                f"FlopCounterMode); at the fp32 peak measured in this run "
                f"({result['fp32_peak_gflops']:.0f} GFLOP/s) that is "
                f"{result['fp32_roofline_seconds']:.2f} s: the step takes "
                f"{result['fp32_roofline_ratio']:.2f}x its roofline "
                f"({result['single_thread_fp32_roofline_ratio']:.2f}x on one thread)",
            ]
            if "fp32_step_gflop" in result
            else []
        ),
        "one thread, CPU time per step (robust to load): "
        + ", ".join(
            f"{name} {seconds:.2f} s ({result['single_thread_speed_vs_fp32'][name]:.2f}x fp32)"
            for name, seconds in result["single_thread_cpu_seconds"].items()
        ),
        "",
        "| inference | median ms | p90 ms | images/s |",
        "| --- | ---: | ---: | ---: |",
    ]
    for lat in result["inference"]:
        lines.append(
            f"| {lat['device']} {lat['precision']} {lat['size']} batch {lat['batch']} | "
            f"{lat['median_ms']:.1f} | {lat['p90_ms']:.1f} | "
            f"{lat['batch'] * 1000.0 / lat['median_ms']:.1f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; prints a Markdown table, writes JSON with ``--out``."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_training", description=__doc__
    )
    parser.add_argument("--out", type=Path, default=None, help="folder for training.json")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--steps", type=positive_int, default=5, help="timed steps per precision")
    parser.add_argument("--warmup", type=int, default=2, help="untimed steps per precision")
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--crop", type=int, default=256)
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (torch default)")
    parser.add_argument(
        "--compile", action="store_true", help="also time torch.compile (minutes to compile)"
    )
    args = parser.parse_args(argv)
    if args.device == "cuda" and not torch.cuda.is_available():
        print("bench_training: --device cuda but no CUDA device is available", file=sys.stderr)
        return 1
    if args.threads:
        torch.set_num_threads(args.threads)
    load_start = os.getloadavg()
    result = measure(
        torch.device(args.device), args.steps, args.warmup, args.batch, args.crop, args.compile
    )
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
