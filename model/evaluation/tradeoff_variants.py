"""What a tradeoff compares: the networks (variants), the budget each trains for, its precisions.

Every variant trains on the same data under the same budget (optimiser steps
or wall-clock seconds), early stopping off so that budgets stay equal
(:func:`variant_config`); each ``GEA``-family checkpoint is scored and timed
again at each native reduced precision (:func:`precisions_for`).
"""

from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch

from lenspair.core.durations import steps_or_seconds
from lenspair.model.errors import ModelError
from lenspair.model.precision import choose_precision
from lenspair.model.training.config import RunConfig, Variant


@dataclass(frozen=True)
class TradeoffVariant:
    """One network in the comparison."""

    name: str
    variant: Variant
    width: float = 1.0
    num_blocks: int = 9


DEFAULT_VARIANTS: tuple[TradeoffVariant, ...] = (
    TradeoffVariant("G", "G"),
    TradeoffVariant("GE", "GE"),
    TradeoffVariant("GEA", "GEA"),
    TradeoffVariant("GEA-w0.5", "GEA", width=0.5),
    TradeoffVariant("GEA-w2", "GEA", width=2.0),
    TradeoffVariant("GEA-b3", "GEA", num_blocks=3),
)
"""G, GE, GEA, a narrower and a wider GEA, and a GEA with 3 residual blocks."""


@dataclass(frozen=True)
class Budget:
    """Training budget of each variant: optimiser steps or wall-clock seconds."""

    steps: int | None = None
    seconds: float | None = None

    def describe(self) -> str:
        """``60 steps`` or ``90 s``."""
        return f"{self.steps} steps" if self.steps is not None else f"{self.seconds:g} s"

    @classmethod
    def from_description(cls, text: str) -> "Budget | None":
        """The budget :meth:`describe` wrote as ``text`` (a run's ``meta``); None for other text."""
        number, _, unit = text.partition(" ")
        try:
            value = float(number)
        except ValueError:
            return None
        if unit == "steps" and value.is_integer():
            return cls(steps=int(value))
        return cls(seconds=value) if unit == "s" else None


def parse_budget(text: str) -> Budget:
    """``"60"`` -> 60 steps; ``"90s"``, ``"2m"``, ``"1h"`` -> seconds.

    Raises:
        ModelError: anything else, or a non-positive budget.

    """
    try:
        steps, seconds = steps_or_seconds(text)
    except ValueError as exc:
        raise ModelError(f"--budget: {exc}") from None
    return Budget(steps=steps) if steps is not None else Budget(seconds=seconds)


DEFAULT_LR_DECAY = 0.5
"""``lenspair tradeoff``'s learning-rate decay: over the step budget's second half (pix2pix)."""


def variant_config(base: RunConfig, variant: TradeoffVariant, budget: Budget) -> RunConfig:
    """The run config of one variant: its network, the shared budget, no early stopping.

    ``train.lr_decay`` is kept for a step budget and set to 0 for a time
    budget, whose length in steps is not known in advance.
    """
    return replace(
        base,
        model=replace(
            base.model, variant=variant.variant, width=variant.width, num_blocks=variant.num_blocks
        ),
        train=replace(
            base.train,
            max_steps=budget.steps,
            max_seconds=budget.seconds,
            patience=0,
            lr_decay=base.train.lr_decay if budget.steps else 0.0,
            epochs=max(base.train.epochs, 10**6)
            if budget.steps or budget.seconds
            else base.train.epochs,
        ),
        runtime=None,
    )


def precisions_for(
    variant: str, device: torch.device, native: Sequence[str] | None = None
) -> list[str]:
    """fp32 for every variant; GEA checkpoints again at each native reduced precision.

    ``native`` is what :func:`lenspair.model.precision.native_precisions` found
    on ``device`` (default: probed now): bf16 where it is native (an emulated
    one would only show the emulation), fp16 on CUDA, and int8 (ONNX Runtime,
    CPU) where the CPU has VNNI.
    """
    if variant != "GEA":
        return ["fp32"]
    if native is None:
        native = choose_precision("auto", device, "infer").native
    order = ("bf16", "fp16", "int8") if device.type == "cuda" else ("bf16", "int8")
    reduced = [p for p in order if p in native and not (p == "int8" and device.type == "cuda")]
    return ["fp32", *reduced]
