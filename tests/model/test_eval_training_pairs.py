"""eval on the pairs a checkpoint trained on: said once, counted in metrics.json, still scored."""

import json
import logging
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.model.evaluation.evaluate import evaluate_checkpoint
from lenspair.model.evaluation.report import write_report
from lenspair.model.training.config import RuntimeInfo
from lenspair.model.training.datasets import paired_training_data
from lenspair.model.training.holdout import holdout_indices
from tests.model.train_fixtures import (
    make_checkpoint,
    tiny_config,
    write_paired_folder,
    write_split_dataset,
)

CPU = torch.device("cpu")
SAID = "trained on"

pytestmark = pytest.mark.usefixtures("one_thread")


def _trained_on(tmp_path: Path, data_path: Path, name: str = "net.pt") -> Path:
    """A checkpoint whose run recorded ``data_path`` as its data (as fit records it)."""
    config = replace(tiny_config(), runtime=RuntimeInfo(data_path=str(data_path.resolve())))
    return Path(make_checkpoint(tmp_path / name, config))


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno == logging.WARNING and SAID in r.getMessage()
    ]


def test_a_paired_folder_it_trained_on_is_scored_whole_and_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """All twelve pairs were scored, ten of them trained on, without a word."""
    folder = write_paired_folder(tmp_path / "pairs", count=12)
    training = paired_training_data(folder, tiny_config().data, 1, 0, notes=[])
    trained = len(training.train)  # type: ignore[arg-type]
    assert 0 < trained < 12
    checkpoint = _trained_on(tmp_path, folder)
    with caplog.at_level(logging.WARNING):
        result = evaluate_checkpoint(checkpoint, folder, "test", CPU, latency_runs=0)
    assert len(result.scores) == 12  # which pairs are scored does not change
    assert result.trained_on_scored == trained
    (said,) = _warnings(caplog)
    assert f"{checkpoint} trained on {trained} of the 12 scored pairs of {folder}" in said
    files = write_report(result, tmp_path / "out")
    assert json.loads(files["json"].read_text())["trained_on_scored_pairs"] == trained
    # and the Markdown report says it too: it read as a plain accuracy
    assert f"trained on {trained} of the 12 scored pairs**" in files["markdown"].read_text()


def test_pairs_trained_on_before_a_resume_on_other_data_count_too(tmp_path: Path) -> None:
    # trained on pairs/ for 3 steps, resumed on copy/: eval on pairs/ said 0 pairs
    folder = write_paired_folder(tmp_path / "pairs", count=12)
    copy = write_paired_folder(tmp_path / "copy", count=12)
    runtime = RuntimeInfo(
        data_path=str(copy.resolve()), earlier_data=(f"{folder.resolve()} until step 3",)
    )
    checkpoint = make_checkpoint(tmp_path / "net.pt", replace(tiny_config(), runtime=runtime))
    training = paired_training_data(folder, tiny_config().data, 1, 0, notes=[])
    result = evaluate_checkpoint(checkpoint, folder, "test", CPU, latency_runs=0)
    assert result.trained_on_scored == len(training.train)  # type: ignore[arg-type]
    other = write_paired_folder(tmp_path / "other", count=12)
    assert (
        evaluate_checkpoint(checkpoint, other, "test", CPU, latency_runs=0).trained_on_scored == 0
    )


def test_a_datasets_train_split_counts_and_its_other_splits_do_not(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    dataset = write_split_dataset(tmp_path / "ds")  # train 6, val 2, test 3
    checkpoint = _trained_on(tmp_path, dataset)
    with caplog.at_level(logging.WARNING):
        train = evaluate_checkpoint(checkpoint, dataset, "train", CPU, latency_runs=0)
        assert _warnings(caplog) and train.trained_on_scored == 6  # validated on val
        caplog.clear()
        for split in ("test", "val"):
            other = evaluate_checkpoint(checkpoint, dataset, split, CPU, latency_runs=0)
            assert other.trained_on_scored == 0, split
        split_folder = evaluate_checkpoint(checkpoint, dataset / "train", "x", CPU, latency_runs=0)
    assert split_folder.trained_on_scored == 6  # the split's own folder is the same pairs
    assert len(_warnings(caplog)) == 1
    assert other.as_dict()["trained_on_scored_pairs"] == 0


def test_a_train_split_without_validation_counts_all_but_its_held_out_pairs(
    tmp_path: Path,
) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 12, "test": 2})
    training = paired_training_data(dataset, tiny_config().data, 1, 0, notes=[])
    checkpoint = _trained_on(tmp_path, dataset)
    result = evaluate_checkpoint(checkpoint, dataset, "train", CPU, latency_runs=0)
    assert result.trained_on_scored == len(training.train) < 12  # type: ignore[arg-type]


def test_other_data_an_unknown_one_and_unread_pairs(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = write_paired_folder(tmp_path / "pairs", count=12)
    copy = write_paired_folder(tmp_path / "copy", count=12)
    with caplog.at_level(logging.WARNING):
        elsewhere = evaluate_checkpoint(
            _trained_on(tmp_path, copy), folder, "test", CPU, latency_runs=0
        )
        unknown = evaluate_checkpoint(  # a run written before data_path was recorded
            make_checkpoint(tmp_path / "old.pt"), folder, "test", CPU, latency_runs=0
        )
    assert elsewhere.trained_on_scored == 0 and unknown.trained_on_scored is None
    assert _warnings(caplog) == []
    # a pair trained on that can no longer be read is not scored, so not counted
    checkpoint = _trained_on(tmp_path, folder)
    names = [f"{index:03d}" for index in range(12)]
    kept, _ = holdout_indices(names, tiny_config().data.val_fraction, folder)
    damaged = folder / "input" / f"{names[kept[0]]}.png"
    whole = damaged.read_bytes()
    damaged.write_bytes(whole[: whole.index(b"IDAT") + 20])
    result = evaluate_checkpoint(checkpoint, folder, "test", CPU, latency_runs=0)
    assert len(result.scores) == 11 and len(result.unread) == 1
    assert result.trained_on_scored == len(kept) - 1


def test_lenspair_eval_of_a_run_on_its_own_folder(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The reproduction: train on a paired folder, then eval its best.pt on that folder."""
    folder = write_paired_folder(tmp_path / "pairs", count=12)
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=1)))
    run = tmp_path / "run"
    train = ["train", str(folder), "--out", str(run), "--config", str(config), "--device", "cpu"]
    assert main(train) == 0
    caplog.clear()
    best = run / "checkpoints" / "best.pt"
    out = tmp_path / "eval"
    argv = ["eval", str(best), "--data", str(folder), "--out", str(out), "--device", "cpu"]
    with caplog.at_level(logging.WARNING):
        assert main([*argv, "--latency-runs", "0"]) == 0
    (said,) = _warnings(caplog)
    assert said.startswith(f"{best} trained on 10 of the 12 scored pairs of {folder}")
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["trained_on_scored_pairs"] == 10
    assert metrics["overall"]["pairs"] == 12


def test_a_copy_of_the_data_trained_on_counts_as_that_data(tmp_path: Path) -> None:
    # cp -r of the dataset: another path, the same pairs; "trained_on_scored_pairs": 0
    dataset = write_split_dataset(tmp_path / "ds")  # train 6, val 2, test 3
    recorded = paired_training_data(dataset, tiny_config().data, 1, 0, notes=[]).description
    runtime = RuntimeInfo(data_path=str(dataset.resolve()), data=recorded)
    checkpoint = make_checkpoint(tmp_path / "net.pt", replace(tiny_config(), runtime=runtime))
    copy = tmp_path / "elsewhere" / "ds_copy"
    shutil.copytree(dataset, copy)
    assert (
        evaluate_checkpoint(checkpoint, copy, "train", CPU, latency_runs=0).trained_on_scored == 6
    )
    assert evaluate_checkpoint(checkpoint, copy, "test", CPU, latency_runs=0).trained_on_scored == 0
    # the same folder with other pairs (one more training pair): not the data trained on
    write_paired_folder(tmp_path / "extra", count=1, seed=9)
    for side in ("input", "target"):
        shutil.copyfile(tmp_path / "extra" / side / "000.png", copy / "train" / side / "zz.png")
    assert (
        evaluate_checkpoint(checkpoint, copy, "train", CPU, latency_runs=0).trained_on_scored == 0
    )
