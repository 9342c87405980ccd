"""Where a training run stands, and when it stops.

:class:`RunState` holds the counters that a checkpoint stores next to the
state dicts (:mod:`lenspair.model.checkpoint`), so that ``--resume`` continues exactly
where a run left off; :func:`stop_reason` and :func:`budget_reason` decide
from it when the loop of :func:`lenspair.model.training.loop.fit` ends.
"""

import math
from dataclasses import dataclass, field
from typing import Any

from lenspair.model.training.config import RunConfig


@dataclass
class RunState:
    """The progress of a run.

    Attributes:
        epoch: completed epochs.
        step: optimiser steps taken (skipped ones included).
        step_in_epoch: steps taken within the current epoch.
        best_psnr: best validation PSNR, dB (``-inf`` if never validated).
        best_epoch: epoch of ``best.pt`` (0 if none).
        stale: validations without improvement.
        seconds: training wall time over all sessions of the run.
        rows: the rows of ``RUN/metrics.csv`` so far.
        loss_sums: sums of the training losses over the current epoch's
            counted steps (kept in a checkpoint written mid-epoch, so that a
            resumed epoch reports the same means as an uninterrupted one).
        loss_steps: steps counted in ``loss_sums``.

    """

    epoch: int = 0
    step: int = 0
    step_in_epoch: int = 0
    best_psnr: float = -math.inf
    best_epoch: int = 0
    stale: int = 0
    seconds: float = 0.0
    rows: list[dict[str, str]] = field(default_factory=list)
    loss_sums: dict[str, float] = field(default_factory=dict)
    loss_steps: int = 0

    def payload(self) -> dict[str, Any]:
        """The progress entries of a checkpoint (:mod:`lenspair.model.checkpoint`)."""
        return {
            "epoch": self.epoch,
            "step": self.step,
            "step_in_epoch": self.step_in_epoch,
            "best_metric": self.best_psnr,
            "best_epoch": self.best_epoch,
            "stale_validations": self.stale,
            "seconds": self.seconds,
            "epoch_loss_sums": dict(self.loss_sums),
            "epoch_loss_steps": self.loss_steps,
        }

    @classmethod
    def from_checkpoint(cls, data: dict[str, Any]) -> "RunState":
        """The progress stored in a checkpoint (``rows`` left empty)."""
        return cls(
            epoch=int(data["epoch"]),
            step=int(data["step"]),
            step_in_epoch=int(data["step_in_epoch"]),
            best_psnr=float(data["best_metric"]),
            best_epoch=int(data["best_epoch"]),
            stale=int(data["stale_validations"]),
            seconds=float(data.get("seconds", 0.0)),
            loss_sums={str(k): float(v) for k, v in data.get("epoch_loss_sums", {}).items()},
            loss_steps=int(data.get("epoch_loss_steps", 0)),
        )


def budget_reason(config: RunConfig, state: RunState) -> str | None:
    """Why a budget stops the run mid-epoch, or ``None``.

    The budgets are ``train.max_steps`` and ``train.max_seconds``.
    """
    train = config.train
    if train.max_steps is not None and state.step >= train.max_steps:
        return f"step budget of {train.max_steps} reached"
    if train.max_seconds is not None and state.seconds >= train.max_seconds:
        return f"time budget of {train.max_seconds:g} s reached"
    return None


def stop_reason(config: RunConfig, state: RunState, seconds: float) -> str | None:
    """Why the run must stop (epochs done, early stopping, budgets), or ``None``.

    Sets ``state.seconds`` to ``seconds`` before checking the budgets.
    """
    train = config.train
    if state.epoch >= train.epochs:
        return f"{train.epochs} epoch{'' if train.epochs == 1 else 's'} done"
    if train.patience and state.stale >= train.patience:
        return (
            f"early stopping: no better validation PSNR in {train.patience} validations "
            f"(best {state.best_psnr:.2f} dB at epoch {state.best_epoch})"
        )
    state.seconds = seconds
    return budget_reason(config, state)
