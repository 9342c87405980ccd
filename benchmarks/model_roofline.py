"""What :mod:`benchmarks.bench_model` derives from its timings: rooflines and targets.

The roofline of a precision is the network's FLOPs over the best GEMM-like
peak measured at that precision in the same run; each configuration is
divided by the roofline of its own precision (:func:`roofline_ratios`), never
another's. :func:`roofline_fields`, :func:`best_fields` and
:func:`single_thread_fields` build those parts of the benchmark's JSON record:
the peaks and ratios, the fastest configurations against
:data:`ROOFLINE_TARGET` and :data:`LATENCY_TARGET_BF16_MS`, and the same
against the one-thread peaks. Pure arithmetic: nothing here is timed.
"""

import torch

from lenspair.model.metrics import psnr

LATENCY_TARGET_BF16_MS = 50.0
ROOFLINE_TARGET = 1.5


def precision_of(configuration: str) -> str:
    """The precision a configuration's convolutions run at (``bf16 autocast ...``: bf16)."""
    return configuration.split()[0]


def roofline_ratios(
    medians_ms: dict[str, float], flops: float, peaks_gflops: dict[str, float | None]
) -> dict[str, float | None]:
    """Each configuration's time over the roofline of its own precision.

    Args:
        medians_ms: milliseconds per configuration.
        flops: the network's FLOPs per forward pass.
        peaks_gflops: the best measured GFLOP/s per precision (``fp32``,
            ``bf16``); ``None`` or absent where not measured.

    Returns:
        ``median / (flops / peak)`` per configuration; ``None`` where its
        precision has no peak (never another precision's).

    """
    ratios: dict[str, float | None] = {}
    for name, ms in medians_ms.items():
        peak = peaks_gflops.get(precision_of(name))
        ratios[name] = None if peak is None else ms / (flops / peak / 1e6)
    return ratios


def roofline_fields(
    peaks: dict[str, float],
    bf16_peaks: dict[str, float],
    flops: float,
    medians: dict[str, float],
) -> dict[str, object]:
    """The record's peaks, rooflines and each configuration's ratio to its own roofline.

    Args:
        peaks: fp32 GFLOP/s per kernel (``mm_gflops``, ...).
        bf16_peaks: the same in bf16; empty where bf16 is not native.
        flops: the network's FLOPs per forward pass.
        medians: milliseconds per configuration.

    """
    peak = max(peaks.values())
    bf16_peak = max(bf16_peaks.values()) if bf16_peaks else None
    return {
        "peaks_gflops": peaks,
        "peak_gflops": peak,
        "peak_kernel": max(peaks, key=peaks.__getitem__).removesuffix("_gflops"),
        "roofline_ms": flops / peak / 1e6,
        "bf16_peaks_gflops": bf16_peaks,
        "bf16_peak_gflops": bf16_peak,
        "bf16_roofline_ms": None if bf16_peak is None else flops / bf16_peak / 1e6,
        "roofline_ratios": roofline_ratios(medians, flops, {"fp32": peak, "bf16": bf16_peak}),
    }


def best_fields(
    medians: dict[str, float],
    outputs: dict[str, torch.Tensor],
    flops: float,
    peaks: dict[str, float],
) -> dict[str, object]:
    """The record's fastest fp32, eager fp32 and bf16 configurations against their targets.

    Args:
        medians: milliseconds per configuration.
        outputs: each configuration's last output, ``(1, 1, H, W)``; the
            fastest fp32 one is the reference of the bf16 PSNRs.
        flops: the network's FLOPs per forward pass.
        peaks: fp32 GFLOP/s per kernel (``mm_gflops``, ``conv1x1_gflops``, ...).

    """
    roofline_ms = flops / max(peaks.values()) / 1e6
    fp32_name = min((n for n in medians if n.startswith("fp32")), key=medians.__getitem__)
    bf16_name = min((n for n in medians if n.startswith("bf16")), key=medians.__getitem__)
    eager_name = min(
        (n for n in medians if n.startswith("fp32") and "compiled" not in n),
        key=medians.__getitem__,
    )
    gemm_peak = max(peaks["mm_gflops"], peaks["conv1x1_gflops"])
    reference = outputs[fp32_name].float()
    bf16_psnr = {
        name: float(psnr(outputs[name].float(), reference)[0])
        for name in medians
        if name.startswith("bf16")
    }
    return {
        "fp32_best": fp32_name,
        "fp32_ms": medians[fp32_name],
        "fp32_roofline_ratio": medians[fp32_name] / roofline_ms,
        "fp32_ratio_to_mm_roofline": medians[fp32_name] * peaks["mm_gflops"] * 1e6 / flops,
        "gemm_peak_gflops": gemm_peak,
        "fp32_ratio_to_gemm_roofline": medians[fp32_name] * gemm_peak * 1e6 / flops,
        "fp32_eager_best": eager_name,
        "fp32_eager_ms": medians[eager_name],
        "fp32_eager_roofline_ratio": medians[eager_name] / roofline_ms,
        "fp32_eager_ratio_to_gemm_roofline": medians[eager_name] * gemm_peak * 1e6 / flops,
        "bf16_best": bf16_name,
        "bf16_ms": medians[bf16_name],
        "bf16_psnr_vs_fp32_db": bf16_psnr,
        "bf16_target_ms": LATENCY_TARGET_BF16_MS,
        "roofline_target": ROOFLINE_TARGET,
        "fp32_target_met": medians[fp32_name] / roofline_ms <= ROOFLINE_TARGET,
        "bf16_target_met": medians[bf16_name] < LATENCY_TARGET_BF16_MS,
    }


def single_thread_fields(
    single_peaks: dict[str, float],
    single_bf16_peaks: dict[str, float],
    single_ms: dict[str, float],
    flops: float,
    fp32_name: str,
) -> dict[str, object]:
    """The record's one-thread CPU times against the one-thread peaks.

    Args:
        single_peaks: one-thread fp32 GFLOP/s per kernel (CPU time).
        single_bf16_peaks: the same in bf16; empty where bf16 is not native.
        single_ms: one-thread CPU milliseconds per configuration.
        flops: the network's FLOPs per forward pass.
        fp32_name: the fastest fp32 configuration (by wall-clock median).

    """
    single_peak = max(single_peaks.values())
    single_bf16_peak = max(single_bf16_peaks.values()) if single_bf16_peaks else None
    single_roofline_ms = flops / single_peak / 1e6
    return {
        "single_thread_peak_gflops": single_peak,
        "single_thread_roofline_ms": single_roofline_ms,
        "single_thread_bf16_peak_gflops": single_bf16_peak,
        "single_thread_cpu_ms": single_ms,
        "single_thread_roofline_ratios": roofline_ratios(
            single_ms, flops, {"fp32": single_peak, "bf16": single_bf16_peak}
        ),
        "single_thread_fp32_roofline_ratio": single_ms[fp32_name] / single_roofline_ms,
    }
