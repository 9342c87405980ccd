"""One train at a time writes a run folder: the lock, its refusal, its life, torchrun."""

import os
import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.model.errors import ModelError
from lenspair.model.training import loop, run_files
from lenspair.model.training.datasets import paired_training_data
from lenspair.model.training.loop import fit, resolve_config
from lenspair.model.training.step import Trainer
from tests.locks import held_lock, is_locked
from tests.model.test_ddp import _cli_worker, _free_port
from tests.model.train_fixtures import tiny_config, write_split_dataset

CPU = torch.device("cpu")
BUSY = "another lenspair train is writing this run folder"
LOCK_FILE = ".lock"

pytestmark = pytest.mark.usefixtures("one_thread")


@contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """Hold ``folder``'s run lock meanwhile, as a running train does (another descriptor)."""
    folder.mkdir(parents=True, exist_ok=True)
    with held_lock(folder / LOCK_FILE):
        yield


def _files(run: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(run)): p.read_bytes()
        for p in sorted(run.rglob("*"))
        if p.is_file() and p.name != LOCK_FILE
    }


def _argv(tmp_path: Path, run: Path, **train: Any) -> list[str]:
    dataset = tmp_path / "ds"
    if not dataset.exists():
        write_split_dataset(dataset, {"train": 4, "val": 1})
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(**train)))
    return ["train", str(dataset), "--out", str(run), "--config", str(config), "--device", "cpu"]


def test_a_resume_beside_the_run_it_resumes_is_refused_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Both trained to the end, exit 0, each overwriting the other's last.pt, best.pt and
    metrics.csv."""
    run = tmp_path / "run"
    argv = _argv(tmp_path, run, max_steps=2)
    assert main(argv) == 0
    before = _files(run)
    _argv(tmp_path, run, max_steps=4)
    with _locked(run):  # the first run, still writing
        capsys.readouterr()
        assert main([*argv, "--resume"]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert main(argv) == 2  # a new run into it: the same answer, before "holds a run"
        (again,) = capsys.readouterr().err.strip().splitlines()
    assert (
        line
        == again
        == f"lenspair train: error: {run}: {BUSY}; run this one when that "
        + ("one has finished, or choose another --out")
    )
    assert _files(run) == before  # nothing written, nothing removed
    assert main([*argv, "--resume"]) == 0  # once that run has ended: resumed as usual
    assert not is_locked(run / LOCK_FILE)  # the lock went with the run


def test_a_new_run_into_a_folder_being_written_writes_nothing(tmp_path: Path) -> None:
    run = tmp_path / "run"
    argv = _argv(tmp_path, run, max_steps=1)
    with _locked(run):  # another train that has just made it
        assert main(argv) == 2
    assert [p.name for p in run.iterdir()] == [LOCK_FILE]
    assert main(argv) == 0


def test_the_lock_is_held_while_the_run_trains_and_let_go_after(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = tmp_path / "run"
    held = []

    def run_epochs(*args: Any, **kwargs: Any) -> str:
        held.append(is_locked(run / LOCK_FILE))
        return "stopped by the test"

    monkeypatch.setattr(loop, "run_epochs", run_epochs)
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})
    config = tiny_config(max_steps=1)
    data = paired_training_data(dataset, config.data, 1, 0, notes=[])
    fit(resolve_config(config, 1), data.train, data.val, run, CPU)
    assert held == [True]  # a folder the run made: locked before anything was written
    assert not is_locked(run / LOCK_FILE)
    fit(resolve_config(config, 1), data.train, data.val, run, CPU)  # no checkpoint: not a run
    assert held == [True, True]  # an existing folder: locked before its files are read


def test_a_run_written_into_the_new_folder_meanwhile_is_not_replaced(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The folder did not exist at the checks; another run made it, wrote and ended."""
    run = tmp_path / "run"
    real = Trainer

    def trainer(*args: Any, **kwargs: Any) -> Any:  # built between the checks and the lock
        (run / "checkpoints").mkdir(parents=True)
        (run / "checkpoints" / "last.pt").write_bytes(b"theirs")
        return real(*args, **kwargs)

    monkeypatch.setattr(loop, "Trainer", trainer)
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1})
    config = tiny_config(max_steps=1)
    data = paired_training_data(dataset, config.data, 1, 0, notes=[])
    with pytest.raises(ModelError, match=r"wrote a run into it since this one started \(last"):
        fit(resolve_config(config, 1), data.train, data.val, run, CPU)
    assert (run / "checkpoints" / "last.pt").read_bytes() == b"theirs"
    assert not (run / "metrics.csv").exists()


def test_a_forked_child_does_not_keep_the_lock(tmp_path: Path) -> None:
    """A DataLoader worker (forked) outliving a killed run by seconds held its lock."""
    assert run_files.LOCK_FILE == LOCK_FILE
    lock = run_files.RunLock(tmp_path)
    assert lock.take() and lock.held and is_locked(tmp_path / LOCK_FILE)
    ready, told = os.pipe()
    child = os.fork()
    if child == 0:  # pragma: no cover (the child: alive, past os.fork's hooks)
        os.write(told, b"1")
        time.sleep(30)
        os._exit(0)
    try:
        assert os.read(ready, 1) == b"1"
        lock.release()
        assert not is_locked(tmp_path / LOCK_FILE)  # the child's inherited copy was closed
    finally:
        os.kill(child, signal.SIGKILL)
        os.waitpid(child, 0)
        os.close(ready)
        os.close(told)


@pytest.mark.skipif(not dist.is_available() or not dist.is_gloo_available(), reason="no gloo")
def test_under_torchrun_every_rank_refuses_a_folder_being_written(tmp_path: Path) -> None:
    """Only rank 0 takes the lock; the others learn it was refused, none waits forever."""
    run = tmp_path / "run"
    argv = _argv(tmp_path, run, max_steps=1)
    with _locked(run), pytest.raises(mp.ProcessExitedException):  # type: ignore[attr-defined]
        mp.spawn(  # type: ignore[attr-defined]
            _cli_worker, args=(2, _free_port(), argv, str(tmp_path)), nprocs=2, join=True
        )
    for rank in range(2):
        assert BUSY in (tmp_path / f"rank{rank}.txt").read_text()
    assert [p.name for p in run.iterdir()] == [LOCK_FILE]
