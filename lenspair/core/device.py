"""Resolve ``--device auto|cpu|cuda`` once, in the CLI, and pass it down."""

from typing import TYPE_CHECKING, Literal

from lenspair.core.errors import LenspairError

if TYPE_CHECKING:
    import torch

DeviceChoice = Literal["auto", "cpu", "cuda"]


def resolve_device(choice: str) -> "torch.device":
    """Map a ``--device`` choice to a ``torch.device``.

    ``auto`` picks CUDA when available and the CPU otherwise; ``cuda`` on a
    machine without one raises a clear error instead of crashing later.
    """
    # Imported here, not at the top: every command imports this module, and
    # `lenspair COMMAND --help` should not pay for importing torch.
    import torch

    if choice == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if choice == "cpu":
        return torch.device("cpu")
    if choice == "cuda":
        if not torch.cuda.is_available():
            raise LenspairError("--device cuda: no CUDA device is available on this machine")
        return torch.device("cuda")
    raise LenspairError(f"--device: expected auto, cpu or cuda, got {choice!r}")
