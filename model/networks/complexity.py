"""Model complexity: parameter counts and FLOPs at a given image size.

FLOPs are counted with :class:`torch.utils.flop_counter.FlopCounterMode`
during one batch-1 forward pass. It counts every multiply-accumulate of a
convolution, transposed convolution or matrix product as **two** FLOPs
(``FLOPs = 2 x MACs``); element-wise work (normalisation, activations,
pooling, padding, additions) is not counted, which is the usual convention
for network tables. Divide by two for MACs.
"""

from dataclasses import asdict, dataclass

import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

from lenspair.model.errors import ModelError


@dataclass(frozen=True)
class ModelSummary:
    """Size and cost of a network at one input size.

    Attributes:
        parameters: number of parameters.
        trainable_parameters: those with ``requires_grad``.
        flops: FLOPs of one forward pass on one image (2 per MAC).
        input_shape: ``(C, H, W)`` the FLOPs were counted at.
    """

    parameters: int
    trainable_parameters: int
    flops: int
    input_shape: tuple[int, int, int]

    @property
    def gflops(self) -> float:
        """FLOPs in units of 1e9."""
        return self.flops / 1e9

    @property
    def macs(self) -> int:
        """Multiply-accumulates (``flops // 2``)."""
        return self.flops // 2

    def as_dict(self) -> dict[str, object]:
        """JSON-ready dict (adds ``gflops``)."""
        return {**asdict(self), "input_shape": list(self.input_shape), "gflops": self.gflops}


def count_parameters(model: nn.Module, trainable_only: bool = False) -> int:
    """Number of parameters of ``model``.

    Args:
        model: any module.
        trainable_only: count only parameters with ``requires_grad``.

    Returns:
        The count (shared parameters counted once).
    """
    return sum(p.numel() for p in model.parameters() if p.requires_grad or not trainable_only)


def count_flops(
    model: nn.Module, input_shape: tuple[int, int, int], device: torch.device | None = None
) -> int:
    """FLOPs (2 per MAC) of one forward pass of ``model`` on a ``(1, C, H, W)`` batch.

    Args:
        model: a module taking one image batch (e.g.
            :class:`~lenspair.model.networks.variants.AnomalyMitigator`).
        input_shape: ``(C, H, W)``.
        device: where to run the pass; default: the device of the model's
            first parameter, else the CPU.

    Returns:
        The FLOP count.

    Raises:
        ModelError: if ``input_shape`` is not three positive integers.
    """
    if len(input_shape) != 3 or min(input_shape) < 1:
        raise ModelError(f"input_shape: expected (C, H, W) positive integers, got {input_shape}")
    if device is None:
        first = next(iter(model.parameters()), None)
        device = first.device if first is not None else torch.device("cpu")
    example = torch.rand(1, *input_shape, device=device)
    counter = FlopCounterMode(display=False)
    with counter, torch.inference_mode():
        model(example)
    return int(counter.get_total_flops())


def describe(
    model: nn.Module, input_shape: tuple[int, int, int], device: torch.device | None = None
) -> ModelSummary:
    """Parameters and FLOPs of ``model`` at ``input_shape``.

    Args:
        model: a module taking one image batch.
        input_shape: ``(C, H, W)``, e.g. ``(1, 360, 540)`` for the paper's crops.
        device: where to run the counting pass (see :func:`count_flops`).

    Returns:
        The :class:`ModelSummary`.
    """
    return ModelSummary(
        parameters=count_parameters(model),
        trainable_parameters=count_parameters(model, trainable_only=True),
        flops=count_flops(model, input_shape, device),
        input_shape=(int(input_shape[0]), int(input_shape[1]), int(input_shape[2])),
    )
