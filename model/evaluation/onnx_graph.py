"""The deployed network as an ONNX graph: its names, its dynamic axes, torch's two exporters.

:class:`DeployedNetwork` is what every export holds: one input ``image``
``(N, C, H, W)`` float32 in [0, 1], one output ``restored`` (the enhanced
image), the generator-only output used for training dropped.
:func:`write_onnx` runs one of torch's ONNX exporters on it with batch,
height and width dynamic and the exporters' narration silenced; checking
and timing the file is :mod:`lenspair.model.evaluation.export`'s, and the
int8 graph (:mod:`lenspair.model.evaluation.quantize`) is written here too.
"""

import contextlib
import logging
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from lenspair import __version__
from lenspair.model.networks.generator import DOWNSAMPLING_FACTOR
from lenspair.model.networks.padding import MIN_SIDE, pad_to_multiple

ONNX_OPSET = 18
INPUT_NAME = "image"
OUTPUT_NAME = "restored"


class DeployedNetwork(nn.Module):
    """The deployed network: ``forward(x)`` returns only the enhanced image."""

    def __init__(self, network: nn.Module) -> None:
        super().__init__()
        self.network = network

    def forward(self, x: Tensor) -> Tensor:
        """``(N, C, H, W)`` in [0, 1] -> restored ``(N, C, H, W)`` in [0, 1]."""
        output: Tensor = self.network(x)[1]
        return output


EXPORTERS = {
    "dynamo": "torch.onnx (dynamo)",
    "legacy": "torch.onnx (TorchScript-based)",
}


# Loggers of the ONNX tool chain that narrate every export: the graph optimiser's
# passes (about 130 INFO lines per GEA export) and torch's note that torchvision,
# whose operators lenspair never uses, is not installed.
_EXPORT_CHATTER = {
    "onnxscript": logging.WARNING,
    "onnx_ir": logging.WARNING,
    "torch.onnx._internal.exporter._registration": logging.ERROR,
}


@contextlib.contextmanager
def _quiet_exporters() -> Iterator[None]:
    """Silence the exporters' warnings and progress lines for the duration of one export.

    Their real failures still raise; only narration is dropped, so that
    ``lenspair export`` and the tradeoff's int8 row print lenspair's own lines.
    """
    loggers = {logging.getLogger(name): level for name, level in _EXPORT_CHATTER.items()}
    before = {logger: logger.level for logger in loggers}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # deprecation, tracer and shape-inference chatter
        for logger, level in loggers.items():
            logger.setLevel(max(level, logger.getEffectiveLevel()))
        try:
            yield
        finally:
            for logger, level in before.items():
                logger.setLevel(level)


DYNAMIC_AXES = {0: "batch", 2: "height", 3: "width"}
"""The exported input's and output's dynamic dimensions, by position in ``(N, C, H, W)``."""


def trace_image(image: Tensor) -> Tensor:
    """``image`` reflection-padded at the bottom/right to a multiple of the downsampling factor.

    What a dynamic graph is traced on. Traced at a side that is not a
    multiple (``export --size 130x98``), torch.export failed on the network's
    own padding of that side ("Cannot create Dim with inconsistent min=0,
    max=-oo"), the int8 export with it, and the fp32 one fell back to the
    TorchScript-based exporter. Traced at a multiple, the padding is recorded
    as arithmetic on the input's shape, so the graph pads and crops every
    other size as the checkpoint does.
    """
    return pad_to_multiple(image, DOWNSAMPLING_FACTOR)


def write_onnx(
    model: nn.Module, image: Tensor, path: Path, *, exporter: str, dynamic: bool = True
) -> None:
    """Run one of torch's ONNX exporters (batch dynamic; H and W too when ``dynamic``).

    ``dynamic=False`` fixes H and W at ``image``'s size: for a model only
    ever run at that size (a quantisation per size,
    :class:`~lenspair.model.evaluation.quantize.Int8Network`), whose export
    then takes about a third of the time. A dynamic graph is traced at
    ``image`` padded up to a multiple of the network's downsampling factor
    (:func:`trace_image`): torch.export cannot trace H and W dynamic at any
    other size, and the graph takes every size alike.

    The graph is traced on a batch of two: traced on one, torch.export
    specialises the batch dimension to 1 wherever an operation's shape
    depends on it (the full GEA's did), whatever ``dynamic_shapes`` asks,
    and ``restore`` with the ONNX file then fails on any batch or tile set.
    H and W were fixed too, so that ``restore`` ran every other frame size in
    tiles of the export's, each normalised by its own statistics: up to 109
    8-bit codes from the checkpoint's output at EuRoC's 752x480.
    """
    if dynamic:
        image = trace_image(image)
    image = image.expand(2, *image.shape[1:]).contiguous()
    axes = DYNAMIC_AXES if dynamic else {0: DYNAMIC_AXES[0]}
    names: dict[str, Any] = {
        "input_names": [INPUT_NAME],
        "output_names": [OUTPUT_NAME],
        "opset_version": ONNX_OPSET,
    }
    with _quiet_exporters():
        if exporter == "dynamo":
            dims = {0: torch.export.Dim("batch", min=1, max=64)}
            if dynamic:
                dims[2] = torch.export.Dim("height", min=MIN_SIDE)
                dims[3] = torch.export.Dim("width", min=MIN_SIDE)
            torch.onnx.export(
                model,
                (image,),
                str(path),
                **names,
                dynamo=True,
                verbose=False,  # no "[torch.onnx] Obtain model graph..." progress lines
                external_data=False,
                dynamic_shapes={"x": dims},
            )
        else:
            torch.onnx.export(
                model,
                (image,),
                str(path),
                **names,
                dynamo=False,
                dynamic_axes={INPUT_NAME: axes, OUTPUT_NAME: axes},
            )
    import onnx  # only ONNX exports need it

    graph = onnx.load(str(path))  # each exporter's file is mended in one load and save
    if exporter == "dynamo":
        _strip_trace(graph)
    else:
        _declare_output_shape(graph, tuple(image.shape), axes)
    _describe(graph, int(image.shape[1]), "fp32")
    onnx.save(graph, str(path))


def document_contract(path: Path, channels: int, precision: str) -> None:
    """Write what a caller must feed the model at ``path`` into it, in place (:func:`_describe`)."""
    import onnx  # only ONNX exports need it

    graph = onnx.load(str(path))
    _describe(graph, channels, precision)
    onnx.save(graph, str(path))


def _describe(model: Any, channels: int, precision: str) -> None:
    """Put what a caller must feed the ONNX ``model`` into it.

    The ONNX file goes where lenspair is not installed (a robot's node in
    C++): its ``doc_string`` says the contract in words and ``metadata_props``
    holds it as keys (``lenspair_version``, ``channels``, ``layout``,
    ``input_range``, ``min_side``, ``precision``), which ONNX Runtime shows as
    the session's ``get_modelmeta().custom_metadata_map``. An export carried
    none of it.
    """
    colours = "mono" if channels == 1 else "RGB"
    model.doc_string = (
        f"lenspair {__version__} restoring network ({colours}, {precision}). Input "
        f"'{INPUT_NAME}': float32 (N, {channels}, H, W), values in [0, 1], H and W at "
        f"least {MIN_SIDE} (any size: it pads inside). Output '{OUTPUT_NAME}': the same "
        "shape, values in [0, 1]."
    )
    properties = {
        "lenspair_version": __version__,
        "channels": str(channels),
        "layout": "NCHW",
        "input_range": "0..1",
        "min_side": str(MIN_SIDE),
        "precision": precision,
    }
    kept = [p for p in model.metadata_props if p.key not in properties]
    del model.metadata_props[:]
    model.metadata_props.extend(kept)
    for key, value in properties.items():
        model.metadata_props.add(key=key, value=value)


def _declare_output_shape(model: Any, shape: tuple[int, ...], axes: dict[int, str]) -> None:
    """Declare the ONNX ``model``'s output shape as the input's (``axes``: the dynamic ones).

    The TorchScript-based exporter names every output dimension it cannot
    infer (``Addrestored_dim_1``), the channels too, and ``restore`` refuses a
    model whose output channels are not its input's.
    """
    for output in model.graph.output:
        for index, dim in enumerate(output.type.tensor_type.shape.dim):
            if index in axes:
                dim.dim_param = axes[index]
            elif index < len(shape):
                dim.dim_value = shape[index]


def _strip_trace(model: Any) -> None:
    """Drop what the dynamo exporter notes on each node of the ONNX ``model``.

    Its ``metadata_props`` hold Python stack traces (absolute paths of the
    machine that exported, its virtual environment's too) and reprs with
    memory addresses (``<function sym_min at 0x7f...>``): an export shipped to
    a robot carried the build machine's layout, and two exports of one
    checkpoint differed in bytes. The graph and weights are untouched.
    """
    graphs = [model.graph]
    while graphs:
        graph = graphs.pop()
        for node in graph.node:
            del node.metadata_props[:]
            node.doc_string = ""
            graphs += [a.g for a in node.attribute if a.HasField("g")]
            graphs += [g for a in node.attribute for g in a.graphs]
