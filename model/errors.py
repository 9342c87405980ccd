"""Errors raised by the ``model`` package."""

from lenspair.core.errors import LenspairError


class ModelError(LenspairError):
    """A problem in the model stage (the message names the file or key)."""


class TrainingDivergedError(ModelError):
    """Training diverged: too many consecutive non-finite steps, or a NaN/Inf network output."""


class NonFiniteOutputError(ModelError):
    """A network gave NaN or Inf for a finite input: the network's fault, never the pair's."""


def is_out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is an allocation failure (CUDA's, the CPU allocator's, numpy's, ORT's).

    By name and message, so that this module needs no torch: ``torch.OutOfMemoryError``
    (CUDA), numpy's ``MemoryError``, and the CPU allocator's and ONNX Runtime's
    ``RuntimeError`` text.
    """
    if isinstance(exc, MemoryError) or type(exc).__name__ == "OutOfMemoryError":
        return True
    text = str(exc)
    return any(
        sign in text
        for sign in ("can't allocate memory", "DefaultCPUAllocator", "Failed to allocate memory")
    )
