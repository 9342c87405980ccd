"""How fast bf16 runs on this CPU, measured: ``fp32 time / bf16 time`` of one convolution.

A CPU flag says that bf16 instructions exist, not that they are faster than
fp32. They are on an AMD EPYC (Zen 5: a GEA training step 1.82x fp32's speed)
and with AMX. They are not on an Intel Xeon whose hypervisor hides AMX but
shows ``avx512_bf16`` (family 6 model 207, measured with ``python -m
benchmarks --only model training``, docs/results/cpu_intel_xeon.md): oneDNN's
native ``avx512_core_bf16`` kernels ran a 2048x2048 matmul at 0.53x fp32's
speed, the GEA 540x360 frame at 0.60x and a training step at 0.84x on one
thread (probably because ``vdpbf16ps`` issues on one port where fp32 FMAs
issue on two).
``auto`` (:func:`lenspair.model.precision.choose_precision`) therefore measures
before it takes bf16.

What is timed is the layer that takes most of the GEA's time (44 % of a
540x360 frame, ``bench_model``'s per-layer profile): a 64-channel 3x3
convolution, channels-last, at the aggregation modules' quarter resolution.
For inference its forward pass at batch 1; for training forward and backward
at batch 4. fp32 and bf16 autocast alternate, so a burst of load slows both;
the ratio is the median of the per-pair ratios. The whole measurement takes
well under a second and is kept for the process (per task, thread count and
oneDNN ISA cap: :func:`lenspair.model.precision.measure_bf16_speed` reads the
last two).
"""

import functools
import statistics
import time
from collections.abc import Callable
from typing import Literal

import torch
from torch import nn

Task = Literal["train", "infer"]

REPEATS = 7
"""Timed fp32/bf16 pairs (after two warm-up pairs)."""

TIMED: dict[str, str] = {
    "train": "a 64-channel 3x3 convolution, forward and backward",
    "infer": "a 64-channel 3x3 convolution",
}
"""What :func:`measured_bf16_speed` times for each task, in words (for the precision's reason)."""


def speed_ratio(
    run_reference: Callable[[], object],
    run_candidate: Callable[[], object],
    repeats: int = REPEATS,
    warmup: int = 2,
    clock: Callable[[], float] = time.perf_counter,
) -> float:
    """Median over alternating runs of ``reference time / candidate time`` (> 1: candidate faster).

    Args:
        run_reference: one run of the reference (fp32).
        run_candidate: one run of the candidate (bf16).
        repeats: timed pairs.
        warmup: untimed pairs first (oneDNN builds its kernels on the first call).
        clock: seconds (mocked in tests).

    """
    for _ in range(warmup):
        run_reference()
        run_candidate()
    ratios = []
    for _ in range(repeats):
        start = clock()
        run_reference()
        middle = clock()
        run_candidate()
        end = clock()
        ratios.append((middle - start) / max(end - middle, 1e-9))
    return statistics.median(ratios)


def _convolution_runs(task: Task) -> tuple[Callable[[], object], Callable[[], object]]:
    generator = torch.Generator().manual_seed(0)
    # the layer's initialisation draws from torch's global generator: leave its state as it
    # was, so that a run draws the same numbers whether or not auto measured here
    with torch.random.fork_rng(devices=[]):
        conv = nn.Conv2d(64, 64, 3, padding=1)
    conv.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    shape = (1, 64, 92, 136) if task == "infer" else (4, 64, 64, 64)
    x = torch.randn(shape, generator=generator).contiguous(memory_format=torch.channels_last)
    if task == "train":
        x.requires_grad_(True)

    def run(bf16: bool) -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            if task == "infer":
                with torch.inference_mode():
                    conv(x)
                return
            y = conv(x)
        y.float().square().mean().backward()

    return (lambda: run(False)), (lambda: run(True))


@functools.cache
def measured_bf16_speed(task: Task, threads: int, isa_cap: str | None) -> float:
    """bf16 autocast's speed as a multiple of fp32's on this CPU for ``task`` (kept per process).

    ``threads`` (torch's thread count) and ``isa_cap`` (oneDNN's) are what the
    timing ran under: they key the kept result.
    """
    del threads, isa_cap  # cache keys only: both change what is measured
    reference, candidate = _convolution_runs(task)
    return speed_ratio(reference, candidate)
