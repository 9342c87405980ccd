"""Resolve ``--device auto|cpu|cuda`` once, in the CLI, and pass it down."""

import re
from typing import TYPE_CHECKING, Literal

from lenspair.core.errors import LenspairError

if TYPE_CHECKING:
    import torch

DeviceChoice = Literal["auto", "cpu", "cuda"]


def resolve_device(choice: "str | torch.device") -> "torch.device":
    """Map a ``--device`` choice (or a library caller's ``torch.device``) to a ``torch.device``.

    ``auto`` picks CUDA when available and the CPU otherwise; ``cuda`` on a
    machine without one raises a clear error instead of crashing later. A
    library caller may name one GPU (``cuda:1`` or ``torch.device("cuda", 1)``);
    the command line takes ``cuda``, and ``CUDA_VISIBLE_DEVICES`` picks the GPU.
    """
    # Imported here, not at the top: every command imports this module, and
    # `lenspair COMMAND --help` should not pay for importing torch.
    import torch

    text = str(choice)
    if text == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if text == "cpu" or re.fullmatch(r"cpu:\d+", text):  # torch.device("cpu", 0) says cpu:0
        return torch.device("cpu")
    if text == "cuda" or re.fullmatch(r"cuda:\d+", text):
        if not torch.cuda.is_available():
            raise LenspairError(f"--device {text}: no CUDA device is available on this machine")
        device = torch.device(text)
        if device.index is not None and device.index >= (count := torch.cuda.device_count()):
            raise LenspairError(
                f"--device {text}: this machine has {count} CUDA device(s), cuda:0 to "
                f"cuda:{count - 1}"
            )
        return device
    raise LenspairError(f"--device: expected auto, cpu or cuda, got {text!r}")
