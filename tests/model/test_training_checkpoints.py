"""Checkpoints within an epoch: a run killed mid-epoch resumes from its latest step."""

from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import torch

from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.model.checkpoint import load_checkpoint
from lenspair.model.training import validation
from lenspair.model.training.config import RunConfig
from lenspair.model.training.datasets import paired_training_data
from lenspair.model.training.loop import fit, resolve_config
from lenspair.model.training.run_files import read_metrics_rows
from lenspair.model.training.step import Trainer
from tests.file_limits import run_with_file_limit
from tests.model.train_fixtures import tiny_config, write_split_dataset

pytestmark = pytest.mark.usefixtures("one_thread")
CPU = torch.device("cpu")


def _train(dataset: Path, run: Path, config: RunConfig, resume: bool = False) -> None:
    data = paired_training_data(dataset, config.data, config.model.channels, config.train.seed)
    fit(resolve_config(config, data.channels), data.train, data.val, run, CPU, resume=resume)


def _weights(run: Path) -> dict[str, torch.Tensor]:
    return dict(load_checkpoint(run / "checkpoints" / "last.pt")["model"])


@pytest.mark.parametrize("lr_decay", [0.0, 0.5])
def test_kill_in_the_first_epoch_resumes_from_the_latest_step(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, lr_decay: float
) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8, "val": 2})  # 4 steps per epoch
    config = tiny_config(
        epochs=2, deterministic=True, seed=5, checkpoint_every_steps=1, lr_decay=lr_decay
    )
    _train(dataset, tmp_path / "straight", config)

    real = Trainer.train_step
    calls = []

    def killed_at_third_step(self: Trainer, batch: object) -> object:
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt  # stands in for kill -9: nothing after this runs
        return real(self, batch)  # type: ignore[arg-type]

    monkeypatch.setattr(Trainer, "train_step", killed_at_third_step)
    with pytest.raises(KeyboardInterrupt):
        _train(dataset, tmp_path / "split", config)
    monkeypatch.setattr(Trainer, "train_step", real)
    saved = load_checkpoint(tmp_path / "split" / "checkpoints" / "last.pt")
    assert (saved["epoch"], saved["step"], saved["step_in_epoch"]) == (0, 2, 2)

    _train(dataset, tmp_path / "split", config, resume=True)
    straight, split = _weights(tmp_path / "straight"), _weights(tmp_path / "split")
    assert straight.keys() == split.keys()
    for key in straight:
        assert torch.equal(straight[key], split[key]), key


def test_default_interval_is_in_time_and_the_cli_sets_steps_or_time(tmp_path: Path) -> None:
    defaults = tiny_config().train
    assert defaults.checkpoint_every_steps is None
    assert defaults.checkpoint_every_seconds is not None and defaults.checkpoint_every_seconds > 0
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})
    config_file = tmp_path / "tiny.yaml"
    config_file.write_text(dump_yaml(tiny_config(max_steps=1)))
    for every, expected in (("3", (3, None)), ("2m", (None, 120.0))):
        run = tmp_path / f"run{every}"
        argv = ["train", str(dataset), "--out", str(run), "--config", str(config_file),
                "--device", "cpu", "--checkpoint-every", every]  # fmt: skip
        assert main(argv) == 0
        stored = load_checkpoint(run / "checkpoints" / "last.pt")["config"]["train"]
        assert (stored["checkpoint_every_steps"], stored["checkpoint_every_seconds"]) == expected


def test_resume_before_the_first_checkpoint_starts_over(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})
    config = replace(tiny_config(max_steps=2), model=replace(tiny_config().model, channels=1))
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(dump_yaml(config))  # what a kill before step 1 leaves
    leftover = run / "checkpoints" / f".last.pt.{2**22 + 7}.abcd1234.pt.tmp"
    leftover.parent.mkdir()
    leftover.write_bytes(b"half a checkpoint")
    assert main(["train", str(dataset), "--out", str(run), "--resume", "--device", "cpu"]) == 0
    assert load_checkpoint(run / "checkpoints" / "last.pt")["step"] == 2
    assert not leftover.exists()
    code = main(["train", str(dataset), "--out", str(tmp_path / "none"), "--resume"])
    assert code == 2 and "holds no run to resume" in capsys.readouterr().err


def test_kill_between_an_epochs_metrics_row_and_its_checkpoint_writes_the_row_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # With a checkpoint every step, last.pt of the epoch's last step is written
    # before that epoch's validation row; a kill after the row, before the
    # validation's last.pt, resumes from that checkpoint (found by the fault tests).
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8, "val": 2})  # 4 steps per epoch
    config = tiny_config(epochs=2, deterministic=True, seed=5, checkpoint_every_steps=1)
    _train(dataset, tmp_path / "straight", config)

    real = validation.save_checkpoint

    def killed_after_the_row(path: Path, *args: object, **kwargs: object) -> None:
        if path.name == "last.pt":
            raise KeyboardInterrupt  # stands in for kill -9 right after metrics.csv
        real(path, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(validation, "save_checkpoint", killed_after_the_row)
    with pytest.raises(KeyboardInterrupt):
        _train(dataset, tmp_path / "split", config)
    monkeypatch.setattr(validation, "save_checkpoint", real)
    metrics = tmp_path / "split" / "metrics.csv"
    assert len(read_metrics_rows(metrics)) == 1  # the row is out, last.pt is not
    saved = load_checkpoint(tmp_path / "split" / "checkpoints" / "last.pt")
    assert (saved["epoch"], saved["step"], saved["step_in_epoch"]) == (0, 4, 4)

    _train(dataset, tmp_path / "split", config, resume=True)
    straight = read_metrics_rows(tmp_path / "straight" / "metrics.csv")
    split = read_metrics_rows(metrics)
    assert [(r["epoch"], r["step"]) for r in split] == [("1", "4"), ("2", "8")]
    for row in (*straight, *split):
        row.pop("seconds")
    assert split == straight


def test_a_checkpoint_the_disk_cannot_hold_is_one_line_naming_it(tmp_path: Path) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})
    config_file = tmp_path / "tiny.yaml"
    config_file.write_text(dump_yaml(tiny_config(max_steps=1)))
    run = tmp_path / "run"
    argv = ["train", str(dataset), "--out", str(run), "--config", str(config_file)]
    failed = run_with_file_limit([*argv, "--device", "cpu"], limit=20_000)  # a checkpoint is more
    assert failed.returncode == 1, failed.stderr
    line = failed.stderr.strip().splitlines()[-1]  # after the log; torch.save's was a traceback
    assert "Traceback" not in failed.stderr
    assert line.startswith("lenspair train: error: ") and line.endswith(".pt: File too large")
    assert not list((run / "checkpoints").glob("*.pt"))  # nothing half-written under its name


def test_last_pt_follows_every_epoch_between_validations(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8, "val": 2})  # 4 steps per epoch
    config = tiny_config(epochs=3, val_every=2, checkpoint_every_seconds=None)
    real = Trainer.train_step
    calls = []

    def killed_in_the_second_epoch(self: Trainer, batch: object) -> object:
        calls.append(1)
        if len(calls) == 6:
            raise KeyboardInterrupt
        return real(self, batch)  # type: ignore[arg-type]

    monkeypatch.setattr(Trainer, "train_step", killed_in_the_second_epoch)
    with pytest.raises(KeyboardInterrupt):
        _train(dataset, tmp_path / "run", config)
    saved = load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")
    assert (saved["epoch"], saved["step"], saved["step_in_epoch"]) == (1, 4, 0)
    assert read_metrics_rows(tmp_path / "run" / "metrics.csv") == []  # no validation yet


def test_a_kill_between_best_pt_and_last_pt_leaves_no_best_pt_the_run_does_not_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # best.pt is written before last.pt: a kill between the two left the killed run's best.pt,
    # which the resumed run (here at another rate: other weights) kept as its best network
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})  # 2 steps per epoch
    config = resolve_config(tiny_config(epochs=2, deterministic=True, seed=5), 1)
    data = paired_training_data(dataset, config.data, 1, config.train.seed)
    psnrs = iter([20.0, 25.0, 18.0])  # epochs 1 and 2, then epoch 2 of the resumed run
    real_validate, real_save = validation.validate, validation.save_checkpoint

    def scripted(*args: Any, **kwargs: Any) -> tuple[float, float, Any]:
        _, ssim, sheet = real_validate(*args, **kwargs)
        return next(psnrs), ssim, sheet

    saved: list[str] = []

    def killed_before_the_second_last_pt(path: Path, *args: Any, **kwargs: Any) -> None:
        saved.append(path.name)
        if saved.count("last.pt") == 2:
            raise KeyboardInterrupt  # stands in for kill -9 right after best.pt
        real_save(path, *args, **kwargs)

    monkeypatch.setattr(validation, "validate", scripted)
    monkeypatch.setattr(validation, "save_checkpoint", killed_before_the_second_last_pt)
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        fit(config, data.train, data.val, run, CPU)
    assert saved == ["best.pt", "last.pt", "best.pt", "last.pt"]
    monkeypatch.setattr(validation, "save_checkpoint", real_save)
    slower = replace(config, train=replace(config.train, lr=config.train.lr / 2))
    with caplog.at_level("WARNING"):
        summary = fit(slower, data.train, data.val, run, CPU, resume=True)
    best = load_checkpoint(run / "checkpoints" / "best.pt")
    last = load_checkpoint(run / "checkpoints" / "last.pt")
    assert (best["best_metric"], best["best_epoch"]) == (last["best_metric"], last["best_epoch"])
    assert (summary.best_psnr, summary.best_epoch) == (18.0, 2)  # the killed 25 dB is gone
    assert all(torch.equal(best["model"][name], value) for name, value in last["model"].items())
    assert any("holds a validation that last.pt does not record" in m for m in caplog.messages)
