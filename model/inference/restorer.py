"""Restore frames in your own process: a ROS node, a camera driver's callback, a notebook.

``lenspair restore`` runs over files, folders and bags; a robot that must
clean each frame as it arrives calls the network itself::

    from lenspair.model.inference.restorer import Restorer

    restorer = Restorer("runs/gea/checkpoints/best.pt")  # or an exported .onnx
    clean = restorer(frame)  # numpy (H, W) or (H, W, 3), uint8 or uint16: same out

The frame goes through exactly what ``restore`` does to each frame: the
16-bit words of a 10- or 12-bit camera are taken on the full scale and
written back in the camera's words (:class:`~lenspair.core.bitdepth.RunningDepth`,
told from the frames seen so far, as for a recording), the precision is the
hardware's fastest native one unless given, and ``tile`` restores large
frames in overlapping tiles. Frames are RGB (not OpenCV's BGR) when the
network is a colour one; a mono network refuses colour frames and the
reverse, with a one-line :class:`~lenspair.model.errors.ModelError`, as
``restore`` does: converting silently would hide a wrong network.

One ``Restorer`` may serve several threads (two camera callbacks): calls
hold no state but the running depth. For 16-bit cameras of different
depths, give each camera its own ``Restorer``, or ``bits=`` its depth: a
12-bit camera's frames after a 16-bit one's were taken as 16-bit words
(sixteen times too dark). The first call at a new frame size also chooses the
CPU's kernels (about twice a call's time here); a node can restore one
blank frame of its size at start-up.
"""

from collections.abc import Iterable
from pathlib import Path

import numpy as np
import torch

from lenspair.core.bitdepth import BIT_DEPTHS, RunningDepth, is_bit_depth
from lenspair.core.device import resolve_device
from lenspair.core.numbers import is_whole_number
from lenspair.core.pixels import check_image, is_one_frame
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import Backend, open_backend
from lenspair.model.inference.input_checks import frame_problem
from lenspair.model.inference.options import DEFAULT_OVERLAP
from lenspair.model.inference.restore_options import RestoreOptions, check_options
from lenspair.model.inference.tiling import restore_images


class Restorer:
    """A trained network, ready to restore frames one call at a time.

    Args:
        model: a lenspair checkpoint (``.pt``) or a model from ``lenspair
            export`` (``.onnx``).
        device: ``auto`` (CUDA when available), ``cpu``, ``cuda``, ``cuda:N`` or a
            ``torch.device``.
        precision: ``auto`` (the fastest precision the hardware runs
            natively), ``fp32``, ``bf16`` or ``fp16``; ONNX models run as
            exported.
        tile: restore in overlapping square tiles of this side (pixels, at
            least 16 and more than ``overlap``) to bound memory on large
            frames; None: whole frames.
        overlap: pixels shared by neighbouring tiles (the ``--overlap`` of
            ``restore``, default 32; errors name the options as it does).
        bits: the bits a camera's ``uint16`` frames hold (10, 12 or 16); they
            are widened to the full scale and written back in the camera's
            words, values above the depth saturating. None: told from the
            frames seen so far (:class:`~lenspair.core.bitdepth.RunningDepth`),
            so one camera per ``Restorer`` (module docstring).
        tune_allocator: on the CPU, tell glibc to keep freed activations
            (:func:`lenspair.model.evaluation.latency.tune_allocator`): the
            fp32 network ran 76 -> 59 ms at 540x360 here, but the setting is
            the whole process's, and memory the host frees stays with the
            process. ``False`` leaves the allocator alone.

    Raises:
        ModelError: the model cannot be read, or a setting is invalid.
        LenspairError: ``device`` cannot be used here.
    """

    def __init__(
        self,
        model: str | Path,
        device: str | torch.device = "auto",
        precision: str = "auto",
        tile: int | None = None,
        overlap: int = DEFAULT_OVERLAP,
        bits: int | None = None,
        tune_allocator: bool = True,
    ) -> None:
        """Load ``model`` on ``device``; see the class docstring."""
        if bits is not None and not is_bit_depth(bits):
            raise ModelError(f"Restorer: bits must be one of {BIT_DEPTHS}, got {bits!r}")
        for name, value in (("tile", tile), ("overlap", overlap)):
            if not is_whole_number(value) and not (value is None and name == "tile"):
                raise ModelError(f"Restorer: {name} must be a whole number of pixels: {value!r}")
        self.backend: Backend = open_backend(
            Path(model), resolve_device(device), precision, tune_allocator
        )
        check_options(RestoreOptions(tile=tile, overlap=overlap), self.backend)  # as restore's
        self.tile = None if tile is None else int(tile)
        self.overlap = int(overlap)
        self.depth = RunningDepth(f"the frames given to Restorer({Path(model).name})")
        self.bits = None if bits is None else int(bits)

    @property
    def channels(self) -> int:
        """Channels of the frames the network takes: 1 (mono) or 3 (RGB)."""
        return self.backend.channels

    @property
    def description(self) -> str:
        """One line: the model file, runtime, device and precision."""
        return self.backend.description

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Restore one frame: ``(H, W)`` or ``(H, W, 3)``, ``uint8``/``uint16``, same out.

        Raises:
            ModelError: not such a frame, channels other than the network's,
                or smaller than 8x8 pixels.
        """
        return self.restore_batch([image])[0]

    def restore_batch(self, images: Iterable[np.ndarray]) -> list[np.ndarray]:
        """Restore frames of one shape and dtype in one batch (faster on a GPU).

        Raises:
            ModelError: as :meth:`__call__`, or frames that differ in shape
                or bit depth.
        """
        if isinstance(images, np.ndarray) and is_one_frame(images):
            raise ModelError(
                f"restore_batch takes a list of frames, got one {images.shape} array: "
                "restore_batch([frame]), or restorer(frame)"
            )
        frames = [np.asarray(image) for image in images]  # any iterable, a generator too
        if not frames:
            return []
        for index, frame in enumerate(frames):
            self._check(frame, f"frame {index}")
        if len({(frame.shape, frame.dtype) for frame in frames}) > 1:  # before depth.see
            raise ModelError(
                "restore_batch: frames of different shapes or bit depths "
                f"({sorted({f'{f.shape} {f.dtype}' for f in frames})}); restore them apart"
            )
        # each frame at the depth known when it comes, as one by one: a frame that raises
        # the depth must not change how the frames before it scale
        runs = [(self.bits, frames)] if self.bits is not None else self._runs(frames)
        return [
            restored
            for bits, run in runs
            for restored in restore_images(self.backend, run, bits, self.tile, self.overlap)
        ]

    def _runs(self, frames: list[np.ndarray]) -> list[tuple[int, list[np.ndarray]]]:
        """``frames`` in runs of one running depth, each at the depth known when it came."""
        runs: list[tuple[int, list[np.ndarray]]] = []
        for frame in frames:
            self.depth.see(frame)
            if runs and runs[-1][0] == self.depth.bits:
                runs[-1][1].append(frame)
            else:
                runs.append((self.depth.bits, [frame]))
        return runs

    def _check(self, image: np.ndarray, name: str) -> None:
        try:
            check_image(image, name)
        except ValueError as exc:
            raise ModelError(str(exc)) from None
        problem = frame_problem(name, image, self.channels)
        if problem is not None:
            raise ModelError(problem)
