"""Export a trained network to ONNX and TorchScript, checked against torch.

The exported graph is the deployed network: one input ``image``
``(N, C, H, W)`` float32 in [0, 1] and one output ``restored`` (the
enhanced image, same shape); the generator-only output used for training is
dropped. Batch, height and width are all dynamic in ONNX: the network pads
to a multiple of 4 from the input's shape with no branch on it
(:func:`~lenspair.model.networks.padding.pad_to_multiple`), so one file runs
any frame of ``H, W >= 8`` whole, as the checkpoint does. A TorchScript trace
replays the same operations at any size too.

``--size`` (540x360 by default) is the size each export is traced, checked
and timed at (an ONNX graph is traced at it padded up to a multiple of 4,
:func:`~lenspair.model.evaluation.onnx_graph.trace_image`, the only sizes
torch.export traces dynamic): it is run on a random image
(seeded) and a flat one at that size and again at a second size with odd
sides, about half of it (:func:`other_size`, not a multiple of the network's
stride), and compared
with the torch output: the largest absolute difference is reported. ONNX
files are checked and timed with ``onnxruntime`` when it is installed (``pip
install 'onnxruntime'``); without it the file is still written and the
report says it could not be checked. torch's new ``dynamo`` exporter needs
``onnxscript``; when that is missing the TorchScript-based exporter is used.
"""

import errno
import functools
import importlib.util
import io
import logging
import statistics
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from lenspair.core.errors import first_line
from lenspair.core.fsutil import atomic_write, atomic_write_bytes
from lenspair.model.checkpoint import LoadedModel, load_model
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.onnx_graph import (
    EXPORTERS,
    INPUT_NAME,
    DeployedNetwork,
    write_onnx,
)
from lenspair.model.inference.onnx_session import session_options
from lenspair.model.networks.padding import MIN_SIDE

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ExportCheck:
    """What one export produced and how well it matches torch.

    Attributes:
        format: ``onnx`` or ``torchscript``.
        path: the written file.
        size: ``WxH`` it was checked and timed at (the file takes any size).
        exporter: which exporter wrote it.
        max_abs_diff: largest |export - torch| on the check images at every size of
            ``sizes_checked`` (``None``: not checked).
        runtime_median_ms: median batch-1 latency in its runtime (``None``: not timed).
        runtime_p90_ms: 90th percentile of the same.
        threads: CPU threads of the timed runtime.
        note: anything the user must know (e.g. onnxruntime missing).
        sizes_checked: ``WxH`` of every size compared with torch (``size`` first).

    """

    format: str
    path: str
    size: str
    exporter: str
    max_abs_diff: float | None
    runtime_median_ms: float | None = None
    runtime_p90_ms: float | None = None
    threads: int | None = None
    note: str = ""
    sizes_checked: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """Plain data for JSON."""
        return asdict(self)

    def summary(self) -> str:
        """One line for people."""
        diff = "not checked" if self.max_abs_diff is None else f"{self.max_abs_diff:.3g}"
        if self.max_abs_diff is not None and self.sizes_checked:
            diff += f" (at {', '.join(self.sizes_checked)})"
        text = (
            f"{self.format}: {self.path} ({self.size}, any size, {self.exporter}); "
            f"max |diff| vs torch {diff}"
        )
        if self.runtime_median_ms is not None:
            text += (
                f"; {self.runtime_median_ms:.2f} ms median (p90 {self.runtime_p90_ms:.2f}, "
                f"{self.threads} threads)"
            )
        return text + (f"; {self.note}" if self.note else "")


def check_image(channels: int, size: tuple[int, int]) -> Tensor:
    """The seeded random ``(1, C, H, W)`` image exports are traced and timed on."""
    generator = torch.Generator().manual_seed(0)
    return torch.rand(1, channels, size[0], size[1], generator=generator)


def check_images(channels: int, size: tuple[int, int]) -> Tensor:
    """``(2, C, H, W)``: :func:`check_image` and a flat mid-grey frame, to check exports on.

    A flat frame is the hard case: kernels that round differently from the
    reference turned its zero-variance norms into blotches
    (:mod:`lenspair.model.networks.layers`).
    """
    flat = torch.full((1, channels, size[0], size[1]), 0.5)
    return torch.cat([check_image(channels, size), flat])


def other_size(size: tuple[int, int]) -> tuple[int, int]:
    """A second ``(H, W)`` to check exports at: about half of ``size``, both sides odd.

    Odd sides are not multiples of the network's stride (4), so the check goes
    through its padding and cropping; a side is at least ``MIN_SIDE + 1`` (9),
    and a size whose halves are that small is checked at its sides plus 3 instead.
    """
    half = tuple(max(MIN_SIDE + 1, side // 2 | 1) for side in size)
    if half == tuple(size):
        half = tuple(side + 3 for side in size)
    return half[0], half[1]


def _size_text(size: tuple[int, int]) -> str:
    """``(H, W)`` as ``WxH``, the way ``--size`` is written."""
    return f"{size[1]}x{size[0]}"


def _time(run: Any, runs: int, warmup: int = 3) -> tuple[float, float]:
    times = []
    for index in range(warmup + runs):
        start = time.perf_counter()
        run()
        if index >= warmup:
            times.append((time.perf_counter() - start) * 1000.0)
    return statistics.median(times), float(np.percentile(times, 90.0))


_DISK_REFUSALS = frozenset(
    {errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EROFS, errno.EIO, errno.EACCES, errno.EPERM}
)
"""A file system refusing the write (full, read-only, another user's folder): the other
exporter would fail the same."""


def _file_system_error(exc: BaseException) -> OSError | None:
    """The disk's refusal (:data:`_DISK_REFUSALS`) in ``exc`` or in what led to it, else None.

    The dynamo exporter wraps the error its file write raised.
    """
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, OSError) and current.errno in _DISK_REFUSALS:
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None


def export_onnx(
    network: nn.Module,
    channels: int,
    path: Path,
    size: tuple[int, int] = (360, 540),
    runs: int = 20,
) -> ExportCheck:
    """Write ``network`` as ONNX, then check (and time) it with onnxruntime if installed.

    The file takes any batch, height and width; it is checked against torch at
    ``size`` and at :func:`other_size` of it, and timed at ``size``.

    Args:
        network: forward(x) -> (generator_out, enhanced_out), on the CPU.
        channels: input channels.
        path: destination ``.onnx`` file.
        size: ``(H, W)`` the graph is checked and timed at, and traced at
            padded up to a multiple of 4 (:func:`write_onnx`).
        runs: timed onnxruntime runs (after warm-up).

    Raises:
        ModelError: the export failed (message from the exporter).

    """
    model = DeployedNetwork(network).cpu().eval()
    image = check_image(channels, size)
    exporters = ["dynamo"] if importlib.util.find_spec("onnxscript") is not None else []
    exporters.append("legacy")  # torch's TorchScript-based exporter needs no onnxscript
    exporter = ""
    for attempt in exporters:
        try:
            atomic_write(
                Path(path), functools.partial(write_onnx, model, image, exporter=attempt), ".onnx"
            )
            exporter = EXPORTERS[attempt]
            break
        except Exception as exc:  # exporters raise many types; report one line
            if (refused := _file_system_error(exc)) is not None:
                raise refused from exc  # a full disk: the other exporter would fail the same
            first = first_line(exc)
            if attempt == exporters[-1]:
                raise ModelError(f"ONNX export failed: {first}") from exc
            log.warning("%s failed (%s); trying %s", EXPORTERS[attempt], first, exporters[-1])
    size_text = _size_text(size)
    if importlib.util.find_spec("onnxruntime") is None:
        note = "onnxruntime is missing (a lenspair dependency): written, not checked"
        return ExportCheck("onnx", str(path), size_text, exporter, None, note=note)
    # here, not at the top: a missing or broken onnxruntime degrades to a note
    import onnxruntime as ort

    threads = torch.get_num_threads()
    options = session_options(threads)
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    feed = {INPUT_NAME: image.numpy()}
    sizes = (size, other_size(size))
    diff = 0.0
    for checked_size in sizes:
        checked = check_images(channels, checked_size)
        with torch.inference_mode():
            expected = model(checked).numpy()
        actual = session.run(None, {INPUT_NAME: checked.numpy()})[0]
        diff = max(diff, float(np.max(np.abs(actual - expected))))
    median, p90 = _time(lambda: session.run(None, feed), runs)
    return ExportCheck(
        "onnx",
        str(path),
        size_text,
        exporter,
        diff,
        median,
        p90,
        threads,
        sizes_checked=tuple(_size_text(checked_size) for checked_size in sizes),
    )


def export_torchscript(
    network: nn.Module,
    channels: int,
    path: Path,
    size: tuple[int, int] = (360, 540),
    runs: int = 20,
) -> ExportCheck:
    """Trace ``network`` to TorchScript, reload the file and check it against torch.

    The trace records shapes as operations on the input's, so the file takes
    any size; it is checked at ``size`` and at :func:`other_size` of it, and
    timed at ``size``.

    Raises:
        ModelError: tracing failed.

    """
    model = DeployedNetwork(network).cpu().eval()
    image = check_image(channels, size)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")  # deprecation and tracer chatter
            traced = torch.jit.trace(model, (image,), check_trace=False)
    except Exception as exc:
        raise ModelError(f"TorchScript trace failed: {str(exc).strip().splitlines()[0]}") from exc

    # Serialised in memory first: torch.jit.save writing a file that the disk
    # refuses part-way aborts the process from C++ ("terminate called ...").
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.jit.save(traced, buffer)
    atomic_write_bytes(Path(path), buffer.getvalue())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        loaded = torch.jit.load(str(path), map_location="cpu")
    sizes = (size, other_size(size))
    with torch.no_grad():
        diff = 0.0
        for checked_size in sizes:
            checked = check_images(channels, checked_size)
            diff = max(diff, float((loaded(checked) - model(checked)).abs().max()))
        median, p90 = _time(lambda: loaded(image), runs)
    return ExportCheck(
        "torchscript",
        str(path),
        _size_text(size),
        "torch.jit.trace",
        diff,
        median,
        p90,
        torch.get_num_threads(),
        sizes_checked=tuple(_size_text(checked_size) for checked_size in sizes),
    )


def export_checkpoint(
    checkpoint: Path | LoadedModel,
    onnx_path: Path | None,
    torchscript_path: Path | None,
    size: tuple[int, int] = (360, 540),
) -> list[ExportCheck]:
    """Export a checkpoint's network to ONNX and/or TorchScript, each checked.

    Args:
        checkpoint: its path, or the model already loaded from it (on the CPU).
        onnx_path: where the ONNX file goes (None: none).
        torchscript_path: where the TorchScript file goes (None: none).
        size: ``(height, width)`` the exports are checked and timed at.

    Raises:
        ModelError: unreadable checkpoint, nothing to export, or a failed export.

    """
    if onnx_path is None and torchscript_path is None:
        raise ModelError("nothing to export: give --onnx and/or --torchscript")
    loaded = checkpoint if isinstance(checkpoint, LoadedModel) else load_model(checkpoint, "cpu")
    channels = loaded.config.model.channels or 1
    checks = []
    try:
        sizes = f"{_size_text(size)} and {_size_text(other_size(size))}"
        if onnx_path is not None:
            log.info("exporting %s, then checking and timing it at %s", onnx_path, sizes)
            checks.append(export_onnx(loaded.network, channels, onnx_path, size))
            log.debug("%s", checks[-1].summary())  # the CLI prints it
        if torchscript_path is not None:
            log.info("exporting %s, then checking and timing it at %s", torchscript_path, sizes)
            checks.append(export_torchscript(loaded.network, channels, torchscript_path, size))
            log.debug("%s", checks[-1].summary())  # the CLI prints it
    except (RuntimeError, MemoryError) as exc:
        if isinstance(exc, RuntimeError) and "allocate" not in str(exc):
            raise
        raise ModelError(
            f"--size {size[1]}x{size[0]}: not enough memory to export at this size "
            f"({str(exc).splitlines()[0][:160]}); give a smaller --size (it is only the "
            "size the export is checked and timed at: the model takes any size)"
        ) from None
    return checks
