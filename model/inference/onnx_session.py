"""ONNX Runtime's side of restoring: session options, a restoring model's signature, its precision.

:class:`~lenspair.model.inference.backends.OnnxBackend` opens a session with
:func:`session_options`, refuses a file that is not a restoring model
(:func:`check_signature`) and tells an int8 file from an fp32 one
(:func:`onnx_precision`); ``export`` and ``export --int8`` time their files
with the same options.
"""

from pathlib import Path
from typing import Any

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
    for output in outputs:
        returned = list(output.shape or [])
        if len(returned) != 4 or returned[1] != shape[1]:
            raise ModelError(
                f"{path}: output {output.name} is {output.shape}, not (N, {shape[1]}, H, W) "
                f"like its input {shape}: not a restoring model (lenspair export writes one)"
            )
    return spec


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
