"""What the machine can do, measured in the benchmark's own run.

The fp32 peaks the network benchmarks divide by (:func:`peaks`), the
round-robin timer that spreads other processes' load over all
configurations alike (:func:`round_robin`), and the CPU pressure line
recorded at the start and end of a run.
"""

import statistics
from collections.abc import Callable
from pathlib import Path

import torch
import torch.nn.functional as F

Clock = Callable[[], float]


def round_robin(
    calls: dict[str, Callable[[], object]], runs: int, warmup: int, clock: Clock
) -> dict[str, list[float]]:
    for call in calls.values():
        for _ in range(warmup):
            call()
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(runs):
        for name, call in calls.items():
            start = clock()
            call()
            times[name].append(clock() - start)
    return times


def median_ms(samples: list[float]) -> float:
    return statistics.median(samples) * 1e3


def peaks(runs: int, clock: Clock) -> dict[str, float]:
    """Median fp32 GFLOP/s of three GEMM-like kernels.

    ``torch.mm`` 2048^3 (MKL), a 1x1 convolution 512->512 on 64x64 (a plain
    4096x512x512 GEMM in oneDNN) and a 3x3 convolution 256->256 on 64x64 (an
    implicit 4096x256x2304 GEMM in oneDNN, the kernel family the network uses).
    """
    generator = torch.Generator().manual_seed(0)
    n = 2048
    a = torch.randn(n, n, generator=generator)
    b = torch.randn(n, n, generator=generator)
    cl = torch.channels_last
    side = 64
    x1 = torch.randn(1, 512, side, side, generator=generator).contiguous(memory_format=cl)
    w1 = torch.randn(512, 512, 1, 1, generator=generator).contiguous(memory_format=cl)
    x3 = torch.randn(1, 256, side, side, generator=generator).contiguous(memory_format=cl)
    w3 = torch.randn(256, 256, 3, 3, generator=generator).contiguous(memory_format=cl)
    times = round_robin(
        {
            "mm": lambda: torch.mm(a, b),
            "conv1x1": lambda: F.conv2d(x1, w1),
            "conv3x3": lambda: F.conv2d(x3, w3, padding=1),
        },
        runs,
        3,
        clock,
    )
    flops = {
        "mm": 2 * n**3,
        "conv1x1": 2 * side * side * 512 * 512,
        "conv3x3": 2 * side * side * 256 * 256 * 9,
    }
    return {f"{name}_gflops": flops[name] / statistics.median(times[name]) / 1e9 for name in flops}


def cpu_pressure() -> str:
    """The first line of ``/proc/pressure/cpu`` (Linux PSI), or ``n/a``."""
    try:
        return Path("/proc/pressure/cpu").read_text().splitlines()[0]
    except OSError:
        return "n/a"
