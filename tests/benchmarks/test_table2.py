"""benchmarks.table2 builds the demo's dataset with the split it is asked for."""

from pathlib import Path

import pytest

from benchmarks import table2
from lenspair.demo_stages import Stage


@pytest.mark.parametrize(("splits", "expected"), [(None, "0.7,0.15,0.15"), ("0.6,0.15,0.25", None)])
def test_dataset_stages_stop_at_dataset_build_with_the_splits_asked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, splits: str | None, expected: str | None
) -> None:
    ran: list[Stage] = []
    monkeypatch.setattr(table2, "run_stages", lambda out, stages, cli: ran.extend(stages))
    dataset = table2._dataset(tmp_path, frames=24, splits=splits)
    assert ran[-1].name == "dataset-build" and dataset == ran[-1].output
    argv = ran[-1].argv
    assert argv[argv.index("--splits") + 1] == (expected or splits)
    assert "segment_frames: 2" in (tmp_path / "demo" / "dataset_config.yaml").read_text()


def test_training_time_is_read_from_the_runs_themselves(tmp_path: Path) -> None:
    # a rerun that scored reused runs said "0.9 min wall clock in all" for an hour of training
    from lenspair.model.training.run_files import write_metrics_rows

    rows = [
        {"epoch": "1", "step": "10", "seconds": "12.5"},
        {"epoch": "2", "step": "20", "seconds": "30.0"},
    ]
    (tmp_path / "run").mkdir()
    write_metrics_rows(tmp_path / "run" / "metrics.csv", rows)  # type: ignore[arg-type]
    assert table2._training_seconds(tmp_path / "run") == 30.0
    assert table2._training_seconds(tmp_path / "never_trained") == 0.0


def test_data_only_builds_the_dataset_and_trains_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # `make tradeoff-seeds` trains on Table 2's dataset without Table 2's hour of training
    ran: list[Stage] = []
    monkeypatch.setattr(table2, "run_stages", lambda out, stages, cli: ran.extend(stages))
    monkeypatch.setattr(table2, "_parallel", lambda *args: pytest.fail("trained"))
    argv = ["--out", str(tmp_path), "--frames", "24", "--splits", "0.6,0.15,0.25", "--data-only"]
    assert table2.main(argv) == 0
    assert capsys.readouterr().out.strip() == str(ran[-1].output)
    assert ran[-1].name == "dataset-build"


def _run_folder(
    run: Path, steps: int, seed: int, data: Path, drops: str | None, finished: bool = True
) -> None:
    """A run folder as `lenspair train` leaves it: config.yaml, best.pt, last.pt if it finished.

    Trained at crop 64, batch 2, early stopping off, as table2 asks without --config.
    """
    import dataclasses

    from lenspair.core.config import dump_yaml
    from lenspair.model.checkpoint import save_checkpoint
    from lenspair.model.training.config import (
        DataConfig,
        ModelConfig,
        RunConfig,
        RuntimeInfo,
        TrainConfig,
    )
    from lenspair.model.training.run_state import RunState

    data_config = DataConfig(crop_size=64)
    config = RunConfig(
        model=ModelConfig(channels=1),
        data=data_config if drops is None else dataclasses.replace(data_config, drops=drops),
        train=TrainConfig(max_steps=steps, batch_size=2, seed=seed, epochs=1000000, patience=0),
        runtime=RuntimeInfo(data_path=str(data.resolve())),
    )
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.yaml").write_text(dump_yaml(config))
    state = RunState(step=steps if finished else 0, epoch=0, best_epoch=1).payload()
    save_checkpoint(run / "checkpoints" / "best.pt", state, config)  # after a first validation
    if finished:
        save_checkpoint(run / "checkpoints" / "last.pt", state, config)


def _table2_out(
    out: Path, monkeypatch: pytest.MonkeyPatch, finetuned: bool = True, killed: str = ""
) -> list[list[str]]:
    """``out`` holding a finished 1-step Table 2 (seed 0); returns the commands trained later."""
    import subprocess
    from types import SimpleNamespace

    import numpy as np

    dataset = out / "demo" / "dataset"
    natural = out / "natural" / "train"
    dataset.mkdir(parents=True)
    natural.mkdir(parents=True)
    for preset in ("ours", "sharp"):
        name = f"pretrain-{preset}"
        _run_folder(out / name, 1, 0, natural, preset, finished=name != killed)
    for init in table2.INITS if finetuned else ():
        _run_folder(out / f"finetune-{init}-seed0", 1, 0, dataset, None)
    monkeypatch.setattr(table2, "_dataset", lambda *args: dataset)
    pair = SimpleNamespace(input=np.zeros((4, 4), np.float32))
    monkeypatch.setattr(table2, "open_eval_pairs", lambda *args: [pair])
    monkeypatch.setattr(table2, "_score", lambda *args: (20.0, 0.8, 18.0, 0.7))
    trained: list[list[str]] = []

    def train(command: list[str], check: bool = False) -> subprocess.CompletedProcess[str]:
        trained.append(command)
        return subprocess.CompletedProcess(command, 0)

    monkeypatch.setattr(subprocess, "run", train)
    return trained


def _argv(out: Path, steps: int, crop: int, batch: int) -> list[str]:
    budget = ["--pretrain-steps", str(steps), "--finetune-steps", str(steps)]
    return ["--out", str(out), "--seeds", "0", *budget, "--crop-size", str(crop),
            "--batch-size", str(batch)]  # fmt: skip


def test_a_rerun_reuses_finished_runs_of_the_same_configuration(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    trained = _table2_out(tmp_path, monkeypatch)
    assert table2.main(_argv(tmp_path, 1, 64, 2)) == 0
    assert trained == []
    assert "pretraining 1 steps" in (tmp_path / "table2.md").read_text()


def test_a_rerun_with_another_budget_is_refused_before_anything_trains(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # reused the 1-step runs, and the table said 500 steps, crop 96, batch 3
    trained = _table2_out(tmp_path, monkeypatch)
    with pytest.raises(SystemExit) as refused:
        table2.main(_argv(tmp_path, 500, 96, 3))
    message = str(refused.value)
    assert "pretrain-ours was trained with another configuration" in message
    assert "train.max_steps: 1 -> 500" in message and "data.crop_size: 64 -> 96" in message
    assert "train.batch_size: 2 -> 3" in message and "choose another --out" in message
    assert trained == [] and not (tmp_path / "table2.md").exists()


def test_a_killed_run_is_trained_again_not_reused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # best.pt exists from the first validation on: a killed run counted as finished
    trained = _table2_out(tmp_path, monkeypatch, finetuned=False, killed="pretrain-ours")
    assert table2.main(_argv(tmp_path, 1, 64, 2)) == 0
    outs = [command[command.index("--out") + 1] for command in trained]
    assert outs[0] == str(tmp_path / "pretrain-ours")  # pretrain-sharp finished: reused
    assert "--resume" in trained[0] and "--init" not in trained[0]
    assert sorted(Path(out).name for out in outs[1:]) == [
        f"finetune-{init}-seed0" for init in sorted(table2.INITS)
    ]
    assert f"table2: {tmp_path / 'pretrain-ours'} did not finish" in capsys.readouterr().out


def test_fine_tuned_runs_of_an_unfinished_pretraining_are_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    trained = _table2_out(tmp_path, monkeypatch, killed="pretrain-ours")
    with pytest.raises(SystemExit, match="finetune-ours-seed0 was fine-tuned from"):
        table2.main(_argv(tmp_path, 1, 64, 2))
    assert trained == []


def test_runs_of_a_moved_out_folder_are_still_its_own(tmp_path: Path) -> None:
    out = tmp_path / "moved"
    data = out / "demo" / "dataset"
    assert table2._same_data(Path("/elsewhere/out/demo/dataset"), data, out)
    assert not table2._same_data(Path("/data/raindrop"), data, out)  # --dataset before
    assert table2._same_data(Path("/data/raindrop"), Path("/data/raindrop"), out)


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        # one run trained, scored twice: a spread of 0, and every difference claimed
        (["--seeds", "0", "0"], "--seeds: each seed once, got 0 0"),
        # ThreadPoolExecutor's traceback, after the demo dataset was built
        (["--jobs", "0"], "--jobs: "),
        (["--batch-size", "0"], "--batch-size: "),
    ],
)
def test_arguments_that_cannot_make_a_table_are_refused_before_any_work(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    said: str,
) -> None:
    monkeypatch.setattr(table2, "run_stages", lambda *args: pytest.fail("built a dataset"))
    with pytest.raises(SystemExit) as stopped:
        table2.main(["--out", str(tmp_path), *argv])
    assert stopped.value.code == 2 and said in capsys.readouterr().err
