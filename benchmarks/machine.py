"""What the machine can do, measured in the benchmark's own run.

The peaks the network benchmarks divide by (:func:`peaks`, fp32 or bf16),
the round-robin timer that spreads other processes' load over all
configurations alike (:func:`round_robin`), a network and its input set up
as lenspair deploys them on the CPU (:func:`as_deployed`), and the CPU
pressure line recorded at the start and end of a run.
"""

import copy
import statistics
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import torch
import torch.nn.functional as F

from lenspair.model.inference.backends import deploy

Clock = Callable[[], float]
Network = TypeVar("Network", bound=torch.nn.Module)


def as_deployed(network: Network, image: torch.Tensor) -> tuple[Network, torch.Tensor]:
    """A channels-last copy of ``network`` and ``image``, with the allocator tuned.

    What :func:`lenspair.model.evaluation.latency.measure_latency` times on the
    CPU (and ``eval``, ``tradeoff`` and ``restore`` run): oneDNN's preferred
    layout, and glibc told to keep freed activations. The tuning is
    process-wide and stays on, so a benchmark that times "as deployed" does it
    before anything it times; ``network`` itself is left as it was (the copy
    goes through :func:`lenspair.model.inference.backends.deploy`).
    """
    deployed = copy.deepcopy(network)
    deploy(deployed, torch.device("cpu"))  # what restore and eval run: in place, on the copy
    return deployed, image.contiguous(memory_format=torch.channels_last)


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


def peaks(runs: int, clock: Clock, dtype: torch.dtype = torch.float32) -> dict[str, float]:
    """Median GFLOP/s of three GEMM-like kernels at ``dtype`` (fp32 or bf16).

    ``torch.mm`` 2048^3 (MKL for fp32), a 1x1 convolution 512->512 on 64x64 (a
    plain 4096x512x512 GEMM in oneDNN) and a 3x3 convolution 256->256 on 64x64
    (an implicit 4096x256x2304 GEMM in oneDNN, the kernel family the network
    uses). A network's time at one precision is divided by the peak of the
    same precision only: bf16 kernels run up to several times faster than
    fp32 ones where bf16 is native.
    """
    generator = torch.Generator().manual_seed(0)
    n = 2048
    a = torch.randn(n, n, generator=generator).to(dtype)
    b = torch.randn(n, n, generator=generator).to(dtype)
    cl = torch.channels_last
    side = 64
    x1 = torch.randn(1, 512, side, side, generator=generator).to(dtype).contiguous(memory_format=cl)
    w1 = torch.randn(512, 512, 1, 1, generator=generator).to(dtype).contiguous(memory_format=cl)
    x3 = torch.randn(1, 256, side, side, generator=generator).to(dtype).contiguous(memory_format=cl)
    w3 = torch.randn(256, 256, 3, 3, generator=generator).to(dtype).contiguous(memory_format=cl)
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


BUSY_PRESSURE = 20.0
"""CPU pressure (``some avg10``, per cent) from which a benchmark is said to start on a busy CPU.

Other processes inflate the network's many short layers far more than the
long peak kernels it is divided by (a run at load 8 read fp32 GEA at 2.6x its
roofline and int8 13x faster than fp32; quiet, 1.5x and 0.8x), so a ratio to
a peak of the same run does not cancel them.
"""


def pressure_avg10(line: str) -> float | None:
    """``some avg10`` of a :func:`cpu_pressure` line, per cent; None when it has none."""
    for field in line.split():
        if field.startswith("avg10="):
            try:
                return float(field.removeprefix("avg10="))
            except ValueError:
                return None
    return None
