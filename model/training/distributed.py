"""Multi-process training under ``torchrun``: this process's place and the process group.

Under ``torchrun`` (``WORLD_SIZE`` > 1) every process reads its rank from the
environment (:func:`distributed_from_env`), joins the process group
(:func:`init_distributed`: NCCL on CUDA, gloo on the CPU), and the
:class:`~lenspair.model.training.step.Trainer` wraps both networks in
``DistributedDataParallel``. Decisions every process must take together (skip
a non-finite step, stop the run) go through :func:`all_true`; values every
process must share (the precision ``auto`` measured) come from rank 0 through
:func:`from_main`. A single-process
run never touches ``torch.distributed``.
"""

import os
from dataclasses import dataclass
from typing import Any, TypeVar

import torch
import torch.distributed as dist

from lenspair.model.errors import ModelError

T = TypeVar("T")


@dataclass(frozen=True)
class Distributed:
    """This process's place in a ``torchrun`` job (rank 0 of 1 without one)."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        """Whether this process logs and writes files."""
        return self.rank == 0

    @property
    def active(self) -> bool:
        """Whether more than one process takes part."""
        return self.world_size > 1


def distributed_from_env() -> Distributed:
    """Read ``WORLD_SIZE``, ``RANK`` and ``LOCAL_RANK`` as set by ``torchrun``."""
    try:
        world = int(os.environ.get("WORLD_SIZE", "1"))
        rank = int(os.environ.get("RANK", "0"))
        local = int(os.environ.get("LOCAL_RANK", "0"))
    except ValueError:
        raise ModelError("WORLD_SIZE, RANK and LOCAL_RANK must be integers") from None
    return Distributed(rank=rank, world_size=max(world, 1), local_rank=local)


def init_distributed(device: torch.device) -> tuple[Distributed, torch.device]:
    """Join the ``torchrun`` process group when there is one.

    Single-process runs return ``(Distributed(), device)`` untouched. Under
    ``torchrun`` with CUDA each process takes ``cuda:LOCAL_RANK``.
    """
    info = distributed_from_env()
    if not info.active:
        return info, device
    if device.type == "cuda":
        device = torch.device("cuda", info.local_rank)
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        init_process_group("nccl" if device.type == "cuda" else "gloo")
    return info, device


def init_process_group(backend: str, **kwargs: Any) -> None:
    """``dist.init_process_group``, with DDP's lazy imports done before it.

    ``torch.distributed.nn.functional`` (which DDP's construction imports)
    evaluates ``group.WORLD`` into the default arguments of its functions when
    it is first imported. Imported after the group exists, it holds the group
    for the life of the process: ``destroy_process_group`` then frees nothing,
    gloo's worker threads outlive it, and one that drops a finished
    collective while the interpreter shuts down aborts the process ("terminate
    called without an active exception", after the run's work was saved; about
    1 in 90 looped two-process runs here). Imported first, those defaults are ``None``.
    """
    import torch.distributed.nn.functional  # noqa: F401  (see above)

    dist.init_process_group(backend=backend, **kwargs)


def all_true(flag: bool, info: Distributed, device: torch.device) -> bool:
    """``flag`` on every process (a MIN all-reduce under ``torchrun``)."""
    if not info.active:
        return flag
    value = torch.tensor([1 if flag else 0], device=device)
    dist.all_reduce(value, op=dist.ReduceOp.MIN)
    return bool(value.item())


def mean_over_processes(
    values: dict[str, float], info: Distributed, device: torch.device
) -> dict[str, float]:
    """The mean of each of ``values`` over every process (``values`` without ``torchrun``).

    Every process must hold the same keys (the same loss terms).
    """
    if not info.active or not values:
        return values
    names = sorted(values)
    stacked = torch.tensor([values[name] for name in names], dtype=torch.float64, device=device)
    dist.all_reduce(stacked, op=dist.ReduceOp.SUM)
    means = (stacked / info.world_size).tolist()
    return dict(zip(names, means, strict=True))


def from_main(value: T, info: Distributed) -> T:
    """Rank 0's ``value`` on every process (``value`` itself without ``torchrun``).

    ``value`` must pickle; it travels by ``broadcast_object_list``.
    """
    if not info.active:
        return value
    shared = [value]
    dist.broadcast_object_list(shared, src=0)
    return shared[0]
