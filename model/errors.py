"""Errors raised by the ``model`` package."""

from lenspair.core.errors import LenspairError


class ModelError(LenspairError):
    """A problem in the model stage (the message names the file or key)."""


class TrainingDivergedError(ModelError):
    """Training diverged: too many consecutive non-finite steps, or a NaN/Inf network output."""


class NonFiniteOutputError(ModelError):
    """A network gave NaN or Inf for a finite input: the network's fault, never the pair's."""
