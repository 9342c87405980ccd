"""What a resume may change, and what it refuses before it writes anything.

The perceptual loss switched on or off, another drops preset, a budget the
run is already past: each is refused in one line, and the run folder is left
as it was. A resume at another precision is said in words that are true.
"""

from pathlib import Path

import pytest
import torch
import yaml

from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.model.checkpoint import load_checkpoint
from lenspair.model.networks.vgg import VGG19_WEIGHTS_ENV, VGG19Features
from tests.model.train_fixtures import tiny_config, write_split_dataset

pytestmark = pytest.mark.usefixtures("one_thread")


def _argv(tmp_path: Path, run: str = "run") -> tuple[list[str], Path]:
    """``lenspair train`` of a tiny network on 4 training pairs (2 steps an epoch)."""
    dataset = tmp_path / "ds"
    if not dataset.exists():
        write_split_dataset(dataset, {"train": 4, "val": 1})
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(epochs=10)))
    out = tmp_path / run
    argv = ["train", str(dataset), "--out", str(out), "--config", str(config), "--device", "cpu"]
    return argv, out


def _files(run: Path) -> dict[Path, bytes]:
    """Every file of a run folder and its bytes."""
    return {p: p.read_bytes() for p in sorted(run.rglob("*")) if p.is_file()}


def _refusal(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one line of a command that must exit with 2."""
    capsys.readouterr()
    assert main(argv) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert error.startswith("lenspair train: error: --resume: ")
    return error


def test_a_resume_that_switches_the_perceptual_loss_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # Resumed without the weights, a run trained on without the term, said by the
    # generic warning alone; config.yaml said it never had it, and the epoch's loss
    # means divided the first session's perceptual sums by steps that had no term.
    weights = tmp_path / "vgg19.pth"
    torch.save(VGG19Features().state_dict(), weights)
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, str(weights))
    argv, run = _argv(tmp_path, "with")
    assert main([*argv, "--max-steps", "1"]) == 0
    kept = _files(run)
    monkeypatch.delenv(VGG19_WEIGHTS_ENV)
    error = _refusal([*argv, "--resume", "--max-steps", "2"], capsys)
    assert f"trained with the perceptual loss enabled ({weights})" in error
    assert "here it is disabled" in error and f"--init {run}" in error
    assert VGG19_WEIGHTS_ENV in error and _files(run) == kept
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, str(weights))  # with them, it resumes
    assert main([*argv, "--resume", "--max-steps", "2"]) == 0
    assert load_checkpoint(run / "checkpoints" / "last.pt")["step"] == 2

    # the other way: a run without the loss is not resumed with it
    monkeypatch.delenv(VGG19_WEIGHTS_ENV)
    argv, run = _argv(tmp_path, "without")
    assert main([*argv, "--max-steps", "1"]) == 0
    kept = _files(run)
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, str(weights))
    error = _refusal([*argv, "--resume", "--max-steps", "2"], capsys)
    assert "trained with the perceptual loss disabled" in error
    assert f"here it is enabled ({weights})" in error and "resume it without" in error
    assert _files(run) == kept


def test_a_resume_on_other_synthetic_drops_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    # --drops sharp only warned: best.pt then compared PSNRs on two validation sets
    argv, run = _argv(tmp_path)
    synthetic = ["train", "--synthetic", str(tmp_path / "ds" / "train" / "target"), *argv[2:]]
    assert main([*synthetic, "--max-steps", "1"]) == 0
    kept = _files(run)
    caplog.clear()
    error = _refusal([*synthetic, "--resume", "--max-steps", "2", "--drops", "sharp"], capsys)
    assert "trained on synthetic ours drops" in error and "on synthetic sharp drops" in error
    assert "resume with --drops ours" in error and f"--init {run}" in error
    assert _files(run) == kept
    # the new budget never applied: it is not said as a change before the refusal
    assert not any("changed config" in m for m in caplog.messages), caplog.messages


def test_a_plain_resume_says_what_config_yaml_said_but_never_trained(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # a --resume --config session stopped before its first checkpoint had written its
    # settings into config.yaml; the next plain --resume went on with last.pt's, unsaid
    argv, run = _argv(tmp_path)
    assert main([*argv, "--max-steps", "2"]) == 0
    caplog.clear()
    assert main([*argv, "--resume", "--max-steps", "4"]) == 0  # a resume that ran: no word
    assert not any("never reached a checkpoint" in m for m in caplog.messages)
    said = yaml.safe_load((run / "config.yaml").read_text())
    trained_lr = said["train"]["lr"]
    said["train"]["lr"] = trained_lr / 10  # as the stopped session wrote it
    (run / "config.yaml").write_text(yaml.safe_dump(said))
    caplog.clear()
    assert main(["train", *argv[1:4], "--device", "cpu", "--resume", "--max-steps", "6"]) == 0
    warned = [m for m in caplog.messages if "never reached a checkpoint" in m]
    assert len(warned) == 1 and f"train.lr: {trained_lr!r} -> {trained_lr / 10!r}" in warned[0]
    assert yaml.safe_load((run / "config.yaml").read_text())["train"]["lr"] == trained_lr


def test_a_resume_past_its_budget_is_refused_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --max-steps 2 at step 6 said "step budget of 2 reached; 0 epochs, 6 steps" and left
    # config.yaml at max_steps: 2 beside a last.pt at step 6
    argv, run = _argv(tmp_path)
    assert main([*argv, "--max-steps", "6"]) == 0  # 3 epochs of 2 steps
    kept = _files(run)
    resumed = [*argv, "--resume"]
    error = _refusal([*resumed, "--max-steps", "2"], capsys)
    assert "is already at step 6, past train.max_steps 2 (--max-steps)" in error
    error = _refusal([*resumed, "--epochs", "2"], capsys)
    assert "is already 3 epochs done, past train.epochs 2 (--epochs)" in error
    error = _refusal([*resumed, "--max-seconds", "0.001"], capsys)
    assert "s of training, past train.max_seconds 0.001 (--max-seconds)" in error
    assert _files(run) == kept
    # the budget it stopped at is no contradiction: nothing trains, and it says so
    assert main([*resumed, "--max-steps", "6"]) == 0
    assert "step budget of 6 reached; 3 epochs, 6 steps" in capsys.readouterr().out


def test_the_precision_warning_names_the_steps_trained_at_the_earlier_precision(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # after bf16 (steps 1-2) and fp32 (3-4) it said "the first 4 steps trained at fp32"
    argv, _ = _argv(tmp_path)
    assert main([*argv, "--precision", "bf16", "--max-steps", "2"]) == 0
    resumed = [*argv, "--resume"]
    assert main([*resumed, "--precision", "fp32", "--max-steps", "4"]) == 0
    assert "resuming at fp32; the first 2 steps trained at bf16 autocast" in caplog.messages
    assert main([*resumed, "--precision", "bf16", "--max-steps", "6"]) == 0
    assert "resuming at bf16 autocast; steps 3 to 4 trained at fp32" in caplog.messages
