"""Inference backends: a torch checkpoint or an exported ONNX model, one call signature.

A backend maps a batch ``(N, C, H, W)`` ``float32`` in [0, 1] (numpy) to the
restored batch of the same shape, dtype and range. Any ``H, W >= 8`` is
accepted by the torch network (it reflection-pads to a multiple of 4 and
crops back, as ``eval`` does), and by an ONNX file from ``lenspair export``
(its height and width are dynamic). An ONNX file of a fixed ``H x W``
(``fixed_size``: exported before sizes were dynamic, or by another tool)
runs other sizes in tiles of its own (:mod:`lenspair.model.inference.tiling`),
which differ from the checkpoint's output at the seams: said once, and
recorded (:class:`ForcedTiles`); a fixed batch size (another tool's) runs in pieces.

Precision: ``--precision auto|fp32|bf16|fp16`` for checkpoints; ``auto`` is the
hardware-driven choice that ``train``/``eval``/``tradeoff``/``export`` share
(:func:`resolve_precision`). An ONNX model runs at the precision it was
exported at: fp32, or int8 from ``lenspair export --int8``; ``--precision``
may only name that one (or ``auto``).
"""

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from lenspair.model.checkpoint import load_model
from lenspair.model.errors import ModelError, is_out_of_memory
from lenspair.model.evaluation.latency import autocast_context, tune_allocator
from lenspair.model.inference import onnx_session
from lenspair.model.inference.options import MIN_TILE, PRECISIONS
from lenspair.model.precision import choose_precision

log = logging.getLogger(__name__)


class Backend(Protocol):
    """What the restore pipeline needs from a network."""

    @property
    def channels(self) -> int:
        """Image channels the network takes and returns (1 mono, 3 RGB)."""

    @property
    def fixed_size(self) -> tuple[int, int] | None:
        """``(H, W)`` the model only accepts, or None for any size."""

    @property
    def forced_tiles(self) -> "ForcedTiles | None":
        """Frames run in tiles of ``fixed_size``, or None for a model of any size.

        Read only where ``fixed_size`` is not None.
        """

    @property
    def description(self) -> str:
        """One line: file, runtime, device, precision."""

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        """``(N, C, H, W)`` float32 in [0, 1] -> restored, same shape, float32 in [0, 1]."""


@dataclass
class ForcedTiles:
    """The frame sizes a model of a fixed size has run in tiles of its size; the first is told.

    Such a model only takes its own ``H x W``, so other sizes run in
    overlapping tiles of it, each of which the network normalises by its own
    statistics (instance norm): those frames differ from the checkpoint's
    whole-frame output, most at the tile seams. :meth:`note` says so in one
    warning line, once per run (:meth:`start`; a
    :class:`~lenspair.model.inference.restorer.Restorer` warns once), and
    ``restore`` records :attr:`tile` in its report.

    Attributes:
        model: the model file, for the warning.
        tile: the model's ``(H, W)``.
        frame_sizes: ``(H, W)`` of the frames run in tiles since :meth:`start`, in order met.
    """

    model: str
    tile: tuple[int, int]
    frame_sizes: list[tuple[int, int]] = field(default_factory=list)

    def start(self) -> None:
        """Begin a run: the next frame of another size is told again."""
        self.frame_sizes.clear()

    def note(self, frame_size: tuple[int, int]) -> None:
        """Record that frames of ``frame_size`` ``(H, W)`` run in tiles; warn at the run's first."""
        if frame_size in self.frame_sizes:
            return
        if not self.frame_sizes:
            log.warning(
                "%s: frames of %dx%d are run in tiles of the model's fixed size %dx%d, and "
                "results differ from the checkpoint at the tile seams; export it again "
                "(lenspair export) to run every size whole",
                self.model,
                frame_size[1],
                frame_size[0],
                self.tile[1],
                self.tile[0],
            )
        self.frame_sizes.append(frame_size)

    @property
    def tile_text(self) -> str:
        """The tile as ``WxH``."""
        return f"{self.tile[1]}x{self.tile[0]}"


def check_batch(batch: np.ndarray, channels: int) -> np.ndarray:
    """``batch`` as a contiguous float32 ``(N, channels, H, W)`` array, or a one-line error.

    Integer frames (0..255) would run unscaled and come out clipped white; a
    3-D array failed inside torch with a traceback about memory formats.

    Raises:
        ModelError: not a floating-point ``(N, C, H, W)`` batch of the network's channels.
    """
    if not np.issubdtype(batch.dtype, np.floating):
        raise ModelError(
            f"a batch of {batch.dtype}: expected float32 in [0, 1] "
            "(lenspair.model.inference.tiling.to_batch converts frames)"
        )
    if batch.ndim != 4 or batch.shape[1] != channels:
        raise ModelError(f"a batch of shape {batch.shape}: expected (N, {channels}, H, W)")
    return np.ascontiguousarray(batch, dtype=np.float32)


def resolve_precision(choice: str, device: torch.device) -> str:
    """``--precision`` to what runs: ``fp32`` or ``bf16`` (``fp16`` on CUDA).

    ``auto`` is the shared hardware-driven decision of
    :func:`lenspair.model.precision.choose_precision` (the fastest native
    precision; emulated bf16 is never chosen); the decision and its reason are
    logged once.

    Raises:
        ModelError: an unknown choice, or one the device cannot run.
    """
    if choice not in PRECISIONS:
        raise ModelError(f"--precision: expected one of {', '.join(PRECISIONS)}, got {choice!r}")
    decision = choose_precision(choice, device, "infer")
    log.info("%s", decision.summary())
    return decision.precision


@dataclass
class TorchBackend:
    """A checkpoint's network in eval mode (the enhanced output only).

    Args:
        network: forward(x) -> (generator_out, enhanced_out), prepared by
            :func:`deploy`.
        channels: its image channels.
        device: where it runs.
        precision: ``fp32`` or ``bf16`` (autocast).
        path: the checkpoint, for the description.
    """

    network: torch.nn.Module
    channels: int
    device: torch.device
    precision: str = "fp32"
    path: Path = Path("checkpoint")

    @property
    def fixed_size(self) -> tuple[int, int] | None:
        """Any size works (the network pads to a multiple of 4)."""
        return None

    @property
    def forced_tiles(self) -> ForcedTiles | None:
        """None: nothing is tiled by force."""
        return None

    @property
    def description(self) -> str:
        """One line for logs and the report."""
        return f"torch checkpoint {self.path} on {self.device} ({self.precision})"

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        """Run the network on a numpy batch (see :class:`Backend`).

        A batch that does not fit in memory runs again one frame at a time;
        a single frame (or tile: ``run_tiled`` calls this with one tile of each
        frame, or a few small ones) that does
        not fit is a :class:`ModelError` that says how to restore it (tiles of
        the largest power of two up to half its longer side; a fp32 frame needs
        about 330 MB per megapixel on the CPU), not an allocator's traceback. The retry runs
        after the failed call's frames are gone (its traceback held the batch's
        tensors), with CUDA's cache emptied.
        """
        return _frame_by_frame_on_failure(self._run, batch, self.path, self.device, self.precision)

    @torch.inference_mode()
    def _run(self, batch: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(check_batch(batch, self.channels)).to(self.device)
        if self.device.type == "cpu":
            x = x.contiguous(memory_format=torch.channels_last)
        with autocast_context(self.device, self.precision):
            output = self.network(x)[1]
        return np.asarray(output.float().clamp(0.0, 1.0).cpu().numpy(), dtype=np.float32)


def memory_error(where: object, height: int, width: int, runs_on: str) -> ModelError:
    """The error of one frame (or tile) too large for memory, with the ``--tile`` to use.

    Tiles of the largest power of two up to half its longer side; a fp32
    frame needs about 330 MB per megapixel on the CPU.
    """
    tile = max(MIN_TILE, 1 << (max(2, max(height, width)) // 2).bit_length() - 1)
    return ModelError(
        f"{where}: out of memory restoring one {width}x{height} image on {runs_on}; restore "
        f"in tiles smaller than that (--tile {tile}, or a smaller --tile if this was one)"
    )


def _frame_by_frame_on_failure(
    run: Callable[[np.ndarray], np.ndarray],
    batch: np.ndarray,
    path: Path,
    device: torch.device,
    precision: str,
) -> np.ndarray:
    """``run(batch)``; out of memory, again one frame at a time; one frame: :func:`memory_error`.

    The retry runs after the failed call's frames are gone (its traceback
    held the batch's tensors), with CUDA's cache emptied.
    """
    try:
        return run(batch)
    except Exception as exc:  # torch, numpy and ONNX Runtime each raise their own type
        if not is_out_of_memory(exc):
            raise
    if device.type == "cuda":
        torch.cuda.empty_cache()
    if len(batch) > 1:
        parts = [
            _frame_by_frame_on_failure(run, batch[i : i + 1], path, device, precision)
            for i in range(len(batch))
        ]
        return np.concatenate(parts)
    height, width = batch.shape[-2:]
    raise memory_error(path, height, width, f"{device} ({precision})")


class OnnxBackend:
    """An ONNX model run by ONNX Runtime (input ``image``, output ``restored``).

    Args:
        path: the ``.onnx`` file (from ``lenspair export``).
        device: ``cuda`` uses the CUDA execution provider (must be installed).
        threads: intra-op CPU threads (``torch.get_num_threads()`` by default).

    Raises:
        ModelError: unreadable model, not a restoring model's signature (one
            image batch in, batches of its channels out: see
            :func:`~lenspair.model.inference.onnx_session.check_signature`),
            or CUDA asked for and not available in onnxruntime.
    """

    def __init__(self, path: Path, device: torch.device, threads: int | None = None) -> None:
        import onnxruntime as ort  # only ONNX models need it: checkpoints do not load it

        self.path = Path(path)
        if not self.path.is_file():
            raise ModelError(f"{path}: ONNX model not found")
        providers = ["CPUExecutionProvider"]
        if device.type == "cuda":
            if "CUDAExecutionProvider" not in ort.get_available_providers():
                raise ModelError(
                    "--device cuda: this onnxruntime has no CUDA provider "
                    "(install onnxruntime-gpu) or use --device cpu"
                )
            providers.insert(0, "CUDAExecutionProvider")
        options = onnx_session.session_options(threads)
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=providers)
        except Exception as exc:  # onnxruntime raises its own assorted types
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ModelError(f"{path}: cannot load ONNX model ({first})") from None
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        spec = self.spec = onnx_session.check_signature(self.path, inputs, outputs)
        self.input_name, self.batch_size = spec.name, onnx_session.fixed_batch(spec)
        self.device = device
        self._channels = int(spec.shape[1])
        height, width = spec.shape[2], spec.shape[3]
        fixed = isinstance(height, int) and isinstance(width, int)
        self._fixed = (int(height), int(width)) if fixed else None
        self._forced = ForcedTiles(str(self.path), self._fixed) if self._fixed else None
        self.precision = onnx_session.onnx_precision(self.path)

    @property
    def channels(self) -> int:
        """Channels of the model's input."""
        return self._channels

    @property
    def fixed_size(self) -> tuple[int, int] | None:
        """The model's only ``(H, W)``, or None when it takes any size (``lenspair export``'s)."""
        return self._fixed

    @property
    def forced_tiles(self) -> ForcedTiles | None:
        """The frames run in tiles of :attr:`fixed_size` (None when the model takes any size)."""
        return self._forced

    @property
    def description(self) -> str:
        """One line for logs and the report."""
        return f"ONNX Runtime {self.path} on {self.device} ({self.precision})"

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        """Run the session on a numpy batch (see :class:`Backend`).

        Out of memory, as :meth:`TorchBackend.__call__`: frame by frame, then
        a :class:`ModelError` with the ``--tile`` to use.

        Raises:
            ModelError: ONNX Runtime refused the batch (``onnx_session.run_error``), or
                the model returned another shape than the batch's (a model of any size
                that shrinks some sizes: its frames fail, rather than being written at
                the wrong size or transposed into a traceback).
        """
        output = _frame_by_frame_on_failure(
            self._run, batch, self.path, self.device, self.precision
        )
        if output.shape != batch.shape:
            raise ModelError(
                f"{self.path}: returned {output.shape} for a batch of {batch.shape}; a restoring "
                "model returns its input's shape (lenspair export writes one)"
            )
        return np.clip(np.asarray(output, dtype=np.float32), 0.0, 1.0)

    def _run(self, batch: np.ndarray) -> np.ndarray:
        batch = check_batch(batch, self.channels)  # in pieces of a fixed batch size, if any
        return onnx_session.run_in_pieces(self._run_piece, batch, self.batch_size)

    def _run_piece(self, batch: np.ndarray) -> np.ndarray:
        try:
            return np.asarray(self.session.run(None, {self.input_name: batch})[0])
        except Exception as exc:  # onnxruntime's own types; out of memory is the caller's
            error = onnx_session.run_error(self.path, exc, batch.shape, self.spec.shape)
            if error is None or is_out_of_memory(exc):
                raise
            raise error from None


def open_backend(
    path: Path, device: torch.device | str, precision: str = "auto", tune: bool = True
) -> Backend:
    """A backend for a checkpoint (``.pt``) or an ONNX model (``.onnx``).

    Args:
        path: the model file; ``.onnx`` selects ONNX Runtime, anything else
            is read as a lenspair checkpoint.
        device: from ``--device`` (resolved in the CLI), or its name (``"cpu"``).
        precision: ``auto``/``fp32``/``bf16``/``fp16``; an ONNX model runs at
            its own (fp32, or int8), which ``auto`` or that name accept.
        tune: on the CPU, tune glibc's allocator for the whole process
            (:func:`deploy`).

    Raises:
        ModelError: unreadable model, or another precision asked of an ONNX model.
    """
    path, device = Path(path), torch.device(device)
    if path.suffix.lower() == ".onnx":
        backend = OnnxBackend(path, device)
        if precision not in ("auto", backend.precision):
            raise ModelError(
                f"--precision {precision}: {path} is an {backend.precision} ONNX model and "
                f"runs as one; use --precision auto, or a checkpoint (.pt) to choose"
            )
        return backend
    loaded = load_model(path, device)  # first: a bad file is the only line a user sees
    resolved = resolve_precision(precision, device)
    channels = loaded.config.model.channels or 1
    return TorchBackend(deploy(loaded.network, device, tune), channels, device, resolved, path)


def deploy(network: torch.nn.Module, device: torch.device, tune: bool = True) -> torch.nn.Module:
    """Prepare ``network`` to run as ``eval``'s latency measures it (in place, eval mode).

    On the CPU: channels-last weights (oneDNN's preferred layout) and, with
    ``tune``, glibc told to keep freed activations for the whole process
    (see :mod:`lenspair.model.evaluation.latency`).
    """
    network.to(device).eval()
    if device.type == "cpu":
        if tune:
            tune_allocator()
        network.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    return network
