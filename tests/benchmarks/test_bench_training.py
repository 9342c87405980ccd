"""The training benchmark times every native precision and the inference shapes it names."""

import json
from pathlib import Path

import pytest
import torch

from benchmarks import bench_training
from lenspair.model.precision import choose_precision


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
