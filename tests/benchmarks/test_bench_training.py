"""The training benchmark times every native precision and the inference shapes it names."""

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from benchmarks import bench_training
from lenspair.model.precision import choose_precision
from lenspair.model.training.config import RunConfig


def test_every_native_precision_and_inference_shape_is_in_the_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    shapes = (((16, 24), 1), ((20, 28), 1), ((16, 24), 3))
    monkeypatch.setattr(bench_training, "INFERENCE_SHAPES", shapes)
    argv = ["--steps", "1", "--warmup", "0", "--batch", "2", "--crop", "32", "--threads", "1"]
    assert bench_training.main([*argv, "--out", str(tmp_path)]) == 0

    result = json.loads((tmp_path / "training.json").read_text())
    cpu = torch.device("cpu")
    trained = [p for p in choose_precision("auto", cpu, "train").native if p != "int8"]
    assert sorted(result["step_seconds_median"]) == sorted(trained)
    assert result["speed_vs_fp32"]["fp32"] == 1.0
    inferred = [p for p in choose_precision("auto", cpu, "infer").native if p != "int8"]
    timed = {(row["size"], row["batch"], row["precision"]) for row in result["inference"]}
    assert timed == {(f"{w}x{h}", n, p) for (h, w), n in shapes for p in inferred}
    table = capsys.readouterr().out
    batch3 = next(r for r in result["inference"] if r["batch"] == 3)
    assert f"24x16 batch 3 | {batch3['median_ms']:.1f} |" in table
    assert f"{3000.0 / batch3['median_ms']:.1f} |" in table  # images/s of the batch
    assert "torch.compile not timed (--compile times it)" in table
    # the fp32 step against the peak measured in the same run, as the table says it
    roofline = result["fp32_step_gflop"] / result["fp32_peak_gflops"]
    assert result["fp32_roofline_seconds"] == pytest.approx(roofline)
    ratio = result["step_seconds_median"]["fp32"] / roofline
    assert result["fp32_roofline_ratio"] == pytest.approx(ratio)
    assert f"the step takes {ratio:.2f}x its roofline" in table


def test_a_step_s_flops_grow_with_the_batch_and_count_the_backward() -> None:
    cpu = torch.device("cpu")
    batches = {n: bench_training._batch(n, 32, cpu) for n in (2, 4)}
    flops = {
        n: bench_training.step_flops(bench_training.Trainer(_tiny(n), cpu), data)
        for n, data in batches.items()
    }
    assert flops[4] == 2 * flops[2] > 0
    trainer = bench_training.Trainer(_tiny(2), cpu)
    with FlopCounterMode(display=False) as forward_only, torch.no_grad():
        trainer.network(batches[2]["input"])
    # the network's forward is a small part: D's three passes and every backward count too
    assert flops[2] > 3 * forward_only.get_total_flops()


def _tiny(batch: int) -> RunConfig:
    config = bench_training._config("fp32", batch)
    return replace(config, model=replace(config.model, width=0.25, num_blocks=1))


def test_the_table_says_what_torch_compile_s_compilation_took() -> None:
    # compile_seconds was in training.json only: the table, and the README from it, said
    # nothing of the compilation that a compiled row's speed leaves out
    result = {
        "batch": 2, "crop": 32, "device": "cpu", "threads": 1, "steps": 1,
        "step_seconds_median": {"fp32": 1.0, "fp32 + torch.compile": 0.8},
        "speed_vs_fp32": {"fp32": 1.0, "fp32 + torch.compile": 1.25},
        "precision_auto": {"reason": "auto: fp32"}, "fastest": "fp32 + torch.compile",
        "auto_is_fastest_eager": True, "auto_over_fastest_eager": 1.0, "compile_seconds": 41.6,
        "single_thread_cpu_seconds": {}, "single_thread_speed_vs_fp32": {}, "inference": [],
    }  # fmt: skip
    table = bench_training._table(result)
    assert "torch.compile's first step (compilation) took 42 s, not timed" in table


def test_auto_is_fastest_within_a_tie_and_compiled_rows_do_not_count() -> None:
    medians = {"bf16": 6.215, "fp32": 6.255, "fp32 + torch.compile": 3.0}
    # fp32 within 1 % of bf16 (one Intel run): a tie, not a wrong choice
    assert bench_training.auto_time_over_fastest(medians, "fp32") == pytest.approx(6.255 / 6.215)
    assert bench_training.auto_time_over_fastest(medians, "bf16") == 1.0  # compile left out
    slow = {"bf16": 1.51, "fp32": 3.15}  # an AMD EPYC: fp32 chosen there would be wrong
    assert bench_training.auto_time_over_fastest(slow, "fp32") > 1.0 + bench_training.TIE
