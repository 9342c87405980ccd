"""Checkpoints within an epoch: a kill loses minutes, not an epoch.

On real datasets an epoch is hours; a run killed before its first epoch
ended used to lose everything. :class:`CheckpointClock` decides when the
loop writes ``last.pt`` between validations, every
``train.checkpoint_every_steps`` optimiser steps and/or every
``train.checkpoint_every_seconds`` of training time (default 10 minutes),
and :func:`save_progress` writes it: the same state a budget stop writes
(state dicts, counters with the step within the epoch, RNG states), without
validating, so ``--resume`` continues with the next batch exactly as an
uninterrupted run would.
"""

from dataclasses import dataclass

from lenspair.model.checkpoint import save_checkpoint
from lenspair.model.training.config import RunConfig, TrainConfig
from lenspair.model.training.distributed import Distributed
from lenspair.model.training.run_files import RunPaths
from lenspair.model.training.run_state import RunState
from lenspair.model.training.step import Trainer, rng_state


@dataclass
class CheckpointClock:
    """When the next in-epoch checkpoint is due.

    Attributes:
        every_steps: interval in optimiser steps, or ``None``.
        every_seconds: interval in training seconds, or ``None``.
        last_step: step of the last checkpoint written (or of the start).
        last_seconds: training seconds at that checkpoint.

    """

    every_steps: int | None
    every_seconds: float | None
    last_step: int = 0
    last_seconds: float = 0.0

    @classmethod
    def start(cls, train: TrainConfig, state: RunState) -> "CheckpointClock":
        """A clock counting from where ``state`` stands (a fresh or resumed run)."""
        return cls(
            train.checkpoint_every_steps, train.checkpoint_every_seconds, state.step, state.seconds
        )

    def due(self, state: RunState) -> bool:
        """Whether a checkpoint is due at ``state`` (its ``step`` and ``seconds``)."""
        by_steps = self.every_steps is not None and state.step - self.last_step >= self.every_steps
        by_time = (
            self.every_seconds is not None
            and state.seconds - self.last_seconds >= self.every_seconds
        )
        return by_steps or by_time

    def reset(self, state: RunState) -> None:
        """Count the next interval from ``state`` (a checkpoint was just written)."""
        self.last_step, self.last_seconds = state.step, state.seconds


def save_progress(
    trainer: Trainer, config: RunConfig, paths: RunPaths, state: RunState, info: Distributed
) -> None:
    """Write ``last.pt`` with the run's current state (rank 0 only; no validation)."""
    if not info.is_main:
        return
    payload = {**trainer.state_dict(), **state.payload(), "rng": rng_state()}
    save_checkpoint(paths.last, payload, config)
