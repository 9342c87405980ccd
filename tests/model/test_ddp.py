"""Two-process DDP on the CPU (gloo): ranks stay in step, gradients keep their layout."""

import gc
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch.nn.parallel import DistributedDataParallel

from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.model.precision import PrecisionDecision
from lenspair.model.training.distributed import (
    Distributed,
    init_process_group,
    mean_over_processes,
)
from lenspair.model.training.step import Trainer
from tests.model.train_fixtures import tiny_config, write_split_dataset

CPU = torch.device("cpu")
STEPS = 3
FP32 = PrecisionDecision("fp32", "fp32", "test", ("fp32",), "cpu", "test")
# what auto may measure in a second process while the first measured fp32 faster
BF16 = PrecisionDecision("bf16", "auto", "measured", ("bf16", "fp32"), "cpu", "test", 1.3)
NEEDS_GLOO = pytest.mark.skipif(
    not dist.is_available() or not dist.is_gloo_available(), reason="no gloo"
)


@contextmanager
def _gloo_group(rank: int, world: int, port: int) -> Iterator[None]:
    """A gloo process group on localhost for the ``with`` block, destroyed however it ends."""
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    init_process_group("gloo", rank=rank, world_size=world)
    try:
        yield
    finally:  # as lenspair's fit tears down: the DDP wrappers first, then the group
        dist.destroy_process_group()


def _batch(seed: int) -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    target = torch.rand(1, 1, 32, 32, generator=generator)
    keep = torch.rand(1, 1, 32, 32, generator=generator) > 0.2
    return {"input": target * keep, "target": target, "valid": torch.ones(1, 1, 32, 32)}


def _train(rank: int, world: int, out: str) -> None:
    """A few DDP steps; the trainer (and its DDP wrappers) is gone when this returns."""
    decision = FP32 if rank == 0 else BF16
    trainer = Trainer(tiny_config(), CPU, Distributed(rank, world, rank), decision=decision)
    mismatched = []
    for step in range(STEPS):
        # Each rank sees different data: only gradient averaging keeps them equal.
        trainer.train_step(_batch(100 * rank + step))
        for name, parameter in trainer.network.named_parameters():
            if parameter.grad is not None and parameter.grad.stride() != parameter.stride():
                mismatched.append(name)
    state = {k: v.clone() for k, v in trainer.model.state_dict().items()}
    # D too: its gradients are averaged only in its own backward, the network's loss
    # leaves its weights frozen
    discriminator = trainer.discriminator.module.state_dict()
    state.update({f"D.{k}": v.clone() for k, v in discriminator.items()})
    torch.save(state, Path(out) / f"rank{rank}.pt")
    (Path(out) / f"rank{rank}.json").write_text(json.dumps(sorted(set(mismatched))))
    (Path(out) / f"rank{rank}.precision").write_text(trainer.decision.precision)


def _threads() -> int | None:
    """This process's OS threads (None where there is no /proc: the check is Linux's)."""
    tasks = Path("/proc/self/task")
    return len(os.listdir(tasks)) if tasks.is_dir() else None


def _threads_down_to(count: int | None, seconds: float = 5.0) -> int | None:
    """The thread count once it is ``count`` or fewer, or after ``seconds``.

    A worker thread ends a moment after the group that joined it is destroyed:
    on a loaded CI machine one was counted still there (3 threads against 2).
    A thread the group never lets go (the bug this guards against) stays.
    """
    deadline = time.monotonic() + seconds
    while (now := _threads()) is not None and count is not None and now > count:
        if time.monotonic() > deadline:
            break
        time.sleep(0.05)
    return now


def _pinned_groups() -> list[str]:
    """Functions of loaded ``torch.distributed`` modules holding a process group as a default."""
    return [
        f"{name}.{attr}"
        for name, module in list(sys.modules.items())
        if name.startswith("torch.distributed")
        for attr, value in list(vars(module).items())
        if any(isinstance(d, dist.ProcessGroup) for d in getattr(value, "__defaults__", None) or ())
    ]


def _worker(rank: int, world: int, port: int, out: str) -> None:
    torch.set_num_threads(1)
    before = _threads()
    with _gloo_group(rank, world, port):
        _train(rank, world, out)
        dist.barrier()
    # the group is gone, gloo's threads joined, none left to run into interpreter shutdown
    (Path(out) / f"rank{rank}.threads").write_text(json.dumps([before, _threads_down_to(before)]))


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@NEEDS_GLOO
def test_two_process_ddp_ends_with_identical_weights(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    mp.spawn(_worker, args=(2, _free_port(), str(tmp_path)), nprocs=2, join=True)
    weights = [torch.load(tmp_path / f"rank{r}.pt", weights_only=True) for r in range(2)]
    assert weights[0].keys() == weights[1].keys()
    for key in weights[0]:
        torch.testing.assert_close(weights[0][key], weights[1][key], rtol=0, atol=0, msg=key)
    untrained = Trainer(tiny_config(), CPU, decision=FP32)
    initial = untrained.model.state_dict()
    assert any(not torch.equal(initial[k], weights[0][k]) for k in initial), "nothing trained"
    initial_d = untrained.discriminator.state_dict()
    assert any(not torch.equal(v, weights[0][f"D.{k}"]) for k, v in initial_d.items())
    for rank in range(2):
        assert json.loads((tmp_path / f"rank{rank}.json").read_text()) == []
        # every rank trains at rank 0's precision, whatever its own measurement said
        assert (tmp_path / f"rank{rank}.precision").read_text() == "fp32"
        before, after = json.loads((tmp_path / f"rank{rank}.threads").read_text())
        if before is not None:
            assert after <= before, f"rank {rank}: {after} threads after the group, {before} before"
    assert "grad strides do not match bucket view strides" not in capfd.readouterr().err.lower()


def _measuring_worker(rank: int, world: int, port: int, out: str) -> None:
    """A trainer on a CPU said to have native bf16, with auto's timing counted, not done."""
    from lenspair.model import precision

    torch.set_num_threads(1)
    timed: list[str] = []
    precision.native_precisions = lambda hardware: ("bf16", "fp32")  # type: ignore[assignment]
    precision.measure_bf16_speed = lambda task: timed.append(task) or 0.6  # type: ignore[assignment,func-returns-value]
    with _gloo_group(rank, world, port):
        trainer = Trainer(tiny_config(amp=True), CPU, Distributed(rank, world, rank))
        result = {"timed": timed, "precision": trainer.decision.precision}
        result["speed"] = trainer.decision.bf16_speed
        del trainer
        dist.barrier()
    (Path(out) / f"rank{rank}.measured").write_text(json.dumps(result))


@NEEDS_GLOO
def test_only_rank_zero_times_bf16_and_every_rank_takes_its_choice(tmp_path: Path) -> None:
    # ranks that timed at once would share the cores, and rank 0 would time under their load
    mp.spawn(_measuring_worker, args=(2, _free_port(), str(tmp_path)), nprocs=2, join=True)
    said = [json.loads((tmp_path / f"rank{r}.measured").read_text()) for r in range(2)]
    assert said[0]["timed"] == ["train"] and said[1]["timed"] == []
    for result in said:  # bf16 measured 0.6x fp32's speed on rank 0: everyone trains fp32
        assert result["precision"] == "fp32" and result["speed"] == 0.6


def test_a_decision_not_measured_still_refuses_a_contradicting_config(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # ranks other than 0 skip the timing, not the checks: a bad config stops them all
    from lenspair.model import precision
    from lenspair.model.errors import ModelError
    from lenspair.model.training.step import training_precision

    def never(task: str) -> float:
        raise AssertionError("timed")

    monkeypatch.setattr(precision, "native_precisions", lambda hardware: ("bf16", "fp32"))
    monkeypatch.setattr(precision, "measure_bf16_speed", never)
    train = tiny_config(amp=True).train
    assert training_precision(train, CPU, measure=False).precision == "bf16"  # a placeholder
    with pytest.raises(ModelError, match="--no-amp"):
        training_precision(replace(train, amp=False, precision="bf16"), CPU, measure=False)
    with pytest.raises(AssertionError, match="timed"):
        training_precision(train, CPU)


def _cli_worker(rank: int, world: int, port: int, argv: list[str], out: str) -> None:
    """One torchrun process of ``lenspair train``: its stdout and stderr go to ``out/rankR.txt``."""
    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), WORLD_SIZE=str(world),
        RANK=str(rank), LOCAL_RANK=str(rank),
    )  # fmt: skip
    os.environ.pop("LENSPAIR_VGG19_WEIGHTS", None)  # the perceptual warning is the one said
    torch.set_num_threads(1)
    destroy = dist.destroy_process_group

    def destroy_after_counting(*args: Any, **kwargs: Any) -> None:
        # DDP wrappers still alive here are freed after the group (see fit's teardown)
        alive = sum(isinstance(o, DistributedDataParallel) for o in gc.get_objects())
        (Path(out) / f"rank{rank}.ddp").write_text(json.dumps([alive, _pinned_groups()]))
        destroy(*args, **kwargs)

    dist.destroy_process_group = destroy_after_counting
    with open(Path(out) / f"rank{rank}.txt", "w") as log:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        code = main(argv)
    # what lenspair left behind: a group still up here would run gloo into interpreter exit
    (Path(out) / f"rank{rank}.left").write_text(json.dumps(dist.is_initialized()))
    if dist.is_initialized():
        dist.destroy_process_group()
    if code != 0:
        raise SystemExit(code)


@NEEDS_GLOO
def test_under_torchrun_only_rank_zero_says_the_run_level_lines(tmp_path: Path) -> None:
    # The real CLI path: init_distributed from torchrun's variables, fit, the summary.
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8})  # no val split: said, once
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=2)))  # perceptual on, no VGG weights
    run = tmp_path / "run"
    argv = ["train", str(dataset), "--out", str(run), "--config", str(config), "--device", "cpu"]
    mp.spawn(_cli_worker, args=(2, _free_port(), argv, str(tmp_path)), nprocs=2, join=True)
    said = [(tmp_path / f"rank{rank}.txt").read_text() for rank in range(2)]
    lines = ("PERCEPTUAL LOSS DISABLED", "best validation PSNR", "reminder: this run trained")
    for line in (*lines, "no 'val' split"):  # the data's warnings too, said while loading
        assert line in said[0] and line not in said[1], line
    assert "no 'val' split" in (run / "train.log").read_text()
    # nothing holds the group when it is destroyed: no DDP wrapper, no function default
    # (either keeps gloo's threads running into interpreter shutdown, where they can abort)
    for rank in range(2):
        assert json.loads((tmp_path / f"rank{rank}.ddp").read_text()) == [0, []]
    assert "world_size: 2" in (run / "config.yaml").read_text()
    # A resume with a changed config is warned about once, by rank 0.
    config.write_text(dump_yaml(tiny_config(max_steps=3, lr=1e-4)))
    resumed = [*argv, "--resume"]
    mp.spawn(_cli_worker, args=(2, _free_port(), resumed, str(tmp_path)), nprocs=2, join=True)
    said = [(tmp_path / f"rank{rank}.txt").read_text() for rank in range(2)]
    assert "--resume with a changed config: train.lr" in said[0]
    assert "--resume with a changed config" not in said[1]


@NEEDS_GLOO
def test_a_run_refused_under_torchrun_tears_its_process_group_down(tmp_path: Path) -> None:
    # batch 3 over 2 processes is refused after the group is up, before training starts
    dataset = write_split_dataset(tmp_path / "ds", {"train": 8, "val": 2})
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=2, batch_size=3)))
    argv = ["train", str(dataset), "--out", str(tmp_path / "run"), "--config", str(config)]
    with pytest.raises(mp.ProcessExitedException):
        mp.spawn(_cli_worker, args=(2, _free_port(), argv, str(tmp_path)), nprocs=2, join=True)
    for rank in range(2):
        assert "not divisible by 2 processes" in (tmp_path / f"rank{rank}.txt").read_text()
        assert json.loads((tmp_path / f"rank{rank}.left").read_text()) is False


def _mean_worker(rank: int, world: int, port: int, out: str) -> None:
    with _gloo_group(rank, world, port):
        losses = {"loss_g": 4.0 + 2.0 * rank, "loss_d": 0.5 * (rank + 1)}
        mean = mean_over_processes(losses, Distributed(rank, world, rank), CPU)
    (Path(out) / f"rank{rank}.mean").write_text(json.dumps(mean))


@NEEDS_GLOO
def test_the_epoch_losses_are_the_mean_over_processes(tmp_path: Path) -> None:
    # metrics.csv and the log had rank 0's half of the batch alone: 4.310 under torchrun
    # against 3.924 for the same run in one process
    mp.spawn(_mean_worker, args=(2, _free_port(), str(tmp_path)), nprocs=2, join=True)
    for rank in range(2):
        said = json.loads((tmp_path / f"rank{rank}.mean").read_text())
        assert said == {"loss_d": 0.75, "loss_g": 5.0}
