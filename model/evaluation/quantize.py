"""int8 inference: ONNX Runtime static quantisation calibrated on dataset images.

The int8 model is the fp32 ONNX export (:mod:`lenspair.model.evaluation.export`)
quantised by ``onnxruntime.quantization.quantize_static``: QDQ format, int8
weights per output channel (symmetric), uint8 activations with MinMax ranges
calibrated on obstructed images of the dataset (by default 16, evenly
spaced). Only the convolutions are quantised (:data:`QUANTISED_OPS`): ONNX
Runtime's CPU provider fuses the QDQ pairs around each into an integer
convolution, which uses VNNI dot products where the CPU has them; instance
norms (exported as ONNX ``InstanceNormalization``), pads, pools, adds and
the final clamp stay in float.

Why ONNX Runtime and not PyTorch's PT2E ``X86InductorQuantizer`` (torchao):
``python -m benchmarks.bench_int8`` measures both in one run (GEA 540x360
mono, batch 1, the shipped weights on a held-out photograph, against fp32
torch channels-last). Which is faster depends on the CPU, and single runs of
ten on the same 2-core AMD EPYC with ``avx512_vnni`` have put either path
between about 0.75x and 1.45x fp32's speed (``docs/results/cpu_amd_epyc.md``
gives one run); on an Intel Xeon without AMX, one run: ONNX Runtime 0.72x,
PT2E 1.35x (``docs/results/cpu_intel_xeon.md``, the README's measured
section); under load from other
processes the ratio means nothing (OpenMP's spinning threads slow fp32 torch
far more than ONNX Runtime, which does not spin: one loaded run read int8 13x
faster), which is why the benchmark runner records a busy start. PT2E keeps
more accuracy against the fp32 output than ONNX Runtime. ONNX Runtime stays
the path because of deployment, not speed: its output is one ``.onnx`` file
that a robot runs without PyTorch or a C++ compiler, quantised in seconds,
while PT2E's artefact is code compiled by ``torch.compile`` in the process
that runs it (about three times ONNX Runtime's setup in the same runs).
Whether int8 pays on a given CPU is what the int8 rows of ``eval`` and
``tradeoff`` show.

Shapes: every image is ``(1, C, H, W)`` float32 in [0, 1]. The quantised
model takes any batch, height and width, as the fp32 export it quantises does
(QDQ pairs hold no shape); its activation ranges are calibrated at the
export's size (``--size``), which is also where it is compared and timed.
"""

import copy
import functools
import logging
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lenspair.core.errors import first_line
from lenspair.core.fsutil import atomic_write
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.export import check_image
from lenspair.model.evaluation.onnx_graph import (
    INPUT_NAME,
    DeployedNetwork,
    document_contract,
    write_onnx,
)
from lenspair.model.inference.backends import deploy
from lenspair.model.inference.onnx_session import session_options
from lenspair.model.metrics import psnr
from lenspair.model.training.pairs import Unread, read_pair, to_tensor

log = logging.getLogger(__name__)

CALIBRATION_IMAGES = 16
"""Images the activation ranges are calibrated on (evenly spaced over the data)."""


def calibration_images(
    pairs: Any, channels: int, size: tuple[int, int], count: int = CALIBRATION_IMAGES
) -> list[np.ndarray]:
    """Obstructed inputs of ``pairs`` as ``(1, C, H, W)`` float32 arrays at ``size``.

    Args:
        pairs: a pair source (``len`` and ``[i].input``, HWC or HW arrays of
            any integer or float dtype), e.g. from ``open_eval_pairs``.
        channels: the network's channels (1 or 3).
        size: ``(H, W)`` of the quantised model; other sizes are resized
            (area interpolation: the ranges matter here, not the geometry).
        count: at most this many images, evenly spaced.

    An unreadable pair is skipped with a warning (calibration goes on with
    the others). Grey images calibrating a colour network (``channels`` 3)
    are repeated into three channels, so the ranges of colour frames are
    never seen: one warning says so, naming the calibration folder (the
    calibration goes on, as ``train`` goes on with mixed images).

    Raises:
        ModelError: no pairs (naming the folder), or none readable.

    """
    if len(pairs) == 0:
        root = getattr(pairs, "root", None)
        where = f"{root}: " if root is not None else ""
        raise ModelError(f"{where}int8 calibration: no pairs to calibrate on")
    indices = np.unique(np.linspace(0, len(pairs) - 1, min(count, len(pairs))).round().astype(int))
    images = []
    unread: list[Unread] = []
    grey = 0
    for index in indices:
        if (item := read_pair(pairs, int(index), unread)) is None:
            continue
        grey += item.input.ndim == 2 or item.input.shape[2] == 1
        x = to_tensor(item.input, channels)[None]
        if tuple(x.shape[2:]) != size:
            x = F.interpolate(x, size=size, mode="area")
        images.append(np.ascontiguousarray(x.numpy(), dtype=np.float32))
    if not images:
        raise ModelError(f"int8 calibration: no image can be read; the first: {unread[0].reason}")
    if channels == 3 and grey:
        _warn_grey(getattr(pairs, "root", None), grey, len(images))
    return images


def _warn_grey(root: Path | None, grey: int, count: int) -> None:
    """Say that grey images calibrated a colour network (:func:`calibration_images`)."""
    where = f"{root}: " if root is not None else ""
    which = "the" if grey == count else f"{grey} of the {count}"
    log.warning(
        "%sint8 calibration: %s calibration images are grey and the network takes colour "
        "(RGB): the ranges of colour frames were not seen, so colour frames may clip or "
        "lose precision; calibrate on colour images",
        where,
        which,
    )


class _Reader:
    """``onnxruntime.quantization.CalibrationDataReader`` over a list of images."""

    def __init__(self, images: Sequence[np.ndarray]) -> None:
        self._images: Iterator[np.ndarray] = iter(images)

    def get_next(self) -> dict[str, np.ndarray] | None:
        image = next(self._images, None)
        return None if image is None else {INPUT_NAME: image}


QUANTISED_OPS = ["Conv", "ConvTranspose"]
"""ONNX operators quantised to int8; norms, pads, pools, concatenations and adds stay float.

Measured on GEA 540x360 mono (untrained, as ``bench_model`` builds it), 2
threads, ONNX Runtime 1.32, AMD EPYC with ``avx512_vnni``, three models timed
interleaved in one process (median of 30 runs each), speed against the first:
every operator quantised with the norm exported as a group norm 1.00x (38.0
dB PSNR against the fp32 output); every operator, norm exported as ONNX
``InstanceNormalization`` 1.07x (38.8 dB); convolutions only 1.14x (39.4 dB).
Fewer quantise/dequantise pairs around operators that run in float anyway.
"""


def quantize_network(
    network: nn.Module,
    channels: int,
    path: Path,
    size: tuple[int, int],
    calibration: Sequence[np.ndarray],
    dynamic: bool = True,
) -> Path:
    """Export ``network`` to ONNX and write its int8 (QDQ) quantisation to ``path``.

    The model takes any height and width (``dynamic``), or only ``size``: for
    a model run at that size alone, whose export is faster.

    Raises:
        ModelError: no calibration images, or the export/quantisation failed.

    """
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if not calibration:
        raise ModelError("int8 calibration: no images to calibrate on")
    model = DeployedNetwork(network).cpu().eval()
    with tempfile.TemporaryDirectory(prefix="lenspair-int8-") as folder:
        fp32 = Path(folder) / "fp32.onnx"
        prepared = Path(folder) / "prepared.onnx"
        try:
            image = check_image(channels, size)
            write_onnx(model, image, fp32, exporter="dynamo", dynamic=dynamic)
            quant_pre_process(str(fp32), str(prepared), skip_symbolic_shape=True)
        except Exception as exc:  # exporters raise many types; report one line
            raise ModelError(f"int8: ONNX export failed: {first_line(exc)}") from exc
        reader = _Reader(calibration)

        def write(tmp: Path) -> None:
            quantize_static(
                str(prepared),
                str(tmp),
                reader,  # type: ignore[arg-type]
                quant_format=QuantFormat.QDQ,
                per_channel=True,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
                calibrate_method=CalibrationMethod.MinMax,
                op_types_to_quantize=QUANTISED_OPS,
            )
            document_contract(tmp, channels, "int8")  # quantize_static drops the fp32 file's

        try:
            atomic_write(Path(path), write, ".onnx")
        except Exception as exc:
            raise ModelError(f"int8: quantisation failed: {first_line(exc)}") from exc
    return Path(path)


def open_session(path: Path, threads: int | None = None) -> Any:
    """An ONNX Runtime CPU session for ``path`` (``threads``: torch's count by default)."""
    import onnxruntime as ort

    options = session_options(threads)  # no spinning: it is timed beside torch
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


class Int8Network(nn.Module):
    """The network at int8 through ONNX Runtime, called like the torch network.

    ``forward(x)`` returns ``(restored, restored)`` (the torch network's
    ``(generator_out, enhanced_out)`` convention; only the second is
    deployed). A model is quantised once per input size, in a temporary
    folder, from the same calibration images resized to that size.

    Args:
        network: the fp32 restoration network (on the CPU).
        channels: its channels.
        calibration: ``(1, C, H, W)`` float32 calibration images.
        threads: ONNX Runtime intra-op threads (default: torch's).

    """

    fp32_network: nn.Module

    def __init__(
        self,
        network: nn.Module,
        channels: int,
        calibration: Sequence[np.ndarray],
        threads: int | None = None,
    ) -> None:
        super().__init__()
        # Not registered as a submodule: .to() and deep copies of this wrapper
        # (latency timing) must not touch the fp32 network it quantises.
        object.__setattr__(self, "fp32_network", network.cpu().eval())
        self.channels = channels
        self.calibration = list(calibration)
        self.threads = threads
        self._folder = tempfile.TemporaryDirectory(prefix="lenspair-int8-")
        self._sessions: dict[tuple[int, int], Any] = {}

    def __deepcopy__(self, memo: dict[int, Any]) -> "Int8Network":
        return self  # sessions cannot be copied; the module holds no trainable state

    def session(self, size: tuple[int, int]) -> Any:
        """The ONNX Runtime session of the int8 model for ``(H, W)``."""
        if size not in self._sessions:
            resized = [
                F.interpolate(torch.from_numpy(image), size=size, mode="area").numpy()
                if tuple(image.shape[2:]) != size
                else image
                for image in self.calibration
            ]
            path = Path(self._folder.name) / f"int8_{size[1]}x{size[0]}.onnx"
            quantize_network(self.fp32_network, self.channels, path, size, resized, dynamic=False)
            self._sessions[size] = open_session(path, self.threads)
        return self._sessions[size]

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``(N, C, H, W)`` float in [0, 1] -> ``(restored, restored)`` float32, CPU."""
        size = (int(x.shape[2]), int(x.shape[3]))
        feed = {INPUT_NAME: np.ascontiguousarray(x.detach().float().cpu().numpy())}
        restored = torch.from_numpy(self.session(size).run(None, feed)[0])
        return restored, restored


@dataclass(frozen=True)
class Int8Check:
    """An int8 export and how it compares with fp32 torch on the check image.

    Attributes:
        path: the written ``.onnx`` file.
        size: ``WxH``.
        calibration_images: how many images calibrated the ranges.
        psnr_vs_fp32_db: PSNR of the int8 output against the fp32 output, on
            an image held out of the calibration.
        max_abs_diff: largest |int8 - fp32| on the check image.
        median_ms: ONNX Runtime batch-1 latency, int8.
        fp32_median_ms: torch fp32 batch-1 latency as deployed (channels-last),
            same run, interleaved.
        threads: CPU threads.
        compared_on: what the comparison ran on: ``a held-out image``, or
            ``random noise`` when one image calibrated (none to hold out).

    """

    path: str
    size: str
    calibration_images: int
    psnr_vs_fp32_db: float
    max_abs_diff: float
    median_ms: float
    fp32_median_ms: float
    threads: int
    compared_on: str = "a held-out image"

    def summary(self) -> str:
        """One line for people."""
        return (
            f"int8 onnx: {self.path} ({self.size}, onnxruntime static QDQ, "
            f"{self.calibration_images} calibration images); PSNR vs fp32 "
            f"{self.psnr_vs_fp32_db:.1f} dB on {self.compared_on}, max |diff| "
            f"{self.max_abs_diff:.3g}; "
            f"{self.median_ms:.1f} ms median vs torch fp32 {self.fp32_median_ms:.1f} ms "
            f"({self.threads} threads)"
        )


def check_int8(
    network: nn.Module,
    channels: int,
    path: Path,
    size: tuple[int, int],
    calibration: Sequence[np.ndarray],
    runs: int = 20,
) -> Int8Check:
    """Quantise ``network`` to ``path``, then compare and time it against fp32 torch.

    The comparison image is held out of the calibration of a probe model (the
    one with the most contrast, when there are two or more): agreement
    measured on an image the ranges were fitted to would flatter int8, and so
    would a flat one (a sky frame gave 76.7 dB where textured frames differ by
    up to 75 codes). With one image there is none to hold out: the check runs
    on seeded random noise, and says so (``compared_on``). The model written
    at ``path`` is calibrated on every image; it is the one timed.
    fp32 is timed as
    ``restore`` runs it on the CPU (a copy prepared by
    :func:`~lenspair.model.inference.backends.deploy`: channels-last, the
    allocator tuned), interleaved with the int8 runs.
    """
    held_out, fitted = None, list(calibration)
    if len(calibration) >= 2:
        index = max(range(len(calibration)), key=lambda i: float(np.std(calibration[i])))
        held_out = fitted.pop(index)
    image = torch.from_numpy(held_out) if held_out is not None else check_image(channels, size)
    feed = {INPUT_NAME: image.numpy()}
    probe = None
    if held_out is not None:  # measured on a model calibrated without the image compared on
        with tempfile.TemporaryDirectory() as folder:
            probe_path = Path(folder) / "probe.onnx"  # run at this size only
            quantize_network(network, channels, probe_path, size, fitted, dynamic=False)
            probe = open_session(probe_path).run(None, feed)[0]
    # the model written is calibrated on every image, the one with the most contrast too
    quantize_network(network, channels, path, size, list(calibration))
    session = open_session(path)
    model = DeployedNetwork(network).cpu().eval()
    deployed = deploy(copy.deepcopy(model), torch.device("cpu"))
    deployed_image = image.contiguous(memory_format=torch.channels_last)
    with torch.inference_mode():
        expected = model(image)
        actual = torch.from_numpy(probe if probe is not None else session.run(None, feed)[0])
        times: dict[str, list[float]] = {"int8": [], "fp32": []}
        calls: dict[str, Callable[[], object]] = {
            "int8": functools.partial(session.run, None, feed),
            "fp32": lambda: deployed(deployed_image),
        }
        for index in range(3 + runs):  # interleaved: load from other processes hits both
            for name, call in calls.items():
                start = time.perf_counter()
                call()
                if index >= 3:
                    times[name].append((time.perf_counter() - start) * 1e3)
    return Int8Check(
        path=str(path),
        size=f"{size[1]}x{size[0]}",
        calibration_images=len(calibration),
        psnr_vs_fp32_db=float(psnr(actual.clamp(0, 1), expected.clamp(0, 1))[0]),
        max_abs_diff=float((actual - expected).abs().max()),
        median_ms=statistics.median(times["int8"]),
        fp32_median_ms=statistics.median(times["fp32"]),
        threads=torch.get_num_threads(),
        compared_on="a held-out image" if held_out is not None else "random noise",
    )


__all__ = [
    "CALIBRATION_IMAGES",
    "Int8Check",
    "Int8Network",
    "calibration_images",
    "check_int8",
    "open_session",
    "quantize_network",
]
