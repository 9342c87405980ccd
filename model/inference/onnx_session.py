"""ONNX Runtime's side of restoring: session options, a restoring model's signature, its precision.

:class:`~lenspair.model.inference.backends.OnnxBackend` opens a session with
:func:`session_options`, refuses a file that is not a restoring model
(:func:`check_signature`), tells an int8 file from an fp32 one
(:func:`onnx_precision`), runs a model of a fixed batch size (another
tool's export) in pieces of that size (:func:`run_in_pieces`) and makes ONNX
Runtime's refusal of a batch one line (:func:`run_error`); ``export`` and
``export --int8`` time their files with the same options.
"""

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lenspair.model.errors import ModelError


def check_signature(path: Path, inputs: list[Any], outputs: list[Any]) -> Any:
    """The one input of a restoring ONNX model, after checking its outputs.

    A model from ``lenspair export`` takes one batch ``(N, C, H, W)`` and returns
    one of the same channels. Any other ONNX file (a classifier, a model of two
    inputs) failed later with a traceback from deep in the pipeline, after OUT
    had been started.

    Args:
        path: the model, for the message.
        inputs: the session's ``get_inputs()``.
        outputs: the session's ``get_outputs()``.

    Raises:
        ModelError: naming ``path`` and what differs.
    """
    if len(inputs) != 1:
        names = ", ".join(spec.name for spec in inputs)
        raise ModelError(
            f"{path}: {len(inputs)} inputs ({names}); a restoring model takes one image "
            "batch (N, C, H, W), as lenspair export writes"
        )
    (spec,) = inputs
    shape = list(spec.shape or [])
    if len(shape) != 4 or not isinstance(shape[1], int):
        raise ModelError(f"{path}: expected an input (N, C, H, W), got {spec.shape}")
    if isinstance(shape[0], int) and shape[0] < 1:
        raise ModelError(f"{path}: an input of batch size {shape[0]} ({spec.shape}) takes no image")
    for output in outputs:
        returned = list(output.shape or [])
        # a channel count named, not numbered (torch's classic exporter with dynamic
        # axes), is checked on the first frame's output instead (OnnxBackend.__call__)
        if len(returned) != 4 or (isinstance(returned[1], int) and returned[1] != shape[1]):
            raise ModelError(
                f"{path}: output {output.name} is {output.shape}, not (N, {shape[1]}, H, W) "
                f"like its input {shape}: not a restoring model (lenspair export writes one)"
            )
    return spec


def fixed_batch(spec: Any) -> int | None:
    """The batch size a model's input ``spec`` fixes, or None when its batch is dynamic.

    ``lenspair export`` writes a dynamic batch; other tools (and a trace on one
    frame) fix it, most often at 1, and ONNX Runtime refuses any other count.
    """
    size = (spec.shape or [None])[0]
    return size if isinstance(size, int) else None


def run_in_pieces(
    run: Callable[[np.ndarray], np.ndarray], batch: np.ndarray, size: int | None
) -> np.ndarray:
    """``run`` on ``batch`` in pieces of ``size`` frames, the outputs concatenated in order.

    A model of a fixed batch size takes ``size`` frames a call, whatever
    ``--batch-size`` and the tiles of a large frame (sent several a call)
    make a batch: a short last piece is filled with copies of its last frame,
    whose outputs are dropped (a restoring network treats each frame alone).
    ``size`` None (a dynamic batch) runs the batch in one call.
    """
    if size is None or len(batch) == size:
        return run(batch)
    outputs = []
    for first in range(0, len(batch), size):
        piece = batch[first : first + size]
        frames = len(piece)
        if frames < size:
            piece = np.concatenate([piece, np.repeat(piece[-1:], size - frames, axis=0)])
        outputs.append(run(piece)[:frames])
    return np.concatenate(outputs)


RUN_ERRORS = frozenset({"InvalidArgument", "Fail", "RuntimeException"})
"""ONNX Runtime's exception types for a batch its session cannot run (shapes, a node's
arithmetic), as its Python binding names them."""


def run_error(
    path: Path, exc: BaseException, shape: tuple[int, ...], declared: Any
) -> ModelError | None:
    """The one-line error of ONNX Runtime refusing a batch of ``shape``, or None for another error.

    A model whose input fixes a side (another tool's export) refused frames of
    other sizes with onnxruntime's traceback, which ended the run; as a
    :class:`ModelError` the frames fail, are copied unchanged and listed, and
    ``Restorer`` raises it. Out-of-memory errors are left to the caller.

    Args:
        path: the model, for the message.
        exc: what ``InferenceSession.run`` raised.
        shape: the batch it was given.
        declared: the model's input shape (``get_inputs()[0].shape``).
    """
    kind = type(exc)
    if kind.__name__ not in RUN_ERRORS or not kind.__module__.startswith("onnxruntime"):
        return None
    words = " ".join(str(exc).split())
    parts = words.split(" : ", 3)  # "[ONNXRuntimeError] : 2 : INVALID_ARGUMENT : <reason>"
    reason = parts[3] if words.startswith("[ONNXRuntimeError]") and len(parts) == 4 else words
    return ModelError(
        f"{path}: ONNX Runtime cannot run a batch of {tuple(shape)} on this model, whose input "
        f"is {list(declared)} ({reason or kind.__name__})"
    )


QUANTISED_NODES = frozenset({"QuantizeLinear", "DequantizeLinear", "QLinearConv", "ConvInteger"})
"""ONNX operators that only a quantised (int8) model holds."""


def onnx_precision(path: Path) -> str:
    """``int8`` for a quantised ONNX model (``export --int8``), else ``fp32``."""
    import onnx  # only ONNX models need it, like onnxruntime

    graph = onnx.load(str(path), load_external_data=False).graph
    return "int8" if any(node.op_type in QUANTISED_NODES for node in graph.node) else "fp32"


def session_options(threads: int | None = None) -> Any:
    """ONNX Runtime CPU options: ``threads`` (torch's count by default), no spinning.

    An idle ONNX Runtime worker spins for a while after each run, holding a
    core. Beside torch (``export --int8`` times the two interleaved) that
    made torch fp32 read 54 ms where it runs in 2.4 ms, and restore's reader
    and writer threads compete with it for two cores; without spinning a
    540x360 GEA ran in 106 against 156 ms on a 2-core CPU (shared load).
    """
    import onnxruntime as ort  # here: only ONNX paths need it, and it loads slowly

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads or torch.get_num_threads()
    options.log_severity_level = 3
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return options
