"""The loop over epochs and steps of one training session.

Epochs are passes over the training set in an order drawn from
``(seed, epoch)`` (``DistributedSampler``, also for a single process); a
resumed epoch skips the batches its checkpoint has seen. Each step sets the
scheduled learning rate, takes one optimiser step and adds its losses to the
epoch's means; ``last.pt`` is saved every
``train.checkpoint_every_seconds/_steps`` (:mod:`lenspair.model.training.periodic`).
An epoch ends in a validation (:mod:`lenspair.model.training.validation`) every
``train.val_every`` epochs, at the last one and when the run stops, else in
a ``last.pt``. All processes stop together, for the first reason any of them
has (:mod:`lenspair.model.training.run_state`).
"""

import logging
import math
import time
from collections.abc import Callable
from typing import Any, Protocol

import torch
from torch.utils.data import DataLoader
from torch.utils.data.distributed import DistributedSampler

from lenspair.core.progress import progress
from lenspair.model.training.config import RunConfig, TrainConfig
from lenspair.model.training.distributed import Distributed, all_true, mean_over_processes
from lenspair.model.training.pairs import Sample
from lenspair.model.training.periodic import CheckpointClock, save_progress
from lenspair.model.training.run_files import RunPaths
from lenspair.model.training.run_state import RunState, budget_reason, stop_reason
from lenspair.model.training.step import Trainer, scheduled_lr
from lenspair.model.training.validation import validate_and_save

log = logging.getLogger(__name__)


class EpochDataset(Protocol):
    """A training set whose random choices depend on the epoch (as in ``training.pairs``)."""

    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> Sample: ...
    def set_epoch(self, epoch: int) -> None:
        """Select the epoch."""


def run_epochs(
    trainer: Trainer,
    config: RunConfig,
    train_set: EpochDataset,
    val_set: EpochDataset,
    paths: RunPaths,
    state: RunState,
    info: Distributed,
    board: Any,
) -> str:
    """Epochs until done, early-stopped, out of budget; returns the reason.

    Args:
        trainer: the run's trainer (restored when resumed).
        config: the configuration the run trains with.
        train_set: training samples, with ``set_epoch``.
        val_set: validation samples.
        paths: the run folder.
        state: the run's progress, updated in place.
        info: this process's rank among the run's processes.
        board: a TensorBoard ``SummaryWriter``, or ``None``.

    Returns:
        Why the run stopped, in words.
    """
    train = config.train
    per_rank = train.batch_size // info.world_size
    sampler: DistributedSampler[int] = DistributedSampler(
        train_set,  # type: ignore[arg-type]
        num_replicas=info.world_size,
        rank=info.rank,
        shuffle=True,
        seed=train.seed,
    )
    steps_per_epoch = math.ceil(len(sampler) / per_rank)
    total_steps = _total_steps(train, steps_per_epoch, info)
    started = time.monotonic()
    session_start = state.seconds

    def elapsed() -> float:
        return session_start + time.monotonic() - started

    reason = stop_reason(config, state, elapsed())
    clock = CheckpointClock.start(train, state)
    while reason is None:
        epoch = state.epoch
        train_set.set_epoch(epoch)
        sampler.set_epoch(epoch)
        order = list(sampler)[state.step_in_epoch * per_rank :]
        loader: DataLoader[Sample] = DataLoader(
            train_set,  # type: ignore[arg-type]
            batch_size=per_rank,
            sampler=order,
            num_workers=config.data.num_workers,
            pin_memory=trainer.device.type == "cuda",
            # Its own generator: each DataLoader draws a base seed, which must not
            # advance the global RNG (a resumed run makes one DataLoader more).
            generator=torch.Generator().manual_seed(train.seed * 100_003 + epoch),
        )
        reason, means = _train_epoch(
            trainer, config, loader, paths, state, info, board, clock, total_steps, elapsed
        )
        if state.step_in_epoch >= steps_per_epoch:
            state.epoch += 1
            state.step_in_epoch = 0
            state.loss_sums, state.loss_steps = {}, 0
        finished = state.epoch >= train.epochs
        if (
            reason is not None
            or finished
            or (state.epoch % train.val_every == 0 and state.step_in_epoch == 0)
        ):
            validate_and_save(trainer, config, val_set, paths, state, info, means, board)
            clock.reset(state)
        elif state.step_in_epoch == 0:  # an epoch between validations: a kill loses none of it
            save_progress(trainer, config, paths, state, info)
            clock.reset(state)
        state.seconds = elapsed()
        reason = reason or stop_reason(config, state, state.seconds)
        if not all_true(reason is None, info, trainer.device):  # stop together
            reason = reason or "stopped with the other processes"
    return reason


def _total_steps(train: TrainConfig, steps_per_epoch: int, info: Distributed) -> int:
    """The run's length in steps, over which the learning rate falls (said once, by rank 0)."""
    # whichever budget ends it first (a time budget aside)
    total_steps = min(train.max_steps or math.inf, train.epochs * steps_per_epoch)
    total_steps = int(total_steps)
    if train.lr_decay > 0 and info.is_main:
        log.info(
            "learning rate %g, falling linearly over the last %d of %d steps",
            train.lr,
            round(train.lr_decay * total_steps),
            total_steps,
        )
    return total_steps


def _train_epoch(
    trainer: Trainer,
    config: RunConfig,
    loader: DataLoader[Sample],
    paths: RunPaths,
    state: RunState,
    info: Distributed,
    board: Any,
    clock: CheckpointClock,
    total_steps: int,
    elapsed: Callable[[], float],
) -> tuple[str | None, dict[str, float]]:
    """The steps of one epoch (or of its rest, when resumed), until its end or a budget.

    Args:
        trainer: the run's trainer.
        config: the configuration the run trains with.
        loader: the epoch's batches not yet seen.
        paths: the run folder (for ``last.pt`` within the epoch).
        state: the run's progress, updated in place; its loss sums and
            steps hold the epoch's so far when the loop ends.
        info: this process's rank among the run's processes.
        board: a TensorBoard ``SummaryWriter``, or ``None``.
        clock: when ``last.pt`` is next due within the epoch.
        total_steps: the run's length in steps (:func:`scheduled_lr`).
        elapsed: the run's training seconds so far, over all sessions.

    Returns:
        ``(reason, means)``: why the run stops (``None`` when it goes on)
        and the epoch's mean losses over the steps not skipped.
    """
    train = config.train
    reason: str | None = None
    # A resumed epoch goes on from the sums its checkpoint recorded.
    sums, counted = dict(state.loss_sums), state.loss_steps
    bar = progress(loader, _epoch_label(state.epoch, train), total=len(loader), unit="step")
    for batch in bar if info.is_main else loader:
        # every step, also at a constant rate: a resumed run's optimiser state
        # carries the rate it was saved with, and the config may have changed it
        trainer.set_lr(scheduled_lr(train, state.step, total_steps))
        result = trainer.train_step(batch)
        state.step += 1
        state.step_in_epoch += 1
        if not result.skipped:
            counted += 1
            for name, value in result.losses.items():
                sums[name] = sums.get(name, 0.0) + value
            if board is not None and state.step % train.log_every == 0:
                for name, value in result.losses.items():
                    board.add_scalar(f"train/{name}", value, state.step)
                lr = trainer.opt_g.param_groups[0]["lr"]
                board.add_scalar("train/lr", lr, state.step)
        state.seconds = elapsed()
        reason = budget_reason(config, state)
        if reason is None and clock.due(state):  # a kill now loses little
            state.loss_sums, state.loss_steps = dict(sums), counted
            save_progress(trainer, config, paths, state, info)
            clock.reset(state)
        if not all_true(reason is None, info, trainer.device):
            reason = reason or "time budget reached on another process"
            break
    state.loss_sums, state.loss_steps = dict(sums), counted  # for a budget-stop checkpoint
    # each process saw its share of the batch: the epoch's loss is their mean, not rank 0's
    means = {name: total / max(counted, 1) for name, total in sums.items()}
    return reason, mean_over_processes(means, info, trainer.device)


def _epoch_label(epoch: int, train: TrainConfig) -> str:
    """Progress label: ``epoch 3/200``, or ``epoch 3 (budget 400 steps)`` when a budget binds."""
    budgets = [f"{train.max_steps} steps"] if train.max_steps else []
    budgets += [f"{train.max_seconds:g} s"] if train.max_seconds else []
    if budgets:
        return f"epoch {epoch + 1} (budget {' or '.join(budgets)})"
    return f"epoch {epoch + 1}/{train.epochs}"
