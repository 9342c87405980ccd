"""Budget stops and resumes: best.pt, early stopping and the samples of a resumed epoch."""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.core.config import load_yaml
from lenspair.dataset.errors import DatasetError
from lenspair.model.checkpoint import checkpoint_config, load_checkpoint
from lenspair.model.errors import ModelError
from lenspair.model.training import validation
from lenspair.model.training.config import RunConfig
from lenspair.model.training.datasets import paired_training_data
from lenspair.model.training.distributed import Distributed
from lenspair.model.training.loop import fit, resolve_config, resume_config
from lenspair.model.training.run_files import RunPaths
from lenspair.model.training.run_state import RunState
from lenspair.model.training.step import Trainer
from tests.model.train_fixtures import tiny_config, write_split_dataset

pytestmark = pytest.mark.usefixtures("one_thread")
CPU = torch.device("cpu")


def _train(dataset: Path, run: Path, config: RunConfig, resume: bool = False) -> None:
    data = paired_training_data(dataset, config.data, config.model.channels, config.train.seed)
    fit(resolve_config(config, data.channels), data.train, data.val, run, CPU, resume=resume)


def _validations(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    events: list[tuple[int, int, float]],
    val_every: int = 1,
) -> tuple[RunState, RunPaths, list[float]]:
    """Run ``validate_and_save`` at ``(epoch, step_in_epoch, psnr)``; best.pt's PSNR after each."""
    scores = iter(psnr for _, _, psnr in events)
    sheet = np.zeros((8, 8, 3), np.uint8)
    monkeypatch.setattr(validation, "validate", lambda *_, **__: (next(scores), 0.9, sheet))
    config = tiny_config()
    config = replace(config, train=replace(config.train, val_every=val_every, epochs=10))
    trainer = Trainer(config, CPU)
    paths = RunPaths(tmp_path / "run")
    state, best = RunState(), []
    for epoch, step_in_epoch, _ in events:
        state.epoch, state.step_in_epoch = epoch, step_in_epoch
        state.step = 10 * epoch + step_in_epoch
        validation.validate_and_save(trainer, config, [], paths, state, Distributed(), {}, None)
        best.append(float(load_checkpoint(paths.best)["best_metric"]) if paths.best.exists() else 0)
    return state, paths, best


def test_a_mid_epoch_validation_leaves_best_and_early_stopping_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A straight run validates after epochs 1, 2, 3; the same run stopped by a
    # budget in epoch 2 and resumed validates once more, mid-epoch (step 7).
    straight, _, _ = _validations(
        tmp_path / "a", monkeypatch, [(1, 0, 30.0), (2, 0, 30.2), (3, 0, 30.1)]
    )
    resumed, paths, best = _validations(
        tmp_path / "b", monkeypatch, [(1, 0, 30.0), (1, 7, 30.5), (2, 0, 30.2), (3, 0, 30.1)]
    )
    assert (straight.best_psnr, straight.best_epoch, straight.stale) == (30.2, 2, 1)
    assert (resumed.best_psnr, resumed.best_epoch, resumed.stale) == (30.2, 2, 1)
    assert best == [30.0, 30.0, 30.2, 30.2]  # the mid-epoch 30.5 never reached best.pt
    assert load_checkpoint(paths.best)["step"] == 20
    assert load_checkpoint(paths.last)["step"] == 30


def test_an_end_of_epoch_validation_off_the_val_every_schedule_is_not_counted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # val_every 2: a straight run validates after epochs 2 and 4; stopped by a budget
    # at the end of epoch 3 and resumed, the run validates there too
    caplog.set_level("INFO", logger="lenspair.model.training.validation")
    straight, _, _ = _validations(tmp_path / "a", monkeypatch, [(2, 0, 30.0), (4, 0, 29.9)], 2)
    resumed, paths, best = _validations(
        tmp_path / "b", monkeypatch, [(2, 0, 30.0), (3, 0, 30.5), (4, 0, 29.9)], 2
    )
    assert (straight.best_psnr, straight.best_epoch, straight.stale) == (30.0, 2, 1)
    assert (resumed.best_psnr, resumed.best_epoch, resumed.stale) == (30.0, 2, 1)
    assert best == [30.0, 30.0, 30.0] and load_checkpoint(paths.best)["step"] == 20
    lines = [r.getMessage() for r in caplog.records if "epoch 3 " in r.getMessage()]
    assert len(lines) == 1 and "off the val_every schedule: not counted" in lines[0]


def test_a_run_with_no_best_yet_takes_best_pt_from_a_mid_epoch_validation(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level("INFO", logger="lenspair.model.training.validation")
    state, paths, best = _validations(tmp_path, monkeypatch, [(0, 3, 25.0), (0, 5, 26.0)])
    # the log names the epoch under way as the progress bar does ("epoch 1"), not "epoch 0"
    lines = [r.getMessage() for r in caplog.records if "validation PSNR" in r.getMessage()]
    assert [line.split(":")[0] for line in lines] == ["epoch 1 step 3", "epoch 1 step 5"]
    assert all(line.endswith("at epoch 1") for line in lines)
    assert best == [25.0, 25.0]  # the first gives the run a best.pt; later ones do not count
    # in epoch 1 (counting from 1, as end-of-epoch bests do): 0 stays "no best yet"
    assert (state.best_psnr, state.best_epoch, state.stale) == (25.0, 1, 0)
    assert load_checkpoint(paths.best)["step"] == 3


def test_a_budget_stop_in_the_first_epoch_leaves_a_best_checkpoint(tmp_path: Path) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8, "val": 1})  # 4 steps per epoch
    _train(dataset, tmp_path / "run", tiny_config(max_steps=1))
    best = load_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")
    assert (best["epoch"], best["step"], best["step_in_epoch"]) == (0, 1, 1)
    assert math.isfinite(float(best["best_metric"]))


def _stopped_mid_epoch(tmp_path: Path) -> tuple[Path, Path, RunConfig]:
    """A run of 8 pairs at batch 4 stopped at step 1 of its first epoch's 2."""
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8, "val": 1})
    run = tmp_path / "run"
    first = tiny_config(batch_size=4, epochs=2, max_steps=1)
    _train(dataset, run, first)
    return dataset, run, first


def test_resuming_mid_epoch_at_another_batch_size_is_refused(tmp_path: Path) -> None:
    dataset, run, first = _stopped_mid_epoch(tmp_path)
    smaller = replace(first, train=replace(first.train, batch_size=2, max_steps=None))
    with pytest.raises(ModelError, match=r"last\.pt.*batch size 4.*batch size 2") as error:
        resume_config(run, smaller)
    assert "\n" not in str(error.value)
    with pytest.raises(ModelError, match=r"last\.pt.*batch size 4.*batch size 2"):
        _train(dataset, run, smaller, resume=True)  # fit itself refuses too
    same = replace(first, train=replace(first.train, max_steps=None))
    _train(dataset, run, resume_config(run, same), resume=True)
    assert load_checkpoint(run / "checkpoints" / "last.pt")["step"] == 4


def test_resuming_mid_epoch_with_another_seed_is_refused(tmp_path: Path) -> None:
    """The seed orders the epoch's pairs: it was only warned about, and pairs repeated."""
    dataset, run, first = _stopped_mid_epoch(tmp_path)
    other = replace(first, train=replace(first.train, seed=5, max_steps=None))
    with pytest.raises(ModelError, match=r"last\.pt.*with seed 0.*with seed 5"):
        _train(dataset, run, other, resume=True)


def test_resuming_at_an_epoch_boundary_may_change_the_batch_size(tmp_path: Path) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8, "val": 1})
    run = tmp_path / "run"
    first = tiny_config(batch_size=4, epochs=2, max_steps=2)  # stops at the end of epoch 1
    _train(dataset, run, first)
    smaller = replace(first, train=replace(first.train, batch_size=2, max_steps=None))
    _train(dataset, run, resume_config(run, smaller), resume=True)
    saved = load_checkpoint(run / "checkpoints" / "last.pt")
    assert (saved["epoch"], saved["step"]) == (2, 6)  # 2 steps of 4, then 4 steps of 2


def test_a_validation_pair_that_cannot_be_scored_is_left_out_not_fatal(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from lenspair.core.imagewrite import write_image
    from tests.model.train_fixtures import clean_image

    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 3})
    small = clean_image(np.random.default_rng(2), 10, 10)  # under SSIM's 11x11 window
    write_image(dataset / "val" / "input" / "001.png", small)
    write_image(dataset / "val" / "target" / "001.png", small)
    cut = dataset / "val" / "target" / "002.png"
    cut.write_bytes(cut.read_bytes()[:300])  # header whole, pixels cut: found when read
    caplog.set_level("WARNING")
    _train(dataset, tmp_path / "run", tiny_config(epochs=2))
    left_out = [r.getMessage() for r in caplog.records if "left out" in r.getMessage()]
    assert len(left_out) == 2  # once per pair, not once per validation
    assert any("001" in m and "window" in m for m in left_out)
    assert any("002.png" in m for m in left_out)
    rows = (tmp_path / "run" / "metrics.csv").read_text().splitlines()
    assert len(rows) == 3 and (tmp_path / "run" / "checkpoints" / "best.pt").is_file()
    for name in ("000", "001"):  # none can be scored: refused before training, naming them
        target = dataset / "val" / "target" / f"{name}.png"
        target.write_bytes(target.read_bytes()[:300])
    unscored = r"none of the 3 validation pair\(s\) can be scored: \S*000.png: truncated"
    with pytest.raises(DatasetError, match=unscored):  # it was after the epoch, unsaved
        _train(dataset, tmp_path / "run2", tiny_config(epochs=1))
    assert not (tmp_path / "run2").exists()
    for name in ("000", "001", "002"):  # too small, all of them: refused before training
        write_image(dataset / "val" / "input" / f"{name}.png", small)
        write_image(dataset / "val" / "target" / f"{name}.png", small)
    with pytest.raises(DatasetError, match=r"every one of the 3 validation pair\(s\) is smaller"):
        _train(dataset, tmp_path / "run3", tiny_config(epochs=1))
    assert not (tmp_path / "run3").exists()


def test_a_run_resumed_at_another_precision_keeps_what_it_trained_at_before(
    tmp_path: Path,
) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8, "val": 1})
    run = tmp_path / "run"
    first = tiny_config(batch_size=4, epochs=2, max_steps=2, amp=True, precision="bf16")
    _train(dataset, run, first)
    fp32 = replace(first, train=replace(first.train, precision="fp32", max_steps=None))
    _train(dataset, run, resume_config(run, fp32), resume=True)
    runtime = load_yaml(RunConfig, run / "config.yaml").runtime
    assert runtime is not None and runtime.precision == "fp32"
    # it said fp32 alone, though the first two steps trained at bf16
    assert runtime.earlier_precisions == ("bf16 autocast until step 2",)
    stored = checkpoint_config(load_checkpoint(run / "checkpoints" / "last.pt")).runtime
    assert stored is not None and stored.earlier_precisions == runtime.earlier_precisions


def _cli_run(tmp_path: Path, steps: int = 2) -> tuple[Path, Path, list[str]]:
    """A finished `lenspair train` run of ``steps`` steps: ``(dataset, run, its argv)``."""
    from lenspair.cli import main
    from lenspair.core.config import dump_yaml

    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})  # 2 steps per epoch
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(epochs=10)))
    run = tmp_path / "run"
    argv = ["train", str(dataset), "--out", str(run), "--config", str(config), "--device", "cpu"]
    assert main([*argv, "--max-steps", str(steps)]) == 0
    return dataset, run, argv


def test_a_refused_restart_keeps_the_runs_best_pt_and_metrics(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from lenspair.cli import main

    _, run, _ = _cli_run(tmp_path)
    (run / "checkpoints" / "last.pt").unlink()  # resume then means starting over
    kept = {p: p.read_bytes() for p in (run / "checkpoints" / "best.pt", run / "metrics.csv")}
    capsys.readouterr()
    code = main(["train", str(tmp_path / "no_such_ds"), "--out", str(run), "--resume"])
    assert code == 2 and "no_such_ds" in capsys.readouterr().err
    # they were deleted before the dataset was even looked at
    assert {p: p.read_bytes() for p in kept} == kept
    dataset = tmp_path / "ds"  # refused when the trainer is built: fp16 needs CUDA
    assert main(["train", str(dataset), "--out", str(run), "--resume", "--precision", "fp16"]) == 2
    assert "fp16" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in kept} == kept


def test_a_run_whose_last_pt_was_removed_after_it_was_saved_is_not_started_over(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path, steps=4)  # two epochs: two validations
    (run / "checkpoints" / "last.pt").unlink()
    kept = {p: p.read_bytes() for p in (run / "checkpoints" / "best.pt", run / "metrics.csv")}
    capsys.readouterr()
    assert main(["train", str(dataset), "--out", str(run), "--resume"]) == 2
    error = capsys.readouterr().err.strip()
    assert "records 2 validations" in error and "last.pt" in error and "\n" not in error
    assert {p: p.read_bytes() for p in kept} == kept
    assert not (run / "checkpoints" / "last.pt").exists()


def test_a_resume_on_a_dataset_rebuilt_in_place_says_and_records_its_pairs_changed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    import yaml

    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path)
    resumed = ["train", str(dataset), "--out", str(run), "--resume"]
    assert main([*resumed, "--max-steps", "4"]) == 0  # the same pairs: nothing said
    assert yaml.safe_load((run / "config.yaml").read_text())["runtime"]["earlier_data"] == []
    assert not any("pairs changed" in m for m in caplog.messages)
    then = yaml.safe_load((run / "config.yaml").read_text())["runtime"]["data"]
    for side in ("input", "target"):  # same folder, same counts, another pair
        (dataset / "train" / side / "000.png").rename(dataset / "train" / side / "100.png")
    assert main([*resumed, "--max-steps", "6"]) == 0
    runtime = yaml.safe_load((run / "config.yaml").read_text())["runtime"]
    assert runtime["earlier_data"] == [f"{then} until step 4"]
    assert runtime["data"] != then and runtime["data_path"] == str(dataset.resolve())
    assert any("whose pairs changed since the run's first 4 steps" in m for m in caplog.messages)


def test_a_synthetic_resume_on_other_clean_images_says_and_records_they_changed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    import shutil

    import yaml

    from lenspair.cli import main
    from lenspair.core.config import dump_yaml

    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})
    clean = tmp_path / "clean"
    shutil.copytree(dataset / "train" / "target", clean)
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(epochs=10)))
    run = tmp_path / "run"
    argv = ["train", "--synthetic", str(clean), "--out", str(run), "--config", str(config)]
    assert main([*argv, "--device", "cpu", "--max-steps", "2"]) == 0
    resumed = ["train", "--synthetic", str(clean), "--out", str(run), "--resume"]
    assert main([*resumed, "--max-steps", "4"]) == 0  # the same images: nothing said
    assert yaml.safe_load((run / "config.yaml").read_text())["runtime"]["earlier_data"] == []
    then = yaml.safe_load((run / "config.yaml").read_text())["runtime"]["data"]
    first = sorted(clean.iterdir())[0]  # same folder, same count, another image's name
    first.rename(first.with_name("zz_" + first.name))
    assert main([*resumed, "--max-steps", "6"]) == 0
    runtime = yaml.safe_load((run / "config.yaml").read_text())["runtime"]
    assert runtime["earlier_data"] == [f"{then} until step 4"]
    assert any("whose pairs changed since the run's first 4 steps" in m for m in caplog.messages)


def test_only_the_pair_digest_of_the_data_line_tells_whether_the_pairs_changed() -> None:
    from lenspair.model.training.datasets import recorded_digest as _digest

    # the counts change with data.max_val_images, allowed on a resume: not other pairs
    then = "/d (train 40 pairs, validation 9 pairs; pair names sha256 0123456789ab)"
    now = "/d (train 40 pairs, validation 5 pairs; pair names sha256 0123456789ab)"
    assert _digest(then) == _digest(now) == "0123456789ab"
    noted = "/d (train 3 pairs, validation 1 pairs; validation: 1 pairs held out by name hash; "
    assert _digest(noted + "pair names sha256 ba9876543210)") == "ba9876543210"
    assert _digest("/d (train 40 pairs, validation 9 pairs)") is None  # an older run's line


def test_a_restart_of_a_fine_tuning_starts_again_from_its_init(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    import yaml

    from lenspair.cli import main

    dataset, first, argv = _cli_run(tmp_path)
    init = first / "checkpoints" / "best.pt"
    run = tmp_path / "fine"
    fine = [*argv[:3], str(run), *argv[4:], "--max-steps", "2"]
    assert main([*fine, "--init", str(init)]) == 0
    straight = load_checkpoint(run / "checkpoints" / "best.pt")["model"]
    (run / "checkpoints" / "last.pt").unlink()  # as a kill before its first checkpoint
    assert main(["train", str(dataset), "--out", str(run), "--resume"]) == 0
    assert any("starting the run again from step 0" in m for m in caplog.messages)
    # it restarted from random weights, and config.yaml said runtime.init: null
    assert yaml.safe_load((run / "config.yaml").read_text())["runtime"]["init"] == str(init)
    again = load_checkpoint(run / "checkpoints" / "best.pt")["model"]
    assert all(torch.equal(straight[key], again[key]) for key in straight)


def test_resuming_keeps_the_init_refuses_other_kinds_of_data_and_records_other_data(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    import shutil

    import yaml

    from lenspair.cli import main

    dataset, first, argv = _cli_run(tmp_path)
    run = tmp_path / "fine"
    init = str(first / "checkpoints" / "best.pt")
    fine = [*argv[:3], str(run), *argv[4:]]
    assert main([*fine, "--init", init, "--max-steps", "2"]) == 0
    moved = tmp_path / "moved_ds"
    shutil.copytree(dataset, moved)
    assert main(["train", str(moved), "--out", str(run), "--resume", "--max-steps", "4"]) == 0
    runtime = yaml.safe_load((run / "config.yaml").read_text())["runtime"]
    assert runtime["init"] == init  # it was null after a resume
    assert runtime["data_path"] == str(moved.resolve())
    assert runtime["earlier_data"] == [f"{dataset.resolve()} until step 2"]
    assert any("the first 2 steps trained on" in m for m in caplog.messages)
    capsys.readouterr()
    synthetic = ["train", "--synthetic", str(dataset / "train" / "target"), "--out", str(run)]
    assert main([*synthetic, "--resume", "--max-steps", "6"]) == 2
    error = capsys.readouterr().err.strip()
    assert "trained on real pairs" in error and "on synthetic ours drops" in error
    assert "\n" not in error and load_checkpoint(run / "checkpoints" / "last.pt")["step"] == 4


def test_a_resume_without_best_pt_writes_it_again(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path)
    best = run / "checkpoints" / "best.pt"
    best.unlink()
    assert main(["train", str(dataset), "--out", str(run), "--resume", "--max-steps", "4"]) == 0
    assert best.is_file() and load_checkpoint(best)["step"] == 4
    assert any(f"{best} is missing" in m for m in caplog.messages)
    assert f"best checkpoint: {best}" in capsys.readouterr().out


def test_a_truncated_best_pt_is_moved_aside_on_resume(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    # it stayed in place, for eval to fail on later, and the summary said it "went missing"
    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path)
    best = run / "checkpoints" / "best.pt"
    cut = best.read_bytes()[:5000]
    best.write_bytes(cut)
    resume = ["train", str(dataset), "--out", str(run), "--resume"]
    last_step = load_checkpoint(run / "checkpoints" / "last.pt")["step"]
    assert main([*resume, "--max-steps", str(last_step)]) == 0  # no step, no validation
    aside = best.with_name("best.pt.forgotten")
    assert not best.exists() and aside.read_bytes() == cut
    assert any("cannot be read" in m and "moved to best.pt.forgotten" in m for m in caplog.messages)
    said = capsys.readouterr().out
    assert "was missing or could not be used when the run resumed" in said


@pytest.mark.parametrize("content", [b"", b"epoch,step,seconds\n"])
def test_an_emptied_metrics_csv_is_said_on_resume(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, content: bytes
) -> None:
    # a missing file was said; an empty or header-only one lost the rows without a word
    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path)
    (run / "metrics.csv").write_bytes(content)
    assert main(["train", str(dataset), "--out", str(run), "--resume", "--max-steps", "4"]) == 0
    said = [m for m in caplog.messages if "holds none of the run's rows" in m]
    assert said and "are lost" in said[0]


@pytest.mark.parametrize("content", [b"\x00\xff\xfe\x01", b"epoch,step,seconds\nx,y,z\n"])
def test_a_damaged_metrics_csv_is_one_line_on_resume(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes
) -> None:
    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path)
    (run / "metrics.csv").write_bytes(content)
    capsys.readouterr()
    assert main(["train", str(dataset), "--out", str(run), "--resume", "--max-steps", "4"]) == 2
    error = capsys.readouterr().err.strip()
    assert f"{run / 'metrics.csv'}: " in error and "move" in error and "\n" not in error


def test_an_out_whose_samples_would_be_read_as_images_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from lenspair.cli import main

    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})
    # the next run on this dataset failed: "1 unpaired file(s): input/samples.png"
    for out in (dataset / "train" / "input", dataset / "val" / "target"):
        assert main(["train", str(dataset), "--out", str(out), "--max-steps", "1"]) == 2
        error = capsys.readouterr().err
        assert f"--out {out}: a folder of the images read" in error, error
        assert not (out / "config.yaml").exists()
    photos = tmp_path / "photos"  # a plain folder: every image below it is a clean image
    photos.mkdir()
    (dataset / "train" / "target" / "000.png").rename(photos / "a.png")
    synthetic = ["train", "--synthetic", str(photos), "--out", str(photos / "runs" / "r")]
    assert main(synthetic) == 2
    assert "inside the images read from" in capsys.readouterr().err
    # elsewhere in the data's tree nothing is read: a run in DS/runs trains
    other = write_split_dataset(tmp_path / "other", {"train": 4, "val": 1})
    from lenspair.core.config import dump_yaml

    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=1)))
    run = other / "runs" / "r"
    assert main(["train", str(other), "--out", str(run), "--config", str(config)]) == 0


@pytest.mark.parametrize("restart", [False, True])
def test_a_config_given_with_resume_sets_only_its_own_keys(tmp_path: Path, restart: bool) -> None:
    # `--resume --config p.yaml` with p.yaml = {train: {patience: 3}} put crop, batch
    # and rate back to train's defaults (256, 8, 2e-4), with a warning per change
    import yaml

    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path)
    before = yaml.safe_load((run / "config.yaml").read_text())
    if restart:
        (run / "checkpoints" / "last.pt").unlink()  # a kill before the first checkpoint
    patience = tmp_path / "patience.yaml"
    patience.write_text("train: {patience: 3}\n")
    resumed = ["train", str(dataset), "--out", str(run), "--resume", "--config", str(patience)]
    assert main([*resumed, "--max-steps", "4"]) == 0
    after = yaml.safe_load((run / "config.yaml").read_text())
    assert after["train"]["patience"] == 3 != before["train"]["patience"]
    for section, key in (("data", "crop_size"), ("train", "batch_size"), ("train", "lr")):
        assert after[section][key] == before[section][key], key


def test_a_no_amp_run_resumes_at_the_precision_given(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # `--resume --precision bf16` of a run started with --no-amp was refused for
    # "train.amp: false (--no-amp)", a flag not given, with no --amp to undo it
    from lenspair.cli import main

    dataset, _, argv = _cli_run(tmp_path)
    assert main([*argv, "--no-amp", "--max-steps", "2", "--out", str(tmp_path / "na")]) == 0
    resumed = ["train", str(dataset), "--out", str(tmp_path / "na"), "--resume"]
    assert main([*resumed, "--max-steps", "4", "--precision", "bf16"]) == 0
    runtime = load_yaml(RunConfig, tmp_path / "na" / "config.yaml").runtime
    assert runtime is not None and runtime.precision == "bf16 autocast"
    assert runtime.earlier_precisions == ("fp32 until step 2",)
    capsys.readouterr()
    both = [*resumed, "--max-steps", "6", "--precision", "bf16", "--no-amp"]
    assert main(both) == 2 and "give one of them" in capsys.readouterr().err
    # and the mirror: --no-amp alone lifts the stored bf16 (it was refused for a
    # --precision not given)
    assert main([*resumed, "--max-steps", "6", "--no-amp"]) == 0
    runtime = load_yaml(RunConfig, tmp_path / "na" / "config.yaml").runtime
    assert runtime is not None and runtime.precision == "fp32"
    assert runtime.earlier_precisions == ("fp32 until step 2", "bf16 autocast until step 4")


def test_a_checkpoint_s_progress_comes_back_whole() -> None:
    # early stopping's count and the time spent must survive a resume: with either
    # reset, a run resumed again and again never stopped early or ran past max_seconds
    from lenspair.model.training.run_state import RunState

    state = RunState(
        epoch=4, step=130, step_in_epoch=7, best_psnr=27.5, best_epoch=3, stale=2,
        seconds=812.25, loss_sums={"loss_g": 3.5, "loss_d": 1.25}, loss_steps=7,
    )  # fmt: skip
    assert RunState.from_checkpoint(state.payload()) == state


def test_betas_changed_on_resume_are_the_ones_trained_with(tmp_path: Path) -> None:
    # the checkpoint's optimiser state brought back its betas: config.yaml said 0.9, the
    # optimiser kept 0.5
    import dataclasses

    from lenspair.cli import main
    from lenspair.core.config import dump_yaml

    dataset, run, _ = _cli_run(tmp_path)
    config = tiny_config(epochs=10)
    changed = tmp_path / "betas.yaml"
    changed.write_text(
        dump_yaml(
            dataclasses.replace(
                config, train=dataclasses.replace(config.train, beta1=0.9, beta2=0.99)
            )
        )
    )
    resumed = ["train", str(dataset), "--out", str(run), "--resume", "--config", str(changed)]
    assert main([*resumed, "--max-steps", "4"]) == 0
    state = torch.load(run / "checkpoints" / "last.pt", weights_only=True)
    for key in ("optimizer_g", "optimizer_d"):
        assert [tuple(g["betas"]) for g in state[key]["param_groups"]] == [(0.9, 0.99)]


def test_a_resume_that_trains_nothing_leaves_config_yaml_as_it_was(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # at a budget just reached no step runs, yet config.yaml took the new seed and bf16,
    # and its runtime said bf16 from step 2 on, a precision no step was trained at
    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path)
    before = (run / "config.yaml").read_bytes()
    resumed = ["train", str(dataset), "--out", str(run), "--resume", "--max-steps", "2"]
    with caplog.at_level("WARNING"):
        assert main([*resumed, "--seed", "5", "--precision", "bf16"]) == 0
    assert (run / "config.yaml").read_bytes() == before
    assert any("nothing was trained" in message for message in caplog.messages)
    # a session stopped before its first checkpoint left its settings in config.yaml:
    # one that trains nothing then puts back what the checkpoints ran, not those
    assert b"seed: 0" in before
    (run / "config.yaml").write_text(before.decode().replace("seed: 0", "seed: 7"))
    assert main(resumed) == 0
    assert (run / "config.yaml").read_bytes() == before


def test_a_last_pt_of_weights_alone_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the shipped weights copied to last.pt: a KeyError traceback ('discriminator')
    from lenspair.cli import main

    dataset, run, _ = _cli_run(tmp_path)
    last = run / "checkpoints" / "last.pt"
    state = torch.load(last, weights_only=True)
    torch.save(
        {k: v for k, v in state.items() if k in ("format", "version", "config", "model")}, last
    )
    capsys.readouterr()
    code = main(["train", str(dataset), "--out", str(run), "--resume", "--max-steps", "4"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].endswith(
        f"--resume: {last} holds a network's weights but no training state (discriminator, "
        f"optimizer_g, optimizer_d): start a new run from it with --init {last}"
    )
    assert "Traceback" not in "\n".join(err)
