"""The shipped weights' card: a rescore keeps the training record; the card says what it holds."""

import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio

from benchmarks import model_card, pretrain_weights
from lenspair.core.imageio import read_image
from lenspair.model.checkpoint import WEIGHTS_DIR, WEIGHTS_FILES
from tests.model.train_fixtures import write_split_dataset


def _entry(**overrides: Any) -> dict[str, Any]:
    entry: dict[str, Any] = {
        "file": "gea_ours_mono.pt",
        "bytes": 1_434_199,
        "budget_steps": 1500,
        "steps": 1500,
        "epochs": 375,
        "stop_reason": "step budget of 1500 reached",
        "training_seconds": 900.0,
        "training_load_average": 2.1,
        "cpu_count": 2,
        "precision": "bf16 autocast",
        "precision_reason": "auto: fastest native precision on X (cpu) (CPU flag avx512_bf16)",
        "seed": 0,
        "best_epoch": 300,
        "pairs": 4,
        "input_psnr": 20.0,
        "output_psnr": 22.5,
        "input_ssim": 0.8,
        "output_ssim": 0.85,
        "cpu_ms_median": 123.4,
        "cpu_ms_p90": 130.0,
    }
    return entry | overrides


def test_card_states_budget_gain_and_machine_load_from_the_card() -> None:
    idle = model_card.card_markdown({"mono": _entry(), "rgb": _entry(output_psnr=19.0)})
    assert "| step budget (a cap; batch 8, 128 px crops) | 1500 | 1500 |" in idle
    assert "| stopped because | step budget of 1500 reached | step budget of 1500 reached |" in idle
    assert "mono: 1500 steps, +2.50 dB" in idle and "RGB: 1500 steps, -1.00 dB" in idle
    assert "a 2-core CPU (load average at the end of training: mono 2.1, RGB 2.1)" in idle
    assert "pretrain_weights --channels 1 3 --steps 1500`" in idle
    mixed = model_card.card_markdown({"mono": _entry(), "rgb": _entry(budget_steps=800)})
    assert "--channels 1 --steps 1500` and `" in mixed and "--channels 3 --steps 800`" in mixed
    assert "demo's test split" not in idle  # no demo_test scores: no table claiming them
    busy = model_card.card_markdown({"mono": _entry(training_load_average=9.0)})
    assert "(load average at the end of training: mono 9.0)" in busy
    assert "| figure | mono |" in busy and "RGB" not in busy.split("| figure |")[1].split("\n")[0]


def test_card_shows_the_demo_test_scores_when_present() -> None:
    demo = {"dataset": "demo_out/dataset", "pairs": 10, "size": "540x360", "input_psnr": 25.6}
    demo |= {"output_psnr": 24.1, "input_ssim": 0.9, "output_ssim": 0.88, "cpu_ms_median": 71.9}
    text = model_card.card_markdown({"mono": _entry(demo_test=demo)})
    assert "On the demo's test split" in text.replace("on the demo", "On the demo")
    assert "| output PSNR (dB) | 24.10 |" in text and "| test pairs | 10 |" in text


def test_rescore_keeps_the_training_record_and_scores_the_dataset(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(pretrain_weights, "LATENCY_RUNS", 3)  # timing is not under test here
    weights = tmp_path / "weights"
    weights.mkdir()
    for name in WEIGHTS_FILES.values():
        shutil.copy(WEIGHTS_DIR / name, weights / name)
    record = {"steps": 77, "budget_steps": 77, "learning_curve": [[4, 20.0]]}
    (weights / "card.json").write_text(json.dumps({"mono": record}))
    dataset = write_split_dataset(tmp_path / "ds", {"train": 1, "val": 1, "test": 3})
    argv = ["--rescore", "--channels", "1", "3", "--weights", str(weights)]
    assert (
        pretrain_weights.main([*argv, "--runs", str(tmp_path / "runs"), "--dataset", str(dataset)])
        == 0
    )

    card = json.loads((weights / "card.json").read_text())
    mono = card["mono"]
    assert mono["steps"] == 77 and mono["learning_curve"] == [[4, 20.0]]
    assert mono["pairs"] == 6 and mono["cpu_ms_median"] > 0  # 3 held-out images x 2 draws
    assert mono["clear_frames"] == 3 and mono["clear_psnr"] > 20  # each once through clear glass
    expected = np.mean(
        [
            peak_signal_noise_ratio(
                read_image(target), read_image(target.parent.parent / "input" / target.name)
            )
            for target in sorted((dataset / "test" / "target").glob("*.png"))
        ]
    )
    demo = mono["demo_test"]
    assert demo["pairs"] == 3 and math.isclose(demo["input_psnr"], expected, abs_tol=1e-3)
    assert "demo_test" not in card["rgb"]  # a mono dataset does not score the RGB weights
