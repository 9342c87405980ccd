"""Where the restoration network's time goes, and how it compares with DeRaindrop.

Two helpers of :mod:`benchmarks.bench_model`:

* :func:`layer_profile`: ``torch.profiler`` over a few forward passes,
  grouped by operator *and input shape* (so the full-resolution 7x7
  convolution, the residual blocks' 3x3 convolutions and the instance norms
  are separate rows), sorted by self CPU time, with each row's share;
* :func:`deraindrop_comparison`: GEA and DeRaindrop's generator
  (:mod:`benchmarks.deraindrop`) at 720x480 RGB, batch 1, fp32,
  channels-last, timed round-robin in the same run: the speed ratio the
  paper reports (8x on its CPU).
"""

import statistics
import time
from collections.abc import Callable

import torch

from benchmarks.deraindrop import DeRaindropGenerator
from lenspair.model.networks.variants import build_model

RAINDROP_SIZE = (480, 720)
"""(H, W) of the Raindrop dataset's images."""


def layer_profile(
    call: Callable[[], object], runs: int = 3, top: int = 12
) -> list[dict[str, object]]:
    """The ``top`` operator/shape rows by self CPU time over ``runs`` calls of ``call``.

    Returns:
        Rows ``{"op", "shapes", "calls_per_run", "self_ms_per_run", "share"}``;
        ``share`` is the fraction of all self CPU time.

    """
    from torch.profiler import ProfilerActivity, profile

    call()  # warm-up outside the profile
    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
        for _ in range(runs):
            call()
    events = prof.key_averages(group_by_input_shape=True)
    total = sum(e.self_cpu_time_total for e in events) or 1.0
    ordered = sorted(events, key=lambda e: e.self_cpu_time_total, reverse=True)[:top]
    return [
        {
            "op": e.key,
            "shapes": str([s for s in e.input_shapes if s][:2]),
            "calls_per_run": e.count / runs,
            "self_ms_per_run": e.self_cpu_time_total / runs / 1e3,
            "share": e.self_cpu_time_total / total,
        }
        for e in ordered
    ]


def profile_table(rows: list[dict[str, object]]) -> str:
    """The profile as Markdown."""
    lines = [
        "| op | input shapes | calls/run | self ms/run | share |",
        "|---|---|---:|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {row['op']} | {row['shapes']} | {float(row['calls_per_run']):.0f} | "  # type: ignore[arg-type]
            f"{float(row['self_ms_per_run']):.1f} | {float(row['share']):.0%} |"  # type: ignore[arg-type]
        )
    return "\n".join(lines)


def deraindrop_comparison(runs: int = 3) -> dict[str, float]:
    """Median fp32 ms of GEA (RGB) and DeRaindrop at 720x480, batch 1, same run.

    Both channels-last under ``torch.inference_mode``, one warm-up each,
    timed round-robin so that load from other processes hits both alike.
    """
    torch.manual_seed(0)
    cl = torch.channels_last
    gea = build_model("GEA", 3).eval().to(memory_format=cl)  # type: ignore[call-overload]
    deraindrop = DeRaindropGenerator().eval().to(memory_format=cl)  # type: ignore[call-overload]
    image = torch.rand(1, 3, *RAINDROP_SIZE, generator=torch.Generator().manual_seed(0))
    image = image.contiguous(memory_format=cl)
    calls = {"gea": lambda: gea.restore(image), "deraindrop": lambda: deraindrop(image)}
    times: dict[str, list[float]] = {name: [] for name in calls}
    with torch.inference_mode():
        for call in calls.values():
            call()
        for _ in range(runs):
            for name, call in calls.items():
                start = time.perf_counter()
                call()
                times[name].append((time.perf_counter() - start) * 1e3)
    gea_ms = statistics.median(times["gea"])
    deraindrop_ms = statistics.median(times["deraindrop"])
    return {
        "gea_ms": gea_ms,
        "deraindrop_ms": deraindrop_ms,
        "speedup": deraindrop_ms / gea_ms,
        "deraindrop_parameters": float(sum(p.numel() for p in deraindrop.parameters())),
        "runs": float(runs),
    }
