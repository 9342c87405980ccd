"""Checkpoints: CPU state dicts plus the resolved run configuration.

A checkpoint is a plain dict saved with :func:`torch.save` and read back with
``weights_only=True`` and ``map_location="cpu"``, so loading one never runs
code and works on a machine without the GPU it was trained on::

    format: "lenspair-checkpoint", version: 1
    config: the resolved RunConfig as plain data (model section builds the network)
    model, discriminator, optimizer_g, optimizer_d, scaler: state dicts (CPU tensors)
    epoch, step, step_in_epoch: progress (epoch = completed epochs)
    best_metric, best_epoch, stale_validations: early-stopping state
    rng: {"torch": ByteTensor, "cuda": [ByteTensor, ...]}

Only ``format``, ``version``, ``config`` and ``model`` are required to use a
checkpoint for inference (``eval``, ``export``) or as ``--init``.
"""

import io
import pickle
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from lenspair.core.config import to_plain
from lenspair.core.errors import ConfigError, first_line
from lenspair.core.fsutil import atomic_write
from lenspair.model.errors import ModelError
from lenspair.model.networks.variants import build_model
from lenspair.model.training.config import ModelConfig, RunConfig
from lenspair.model.training.config_loading import stored_run_config

CHECKPOINT_FORMAT = "lenspair-checkpoint"

DETECTOR_FORMAT = "lenspair-detector-1"
"""The ``format`` of an anomaly detector's checkpoint (:mod:`lenspair.model.detection.train`)."""
CHECKPOINT_VERSION = 1


WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
"""Package data folder of the shipped weights (``lenspair/model/weights``)."""

WEIGHTS_FILES: dict[int, str] = {1: "gea_ours_mono.pt", 3: "gea_ours_rgb.pt"}
"""Shipped checkpoint per channel count."""


def to_cpu(obj: Any) -> Any:
    """Copy every tensor inside nested dicts/lists/tuples to the CPU (detached)."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().to("cpu", copy=True)
    if isinstance(obj, dict):
        return {key: to_cpu(value) for key, value in obj.items()}
    if isinstance(obj, list):
        return [to_cpu(value) for value in obj]
    if isinstance(obj, tuple):
        return tuple(to_cpu(value) for value in obj)
    return obj


def save_checkpoint(path: Path, payload: dict[str, Any], config: RunConfig) -> None:
    """Write ``payload`` (plus format, version and config) atomically to ``path``.

    Args:
        path: destination ``.pt`` file; parent folders are created.
        payload: state dicts and counters; tensors are copied to the CPU.
        config: the resolved run configuration, stored as plain data.

    """
    data = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "config": to_plain(config),
        **to_cpu(payload),
    }

    def _write(tmp: Path) -> None:
        # serialised first: torch.save's own short write is a RuntimeError naming no file
        buffer = io.BytesIO()
        torch.save(data, buffer)
        tmp.write_bytes(buffer.getbuffer())

    atomic_write(Path(path), _write, suffix=".pt")


def _exported_kind(path: Path) -> str | None:
    """``an ONNX model`` / ``a TorchScript model`` for the files export writes, else None."""
    if path.suffix.lower() == ".onnx":
        return "an ONNX model"
    if zipfile.is_zipfile(path):
        try:
            with zipfile.ZipFile(path) as archive:
                names = archive.namelist()
        except (OSError, zipfile.BadZipFile):
            return None
        if any(name.endswith("/constants.pkl") or "/code/" in name for name in names):
            return "a TorchScript model"
    return None


def _cut_short(path: Path) -> bool:
    """Whether ``path`` begins as a zip archive (as torch saves) but has no end to read."""
    try:
        with path.open("rb") as file:
            head = file.read(4)
    except OSError:
        return False
    return head == b"PK\x03\x04" and not zipfile.is_zipfile(path)


def read_torch_file(path: Path, what: str) -> Any:
    """``torch.load`` with ``weights_only=True`` onto the CPU; every failure is one line.

    Args:
        path: an existing file.
        what: what the file should be, for messages ("lenspair checkpoint").

    Raises:
        ModelError: an empty file, pickled Python objects, or a corrupt file;
            never torch's advice to load with ``weights_only=False``, which is
            never right for a file from elsewhere, nor its terminal escape codes.
    """
    if path.stat().st_size == 0:
        raise ModelError(f"{path}: empty file, not a {what}")
    exported = _exported_kind(path)
    if exported is not None:  # torch.load warns about a TorchScript archive before failing
        raise ModelError(f"{path}: {exported} (from lenspair export), not a {what}")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        found = "Python objects other than tensors" if "GLOBAL" in str(exc) else "no torch data"
        raise ModelError(
            f"{path}: not a {what} (it holds {found}; lenspair loads only tensors and plain data)"
        ) from None
    except Exception as exc:  # torch raises many types for corrupt files
        detail = first_line(exc)
        if "weights_only" in detail:  # torch's advice to unpickle anything: never right here
            detail = "it holds more than tensors and plain data"
        elif _cut_short(path):  # torch says "[Errno 22] Invalid argument" of it
            detail = "a torch zip archive cut short: an interrupted copy or download?"
        elif detail.isdigit() or len(detail) < 4:  # a bare key or code (KeyError: 101) says nothing
            detail = "neither a torch zip archive nor a torch pickle"
        raise ModelError(f"{path}: not a {what} (not a readable torch file: {detail})") from None


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Read a checkpoint safely (``weights_only=True``) onto the CPU.

    Raises:
        ModelError: missing file, not a lenspair checkpoint, or unreadable.

    """
    path = Path(path)
    if path.is_dir():
        runs = path / "checkpoints" / "best.pt"
        hint = f"; the run's best network is {runs}" if runs.is_file() else ""
        raise ModelError(f"{path}: a folder, not a checkpoint file{hint}")
    if not path.is_file():
        hint = ""
        if str(path) == "pretrained":
            shipped = " and ".join(str(WEIGHTS_DIR / name) for name in WEIGHTS_FILES.values())
            hint = (
                " ('pretrained' names the shipped weights for train --init only; elsewhere "
                f"give the file: {shipped})"
            )
        raise ModelError(f"{path}: checkpoint not found{hint}")
    other = _exported_kind(path) if path.stat().st_size else None
    if other is not None:
        raise ModelError(
            f"{path}: {other} written by lenspair export, not a checkpoint; give the "
            "checkpoint (.pt from lenspair train) it was exported from"
            + (" (restore also runs the .onnx file itself)" if other.startswith("an ONNX") else "")
        )
    data = read_torch_file(path, "lenspair checkpoint")
    if isinstance(data, dict) and data.get("format") == DETECTOR_FORMAT:
        raise ModelError(
            f"{path}: an anomaly detector (from train-detector, for detect), not a restoration "
            "network; give a checkpoint from lenspair train"
        )
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise ModelError(f"{path}: not a lenspair checkpoint")
    if data.get("version") != CHECKPOINT_VERSION:
        raise ModelError(
            f"{path}: checkpoint version {data.get('version')}, expected {CHECKPOINT_VERSION}"
        )
    return data


def checkpoint_config(data: dict[str, Any], path: Path | str = "checkpoint") -> RunConfig:
    """The run configuration stored in a loaded checkpoint."""
    try:
        return stored_run_config(data["config"])
    except (KeyError, ConfigError) as exc:
        raise ModelError(f"{path}: invalid stored config ({exc})") from None


def build_network(config: ModelConfig) -> nn.Module:
    """Build the restoration network a model config describes (weights at init).

    Raises:
        ModelError: ``channels`` is not resolved yet.

    """
    if config.channels is None:
        raise ModelError("model.channels is unresolved; cannot build the network")
    return build_model(config.variant, config.channels, config.width, config.num_blocks)


@dataclass
class LoadedModel:
    """A restoration network restored from a checkpoint, in eval mode on ``device``.

    Attributes:
        network: forward(x) -> (generator_out, enhanced_out), NCHW float in [0, 1].
        config: the run configuration it was trained with.
        path: the checkpoint file.
        epoch: completed training epochs.
        step: optimiser steps taken.

    """

    network: nn.Module
    config: RunConfig
    path: Path
    epoch: int
    step: int


def load_model(path: Path, device: torch.device | str = "cpu") -> LoadedModel:
    """Rebuild the network of a checkpoint and load its weights (strict).

    Raises:
        ModelError: unreadable checkpoint or weights that do not fit the network.

    """
    path = Path(path)
    data = load_checkpoint(path)
    config = checkpoint_config(data, path)
    network = build_network(config.model)
    load_weights(network, data, path)
    network.to(device).eval()
    return LoadedModel(
        network=network,
        config=config,
        path=path,
        epoch=int(data.get("epoch", 0)),
        step=int(data.get("step", 0)),
    )


def load_weights(network: nn.Module, data: dict[str, Any], path: Path | str) -> None:
    """Load a checkpoint's ``model`` state dict into ``network`` (strict, finite).

    Weights holding NaN or Inf (a run that diverged) are refused here, in one
    line naming the tensor: such a network's outputs are not finite, and each
    command using it would fail later, frame by frame, blaming the frames.

    Raises:
        ModelError: no state dict, another network's, or non-finite weights.
    """
    if "model" not in data:
        raise ModelError(f"{path}: checkpoint holds no model weights")
    weights = data["model"]
    if not isinstance(weights, dict):
        raise ModelError(f"{path}: checkpoint 'model' is not a state dict")
    problem = first_shape_difference(network.state_dict(), weights)
    if problem is not None:
        raise ModelError(f"{path}: weights do not fit the network: {problem}")
    check_finite_weights(weights, str(path))
    try:
        network.load_state_dict(weights)
    except RuntimeError as exc:
        raise ModelError(f"{path}: weights do not fit the network ({first_line(exc)})") from None


def check_finite_weights(weights: dict[str, Any], label: str) -> None:
    """Refuse a state dict holding NaN or Inf (a run that diverged), naming the first tensor.

    Args:
        weights: a state dict.
        label: what the weights are, leading the message (a path, ``--init PATH``).

    Raises:
        ModelError: ``label: its weights hold NaN or Inf: <tensor> (<n> of <m> values); ...``.
    """
    bad = first_non_finite(weights)
    if bad is not None:
        raise ModelError(
            f"{label}: its weights hold NaN or Inf: {bad}; the run that wrote it diverged: "
            "use an earlier checkpoint of it"
        )


def first_non_finite(weights: dict[str, Any]) -> str | None:
    """The first floating-point tensor of a state dict that holds NaN or Inf, in words.

    Args:
        weights: a state dict (name -> tensor; other values are skipped).

    Returns:
        ``None`` when every value is finite, else one phrase such as
        ``generator.head.weight (1 of 432 values)``.
    """
    for name, value in weights.items():
        if not isinstance(value, torch.Tensor) or not value.is_floating_point():
            continue
        bad = int((~torch.isfinite(value)).sum())
        if bad:
            return f"{name} ({bad} of {value.numel()} values)"
    return None


def first_shape_difference(expected: dict[str, torch.Tensor], found: dict[str, Any]) -> str | None:
    """Describe the first tensor whose name or shape differs, in the network's order.

    Args:
        expected: the network's own state dict.
        found: the state dict read from a checkpoint.

    Returns:
        ``None`` when every name and shape agree, else one phrase such as
        ``generator.head.weight: checkpoint (16, 3, 3, 3), network (32, 3, 3, 3)``.

    """
    for name, tensor in expected.items():
        if name not in found:
            return f"{name}: missing from the checkpoint"
        other = found[name]
        shape = tuple(other.shape) if isinstance(other, torch.Tensor) else None
        if shape != tuple(tensor.shape):
            return f"{name}: checkpoint {shape}, network {tuple(tensor.shape)}"
    extra = [name for name in found if name not in expected]
    if extra:
        return f"{extra[0]}: in the checkpoint but not in the network"
    return None
