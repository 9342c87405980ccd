"""Inference latency as deployed: batch 1, full frame, after warm-up, median of many runs.

Used by ``lenspair eval``, ``lenspair tradeoff`` and the benchmarks, so that
every number quoted in the project is measured the same way: one image of
the data's size (540x360 by default), ``torch.inference_mode``, a few
warm-up runs (allocator, kernel selection), then ``runs`` timed runs; the
median and the 90th percentile are reported with the thread count and the
precision. CUDA timings synchronise the device around each run.

On the CPU the network runs as it should be deployed there:

* channels-last (NHWC) tensors, which oneDNN's convolutions prefer (compare
  the two layouts with ``python -m benchmarks.bench_model``; the timed copy of
  the network is converted, the caller's network is left as it was);
* with glibc's allocator told to keep freed blocks (:func:`tune_allocator`).
  By default glibc hands the large activation tensors back to the kernel on
  free and page-faults them in again on the next forward pass (the benchmark
  reports both allocator settings); jemalloc/tcmalloc (what Intel recommends
  for PyTorch on CPU) behave like the tuned setting. This is a process-wide
  setting and stays on.
"""

import contextlib
import copy
import ctypes
import functools
import statistics
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from lenspair.model.errors import ModelError

Precision = Literal["fp32", "bf16", "fp16", "int8"]
DEFAULT_SIZE = (360, 540)
"""(H, W) of the deployed camera crop, 540x360."""

_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}
MMAP_THRESHOLD = 32 * 1024 * 1024
"""Blocks below this size come from the heap, not fresh ``mmap`` calls."""


@functools.cache
def tune_allocator() -> bool:
    """Keep freed activations in the heap (glibc ``mallopt``); False where unavailable.

    Raises the mmap threshold to :data:`MMAP_THRESHOLD` and disables trimming,
    for the whole process, once.
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3
        ok_mmap = libc.mallopt(m_mmap_threshold, MMAP_THRESHOLD)
        ok_trim = libc.mallopt(m_trim_threshold, 2**30)
    except (OSError, AttributeError):
        return False
    return bool(ok_mmap and ok_trim)


@dataclass(frozen=True)
class Latency:
    """Timing of one network at one size, precision and device.

    Attributes:
        device: ``cpu`` or ``cuda`` (plus the GPU name for CUDA).
        precision: ``fp32``, ``bf16`` or ``fp16`` (autocast).
        size: ``WxH`` of the input.
        threads: ``torch.get_num_threads()`` during the runs (CPU).
        layout: ``channels-last`` or ``NCHW``.
        runs: timed runs after ``warmup`` untimed ones.
        warmup: untimed runs before timing.
        median_ms: median wall time of one forward pass, milliseconds.
        p90_ms: 90th percentile, milliseconds.
        batch: images per forward pass (1 as deployed on a robot; more for
            throughput, ``batch * 1000 / median_ms`` images/s).

    """

    device: str
    precision: str
    size: str
    threads: int
    layout: str
    runs: int
    warmup: int
    median_ms: float
    p90_ms: float
    batch: int = 1

    @property
    def images_per_second(self) -> float:
        """Throughput at this batch: images per second at the median time."""
        return self.batch * 1000.0 / self.median_ms

    def as_dict(self) -> dict[str, Any]:
        """Plain data for JSON."""
        return asdict(self)

    def summary(self) -> str:
        """One line for people: ``cpu fp32 540x360: 12.3 ms median (p90 13.1), 2 threads``."""
        batch = "" if self.batch == 1 else f" batch {self.batch}"
        return (
            f"{self.device} {self.precision} {self.size}{batch}: {self.median_ms:.2f} ms median "
            f"(p90 {self.p90_ms:.2f}, {self.runs} runs, {self.threads} threads, {self.layout})"
        )


def autocast_context(
    device: torch.device, precision: str
) -> contextlib.AbstractContextManager[Any]:
    """Autocast for ``bf16``/``fp16`` on ``device``; a no-op for ``fp32``.

    Raises:
        ModelError: fp16 requested on the CPU, or an unknown precision.

    """
    if precision in ("fp32", "int8"):  # an int8 network is quantised itself (ONNX Runtime)
        return contextlib.nullcontext()
    if precision not in _DTYPES:
        raise ModelError(f"unknown precision {precision!r}; valid: fp32, bf16, fp16, int8")
    if precision == "fp16" and device.type != "cuda":
        raise ModelError("fp16 inference is measured on CUDA only; use bf16 on the CPU")
    return torch.autocast(device_type=device.type, dtype=_DTYPES[precision])


@contextlib.contextmanager
def _threads(count: int | None) -> Iterator[int]:
    before = torch.get_num_threads()
    if count is not None:
        torch.set_num_threads(count)
    try:
        yield torch.get_num_threads()
    finally:
        torch.set_num_threads(before)


def measure_latency(
    network: nn.Module,
    channels: int,
    device: torch.device,
    size: tuple[int, int] = DEFAULT_SIZE,
    precision: str = "fp32",
    warmup: int = 5,
    runs: int = 30,
    threads: int | None = None,
    batch: int = 1,
) -> Latency:
    """Time ``network(x)`` for one ``(batch, channels, H, W)`` input on ``device``.

    The network is left on ``device`` and in eval mode. On the CPU a
    channels-last copy of it is timed, with the allocator tuned (module
    docstring).

    Args:
        network: the restoration network (any module taking one NCHW tensor).
        channels: input channels (1 or 3).
        device: where to run it.
        size: ``(H, W)`` of the input.
        precision: ``fp32``, ``bf16`` (autocast) or ``fp16`` (autocast, CUDA only).
        warmup: untimed runs first.
        runs: timed runs.
        threads: CPU threads to use (``None``: torch's current setting).
        batch: images per forward pass (1: latency as deployed; more: throughput).

    Returns:
        Median and 90th-percentile milliseconds, with the settings used.

    """
    if runs < 1 or warmup < 0 or batch < 1:
        raise ModelError(
            f"latency: need runs >= 1, warmup >= 0 and batch >= 1, got {runs}, {warmup}, {batch}"
        )
    network.to(device).eval()
    height, width = size
    generator = torch.Generator().manual_seed(0)
    image = torch.rand(batch, channels, height, width, generator=generator).to(device)
    cuda = device.type == "cuda"
    layout = "NCHW"
    if precision == "int8":  # an Int8Network: ONNX Runtime takes NCHW
        layout = "NCHW (onnxruntime)"
    elif device.type == "cpu":
        tune_allocator()
        network = copy.deepcopy(network).to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        image = image.contiguous(memory_format=torch.channels_last)
        layout = "channels-last"
    times: list[float] = []
    with _threads(threads) as used, torch.inference_mode(), autocast_context(device, precision):
        for index in range(warmup + runs):
            if cuda:
                torch.cuda.synchronize(device)
            start = time.perf_counter()
            network(image)
            if cuda:
                torch.cuda.synchronize(device)
            if index >= warmup:
                times.append((time.perf_counter() - start) * 1000.0)
    name = f"cuda ({torch.cuda.get_device_name(device)})" if cuda else "cpu"
    return Latency(
        device=name,
        precision=precision,
        size=f"{width}x{height}",
        threads=used,
        layout=layout,
        runs=runs,
        warmup=warmup,
        median_ms=statistics.median(times),
        p90_ms=float(np.percentile(times, 90.0)),
        batch=batch,
    )
