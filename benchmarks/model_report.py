"""The Markdown report of :mod:`benchmarks.bench_model`'s record.

:func:`model_table` turns the JSON record of :func:`benchmarks.bench_model.run`
into what ``python -m benchmarks.bench_model`` prints: the machine's measured
peaks and rooflines, one row per timed configuration (median, minimum, ratio
to the roofline of its own precision, default-allocator and one-thread
times, bf16 PSNR against fp32), the best configurations against their
targets, the DeRaindrop comparison and the per-layer profile
(:func:`benchmarks.model_profile.profile_table`). Everything it shows is read
from the record.
"""

from typing import Any

from benchmarks.model_profile import profile_table


def _ratio(value: float | None) -> str:
    return "" if value is None else f"{value:.2f}"


def _peak_lines(record: dict[str, Any]) -> list[str]:
    """The title, FLOPs, peaks and rooflines, allocator and ISA cap lines."""
    height, width = record["size"]
    peaks = record["peaks_gflops"]
    roofline = float(record["roofline_ms"])
    single_roofline = float(record["single_thread_roofline_ms"])
    threads = record["threads"]
    cap = record["onednn_max_cpu_isa"]
    lines = [
        f"GEA, mono {width}x{height}, batch 1, {threads} threads, {record['runs']} runs "
        f"(median; bf16: {record['bf16_runs']}), torch {record['torch']}",
        "",
        f"- FLOPs: {record['gflops']:.2f} G (2 per MAC); parameters: {record['parameters']:,}",
        f"- fp32 peak ({threads} threads, GFLOP/s): "
        + ", ".join(f"{k.removesuffix('_gflops')} {v:.0f}" for k, v in peaks.items())
        + f"; roofline = FLOPs / best ({record['peak_kernel']}) = {roofline:.1f} ms",
    ]
    if record["bf16_peaks_gflops"]:
        lines.append(
            f"- bf16 peak ({threads} threads, GFLOP/s): "
            + ", ".join(
                f"{k.removesuffix('_gflops')} {v:.0f}"
                for k, v in record["bf16_peaks_gflops"].items()
            )
            + f"; bf16 roofline {record['bf16_roofline_ms']:.1f} ms: bf16 rows are divided by it"
        )
    else:
        lines.append(
            "- no bf16 peak: bf16 is not native here, so bf16 rows have no roofline "
            "(x roofline left empty; the fp32 peak is not theirs)"
        )
    lines += [
        f"- one thread, CPU time: peak {record['single_thread_peak_gflops']:.0f} GFLOP/s, "
        f"roofline {single_roofline:.1f} ms"
        + (
            f"; bf16 peak {record['single_thread_bf16_peak_gflops']:.0f} GFLOP/s"
            if record["single_thread_bf16_peak_gflops"]
            else ""
        ),
        f"- allocator tuned (mallopt): {record['allocator_tuned']}"
        + (
            "; it was tuned before this run (same process), so the default allocator was "
            "not measured"
            if record["allocator_tuned_before_run"]
            else ""
        ),
        "- oneDNN ISA cap: "
        + (f"ONEDNN_MAX_CPU_ISA={cap}" if cap else "none (the CPU as it is)")
        + (f" ({record['isa_cap']})" if record["isa_cap"] else ""),
    ]
    return lines


def _configuration_rows(record: dict[str, Any]) -> list[str]:
    """The table of timed configurations, one row each, with its header."""
    minima = record["min_ms"]
    default = record["default_allocator_medians_ms"]
    single = record["single_thread_cpu_ms"]
    psnrs = record["bf16_psnr_vs_fp32_db"]
    ratios = record["roofline_ratios"]
    single_ratios = record["single_thread_roofline_ratios"]
    emulated = set(record["emulated"])
    lines = [
        "| configuration | median ms | min ms | x roofline | default malloc ms "
        "| 1-thread CPU ms | x 1-thread roofline | PSNR vs fp32 (dB) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, value in record["medians_ms"].items():
        mark = " (best)" if name in (record["fp32_best"], record["bf16_best"]) else ""
        mark += " (emulated)" if name in emulated else ""
        quality = f"{psnrs[name]:.1f}" if name in psnrs else "reference" if mark else ""
        malloc = f"{default[name]:.1f}" if name in default else ""
        lines.append(
            f"| {name}{mark} | {value:.1f} | {minima[name]:.1f} | {_ratio(ratios[name])} "
            f"| {malloc} | {single[name]:.1f} | {_ratio(single_ratios[name])} | {quality} |"
        )
    return lines


def _summary_lines(record: dict[str, Any]) -> list[str]:
    """The best configurations against their targets, native precisions and load."""
    roofline_target = record["roofline_target"]
    bf16_target_ms = record["bf16_target_ms"]
    fp32_met = "met" if record["fp32_target_met"] else "MISSED"
    bf16_met = "met" if record["bf16_target_met"] else "MISSED"
    bf16_emulated = " (emulated)" if record["bf16_best"] in set(record["emulated"]) else ""
    return [
        f"- fp32 best: {record['fp32_best']}, {record['fp32_ms']:.1f} ms = "
        f"{record['fp32_roofline_ratio']:.2f}x roofline (target <= {roofline_target}x: "
        f"{fp32_met}); {record['fp32_ratio_to_gemm_roofline']:.2f}x the plain-GEMM "
        f"(mm, conv1x1) roofline; {record['fp32_ratio_to_mm_roofline']:.2f}x the torch.mm "
        f"roofline; one thread: {record['single_thread_fp32_roofline_ratio']:.2f}x",
        f"- fp32 eager best: {record['fp32_eager_best']}, {record['fp32_eager_ms']:.1f} ms = "
        f"{record['fp32_eager_roofline_ratio']:.2f}x roofline, "
        f"{record['fp32_eager_ratio_to_gemm_roofline']:.2f}x the plain-GEMM roofline",
        f"- bf16 best: {record['bf16_best']}{bf16_emulated}, {record['bf16_ms']:.1f} ms "
        f"(target < {bf16_target_ms:.0f} ms: {bf16_met})",
        f"- precisions native on this CPU ({record['cpu_model']}): "
        f"{', '.join(record['precision']['native'])}; auto picks "
        f"{record['precision']['precision']} ({record['precision']['reason']})",
        f"- load average start/end: {record['load_average_start']} / "
        f"{record['load_average_end']}; CPU pressure start: {record['cpu_pressure_start']}",
    ]


def model_table(data: dict[str, object]) -> str:
    """The Markdown report of a :func:`benchmarks.bench_model.run` record."""
    record: dict[str, Any] = data
    lines = [*_peak_lines(record), "", *_configuration_rows(record), "", *_summary_lines(record)]
    deraindrop = record["deraindrop_720x480_rgb"]
    if isinstance(deraindrop, dict) and deraindrop:
        lines.append(
            f"- 720x480 RGB, fp32, same run: GEA {deraindrop['gea_ms']:.0f} ms, DeRaindrop's "
            f"generator ({deraindrop['deraindrop_parameters'] / 1e6:.2f} M parameters) "
            f"{deraindrop['deraindrop_ms']:.0f} ms: GEA is {deraindrop['speedup']:.1f}x faster "
            "(the paper: 8x)"
        )
    profile = record["layer_profile_fp32"]
    if isinstance(profile, list) and profile:
        lines += ["", f"Where the fp32 time goes ({record['fp32_best']}):", ""]
        lines.append(profile_table(profile))
    return "\n".join(lines)
