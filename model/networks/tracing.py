"""Whether a forward is being exported or compiled: the layers' one data-dependent switch.

Layers with a faster eager formulation of the same function give exports the
plain one (:func:`exporting`); the flat-frame guard skips its masks in eager
CPU runs only (:func:`traced`), since an export or a compiled graph must
carry them whatever the example input was.
"""

import torch


def exporting() -> bool:
    """Whether the forward is being exported (ONNX, ``torch.export``, a TorchScript trace).

    Layers with a faster eager formulation of the same function give exports
    the plain one, made of the operators that exporters and quantisers know.
    """
    tracing = torch._C._get_tracing_state() is not None  # torch.jit.is_tracing, typed
    return tracing or torch.onnx.is_in_onnx_export() or torch.compiler.is_exporting()


def traced() -> bool:
    """Whether the forward is being exported or compiled: no data-dependent branch then."""
    return exporting() or torch.compiler.is_compiling()
