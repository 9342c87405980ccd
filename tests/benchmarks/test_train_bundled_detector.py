"""The one-command retraining of the bundled detector, on a tiny budget."""

import json
from pathlib import Path

import pytest

from benchmarks.train_bundled_detector import _held_out, main


def test_the_last_two_recordings_of_each_kind_are_held_out() -> None:
    paths = [Path(f"{kind}_{k}") for kind in ("clean", "rain") for k in range(4)]
    others, held = _held_out(paths)
    assert [p.name for p in held] == ["clean_2", "clean_3", "rain_2", "rain_3"]
    assert [p.name for p in others] == ["clean_0", "clean_1", "rain_0", "rain_1"]


def test_too_few_recordings_per_kind_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        main(
            [
                "--work",
                str(tmp_path),
                "--checkpoint",
                "d.pt",
                "--markdown",
                "d.md",
                "--per-kind",
                "3",
            ]
        )


@pytest.mark.slow
def test_one_command_writes_the_checkpoint_and_the_document(tmp_path: Path) -> None:
    checkpoint, document = tmp_path / "out" / "detector.pt", tmp_path / "out" / "detector.md"
    argv = ["--work", str(tmp_path / "work"), "--checkpoint", str(checkpoint)]
    argv += ["--markdown", str(document), "--device", "cpu", "--steps", "2", "--per-kind", "4"]
    argv += ["--frames", "2", "--synthetic", "8", "--hard", "10", "--latency-runs", "0"]
    assert main(argv) == 0
    assert checkpoint.stat().st_size > 0
    text = document.read_text()
    assert "python -m benchmarks.train_bundled_detector " + " ".join(argv) in text
    assert "Training: 2 steps of 64 windows" in text and "on `cpu`" in text
    # 8 held-out recordings x 2 frames x 2 cameras; the 6 not of clean glass have 2 obstructed
    assert "**test recordings**: 32 frames (12 obstructed)" in text
    assert text.count("| smooth whole-frame dust: obstructed |") == 1
    figures = json.loads(document.with_suffix(".json").read_text())  # the README's source
    assert figures["scores"]["test recordings"]["frames"] == 32
    assert figures["scores"]["test recordings"]["positives"] == 12
    assert figures["training"]["steps"] == 2 and figures["latency"] is None
    assert figures["hard_cases"][2]["name"] == "smooth whole-frame dust: obstructed"
