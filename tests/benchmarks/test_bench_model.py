"""bench_model divides each precision by its own peak and says what oneDNN's ISA cap did."""

from typing import Any

import pytest
import torch

from benchmarks import bench_model, model_report, model_roofline
from lenspair.model import precision
from lenspair.model.evaluation.latency import tune_allocator

BF16_CPU = ("Test CPU", frozenset({"avx512_bf16", "avx512_vnni"}), "test")
"""A CPU whose bf16 is native (until ``ONEDNN_MAX_CPU_ISA`` caps it)."""


def _small_run(
    monkeypatch: pytest.MonkeyPatch, cap: str | None
) -> tuple[dict[str, Any], list[torch.dtype]]:
    """``bench_model.run`` on a 54x36 frame with fixed peaks; returns it and the peaks' dtypes."""
    monkeypatch.setattr(precision, "read_cpu_flags", lambda *args: BF16_CPU)
    for variable in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA"):
        monkeypatch.delenv(variable, raising=False)
    if cap is not None:
        monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", cap)
    monkeypatch.setattr(bench_model, "HEIGHT", 36)
    monkeypatch.setattr(bench_model, "WIDTH", 54)
    measured: list[torch.dtype] = []

    def peaks(runs: int, clock: object, dtype: torch.dtype = torch.float32) -> dict[str, float]:
        measured.append(dtype)
        scale = 4.0 if dtype == torch.bfloat16 else 1.0  # bf16 kernels several times faster
        return {"mm_gflops": 50.0 * scale, "conv1x1_gflops": 80.0 * scale,
                "conv3x3_gflops": 100.0 * scale}  # fmt: skip

    monkeypatch.setattr(bench_model, "measure_peaks", peaks)
    tune_allocator()  # as another benchmark in this process would: no default-malloc phase
    threads = torch.get_num_threads()
    record = bench_model.run(1, 0, threads, profile_runs=0, deraindrop_runs=0)
    return record, measured


def test_bf16_rows_are_divided_by_the_bf16_peak_where_bf16_is_native(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # bf16 times divided by the fp32 roofline gave ratios of 0.58 and 0.95, below the roofline
    record, measured = _small_run(monkeypatch, None)
    assert torch.bfloat16 in measured
    flops, medians, ratios = record["flops"], record["medians_ms"], record["roofline_ratios"]
    for name, ms in medians.items():
        peak = 400.0 if name.startswith("bf16") else 100.0
        assert ratios[name] == pytest.approx(ms / (flops / peak / 1e6))
    assert record["emulated"] == [] and record["onednn_max_cpu_isa"] is None
    # tuned before the run (another benchmark in this process): default malloc not measured
    assert record["allocator_tuned_before_run"] and record["default_allocator_medians_ms"] == {}
    table = model_report.model_table(record)
    assert "- bf16 peak" in table and "(emulated)" not in table


def test_under_an_isa_cap_bf16_is_marked_emulated_and_has_no_roofline(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a run under ONEDNN_MAX_CPU_ISA=AVX2 recorded no cap and listed bf16 rows like native ones
    record, measured = _small_run(monkeypatch, "AVX2")
    assert torch.bfloat16 not in measured  # an emulated "peak" is no peak
    assert record["onednn_max_cpu_isa"] == "AVX2"
    assert record["isa_cap"] == "ONEDNN_MAX_CPU_ISA=AVX2 turns off avx512_bf16"
    assert "ONEDNN_MAX_CPU_ISA=AVX2" in record["precision"]["reason"]
    bf16 = sorted(name for name in record["medians_ms"] if name.startswith("bf16"))
    assert record["emulated"] == bf16
    assert all(record["roofline_ratios"][name] is None for name in bf16)
    assert all(record["single_thread_roofline_ratios"][name] is None for name in bf16)
    assert record["roofline_ratios"]["fp32 NCHW"] is not None
    table = model_report.model_table(record)
    assert "- oneDNN ISA cap: ONEDNN_MAX_CPU_ISA=AVX2 (turns off avx512_bf16)" not in table
    assert "- oneDNN ISA cap: ONEDNN_MAX_CPU_ISA=AVX2 (ONEDNN_MAX_CPU_ISA=AVX2 turns off" in table
    row = next(line for line in table.splitlines() if line.startswith("| bf16 weights NCHW"))
    cells = [cell.strip() for cell in row.split("|")]
    assert "(emulated)" in cells[1] and cells[4] == "" and cells[7] == ""


def test_roofline_ratios_never_use_another_precisions_peak() -> None:
    medians = {"fp32 NCHW": 200.0, "bf16 weights NCHW": 100.0, "bf16 autocast NCHW": 50.0}
    ratios = model_roofline.roofline_ratios(medians, 20e9, {"fp32": 100.0, "bf16": None})
    assert ratios == {"fp32 NCHW": 1.0, "bf16 weights NCHW": None, "bf16 autocast NCHW": None}
    ratios = model_roofline.roofline_ratios(medians, 20e9, {"fp32": 100.0, "bf16": 400.0})
    assert ratios["bf16 autocast NCHW"] == pytest.approx(1.0)
