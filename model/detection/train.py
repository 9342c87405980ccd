"""Training the detector, and saving/loading its checkpoints.

The loss is the kind loss plus ``map_weight`` times the binary
cross-entropy of the valid tiles of the map, covered tiles weighted
``covered_weight`` times (they are few; unweighted, the map learns to say
"nothing" everywhere). The kind loss is, per frame, the cross-entropy of
its kind, or for a positive of unknown kind (a label that is none of
:data:`KINDS`, or none at all on a dataset pair) the binary cross-entropy
of the obstructed answer, ``-log(1 - p(clean))``: it says nothing of which
anomaly, only that there is one; averaged over the frames that take part.
Each step draws a batch with a ``torch.Generator`` seeded by ``seed``, cuts
one window of ``crop_tiles`` tiles (aligned to the tile grid, so the map
targets are cut exactly) out of every frame, which halves the cost of a
step and stops the network from learning whole scenes by heart; an
obstructed frame whose window holds no covered tile does not take part in
the kind loss for that step (:data:`SKIPPED_KIND`). It flips half of the
batch left-right and scales each image by a random exposure gain (0.5..1.2,
clipped), so the same samples and seed give the same weights on one
machine (with ``max_seconds`` the number of steps, and so the weights,
depend on the machine's speed).

Synthetic samples (group ``synthetic``) are cheap to make and easily
outnumber the recorded ones; when both are present, batches draw half from
each, so the frames of real (or simulated) cameras are not drowned. The
learning rate decays on a cosine to 5 % of its start over ``steps`` or over
``max_seconds``, whichever is nearer its end, so a time-limited run still
ends with small steps. Training stops at whichever of the two comes first;
``steps=None`` sets no step limit, and leaves ``max_seconds`` to end it.

A checkpoint is a dict of plain values and tensors (``format``, the
:class:`DetectorSpec` fields, the kinds, the state dict, a training summary),
read back with ``weights_only=True``.
"""

import io
import itertools
import math
import operator
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as functional

from lenspair.core.device import resolve_device
from lenspair.core.errors import first_line
from lenspair.core.fsutil import atomic_write_bytes
from lenspair.core.progress import progress
from lenspair.core.samples import file_or_sample
from lenspair.model.checkpoint import DETECTOR_FORMAT, check_finite_weights, read_torch_file
from lenspair.model.detection.data import UNKNOWN_KIND, DetectorSample
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import KINDS, TILE_STRIDE, AnomalyDetector, DetectorSpec

SKIPPED_KIND = -2
"""Kind of an obstructed frame's training window without a covered tile: no kind loss."""


@dataclass(frozen=True)
class DetectorTraining:
    """Training settings.

    Attributes:
        steps: optimiser steps; None: no step limit (``max_seconds`` ends training).
        batch_size: frames per step.
        learning_rate: AdamW learning rate (cosine decay to 5 % of it).
        weight_decay: AdamW weight decay.
        map_weight: weight of the tile-map loss against the kind loss.
        seed: seeds the initial weights and every batch.
        max_seconds: stop early after this much wall time (None: no limit).
        covered_weight: weight of covered tiles in the map loss.
        crop_tiles: ``(rows, cols)`` of the training window, tiles; None: whole frames.
        threads: CPU threads for training; 1 is fastest for this small network
            on a shared CPU (measured: 2 threads were several times slower
            while other jobs ran).
    """

    steps: int | None = 600
    batch_size: int = 8
    learning_rate: float = 3e-3
    weight_decay: float = 1e-4
    map_weight: float = 1.0
    seed: int = 0
    max_seconds: float | None = None
    threads: int = 1
    covered_weight: float = 4.0
    crop_tiles: tuple[int, int] | None = (15, 22)

    def __post_init__(self) -> None:
        if (self.steps is not None and self.steps < 1) or self.batch_size < 1:
            raise ModelError(
                f"steps and batch_size must be >= 1, got {self.steps}, {self.batch_size}"
            )
        if self.steps is None and self.max_seconds is None:
            raise ModelError("steps=None (no step limit) needs max_seconds to end training")
        if self.threads < 1:
            raise ModelError(f"--threads: expected at least 1, got {self.threads}")


@dataclass(frozen=True)
class TrainingSummary:
    """What a training run did: steps done, seconds, first and last mean loss (20 steps)."""

    steps: int
    seconds: float
    first_loss: float
    last_loss: float
    samples: int


def stack(samples: Sequence[DetectorSample]) -> dict[str, torch.Tensor]:
    """Samples -> ``images (N,1,H,W)``, ``kinds (N,)``, ``tiles``/``valid (N,rows,cols)``."""
    return {
        "images": torch.from_numpy(np.stack([s.image for s in samples]))[:, None],
        "kinds": torch.tensor([s.kind for s in samples], dtype=torch.long),
        "tiles": torch.from_numpy(np.stack([s.tiles for s in samples])),
        "valid": torch.from_numpy(np.stack([s.valid for s in samples])),
    }


def sampling_weights(samples: Sequence[DetectorSample]) -> torch.Tensor:
    """Per-sample draw weights: synthetic and other samples half each (module docstring)."""
    synthetic = torch.tensor([s.group == "synthetic" for s in samples])
    count = int(synthetic.sum())
    if count in (0, len(samples)):
        return torch.ones(len(samples), dtype=torch.float64)
    return torch.where(synthetic, 0.5 / count, 0.5 / (len(samples) - count)).double()


def crop_batch(
    batch: dict[str, torch.Tensor], crop_tiles: tuple[int, int], generator: torch.Generator
) -> dict[str, torch.Tensor]:
    """One tile-aligned window of every frame (module docstring); kinds adjusted.

    The window of an obstructed frame (known kind or :data:`UNKNOWN_KIND`)
    that holds no covered valid tile gets :data:`SKIPPED_KIND`: it may show
    nothing of the anomaly, so it says neither which one nor that there is one.
    """
    images, tiles = batch["images"], batch["tiles"]
    full_rows, full_cols = images.shape[2] // TILE_STRIDE, images.shape[3] // TILE_STRIDE
    rows, cols = min(crop_tiles[0], full_rows), min(crop_tiles[1], full_cols)
    top = int(torch.randint(full_rows - rows + 1, (1,), generator=generator))
    left = int(torch.randint(full_cols - cols + 1, (1,), generator=generator))
    window = (slice(top, top + rows), slice(left, left + cols))
    pixels = tuple(slice(s.start * TILE_STRIDE, s.stop * TILE_STRIDE) for s in window)
    cropped = {
        "images": images[:, :, pixels[0], pixels[1]],
        "tiles": tiles[:, window[0], window[1]],
        "valid": batch["valid"][:, window[0], window[1]],
    }
    covered = ((cropped["tiles"] > 0.5) & cropped["valid"]).flatten(1).any(dim=1)
    kinds = batch["kinds"]
    cropped["kinds"] = torch.where((kinds != 0) & ~covered, SKIPPED_KIND, kinds)
    return cropped


def detector_loss(
    network: AnomalyDetector,
    batch: dict[str, torch.Tensor],
    map_weight: float,
    covered_weight: float = 1.0,
) -> torch.Tensor:
    """Kind loss + ``map_weight`` x weighted tile cross-entropy over valid tiles.

    The kind loss (module docstring) is the mean, over the frames of a known
    kind and those of :data:`UNKNOWN_KIND`, of the kind's cross-entropy or of
    ``-log(1 - p(clean))``; :data:`SKIPPED_KIND` frames add nothing to it.
    """
    output = network(batch["images"])
    kinds, logits = batch["kinds"], output.kind_logits
    known, unknown = kinds >= 0, kinds == UNKNOWN_KIND
    named = functional.cross_entropy(logits[known], kinds[known], reduction="sum")
    # -log(1 - p(clean)) = -log(sum of the anomalies' softmax), computed without 1 - p
    obstructed = torch.logsumexp(logits, dim=1) - torch.logsumexp(logits[:, 1:], dim=1)
    counted = int(known.sum()) + int(unknown.sum())
    kind_loss = (named + obstructed[unknown].sum()) / max(1, counted)
    valid = batch["valid"].float()
    tile_loss = functional.binary_cross_entropy_with_logits(
        output.tile_logits,
        batch["tiles"],
        reduction="none",
        pos_weight=torch.tensor(covered_weight, device=output.tile_logits.device),
    )
    tile_loss = (tile_loss * valid).sum() / valid.sum().clamp(min=1.0)
    return kind_loss + map_weight * tile_loss


def _augment(images: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    count = images.shape[0]
    flip = (torch.rand(count, generator=generator) < 0.5).to(images.device)
    images = torch.where(flip[:, None, None, None], images.flip(-1), images)
    gains = 0.5 + 0.7 * torch.rand(count, 1, 1, 1, generator=generator)
    return (images * gains.to(images.device)).clamp(0.0, 1.0)


def train_detector(
    samples: Sequence[DetectorSample],
    spec: DetectorSpec,
    settings: DetectorTraining,
    device: torch.device | str = "cpu",
) -> tuple[AnomalyDetector, TrainingSummary]:
    """Train a fresh detector on ``samples``.

    All samples are stacked once and moved to ``device`` (a few thousand
    frames of 270x180 are a few hundred MB); batches are drawn, cut and
    augmented there. The random draws come from a CPU ``torch.Generator``,
    so the batches do not depend on the device (the arithmetic may differ
    in the last bits).

    Args:
        samples: labelled frames at ``spec.input_size``.
        spec: the architecture.
        settings: steps, batch, optimiser, seed, time limit.
        device: where to train (resolved by the caller, e.g. ``--device``).

    Returns:
        The network (eval mode, on ``device``) and a summary.

    Raises:
        ModelError: no samples, or samples of another size than ``spec.input_size``.
    """
    if not samples:
        raise ModelError("train-detector: no training samples")
    sizes = {s.image.shape for s in samples}
    if sizes != {spec.input_size}:
        raise ModelError(f"samples have sizes {sorted(sizes)}, expected {spec.input_size}")
    threads_before = torch.get_num_threads()
    torch.set_num_threads(max(1, settings.threads))
    try:
        return _train(samples, spec, settings, torch.device(device))
    finally:
        torch.set_num_threads(threads_before)


def _train(
    samples: Sequence[DetectorSample],
    spec: DetectorSpec,
    settings: DetectorTraining,
    device: torch.device,
) -> tuple[AnomalyDetector, TrainingSummary]:
    torch.manual_seed(settings.seed)
    network = AnomalyDetector(spec).to(device)
    data = {key: value.to(device) for key, value in stack(samples).items()}
    generator = torch.Generator().manual_seed(settings.seed)
    optimiser = torch.optim.AdamW(
        network.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay
    )
    weights = sampling_weights(samples)
    losses: list[torch.Tensor] = []  # kept on the device: no synchronisation per step
    start = time.perf_counter()
    network.train()
    steps: Iterable[int] = itertools.count() if settings.steps is None else range(settings.steps)
    for step in progress(steps, desc="train-detector", unit="step"):
        done = 0.0 if settings.steps is None else step / settings.steps
        if settings.max_seconds is not None:
            done = max(done, (time.perf_counter() - start) / settings.max_seconds)
        factor = 0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * min(1.0, done)))
        for group in optimiser.param_groups:
            group["lr"] = settings.learning_rate * factor
        picks = torch.multinomial(weights, settings.batch_size, True, generator=generator)
        batch = {key: value[picks.to(device)] for key, value in data.items()}
        if settings.crop_tiles is not None:
            batch = crop_batch(batch, settings.crop_tiles, generator)
        batch["images"] = _augment(batch["images"], generator)
        loss = detector_loss(network, batch, settings.map_weight, settings.covered_weight)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[no-untyped-call]
        optimiser.step()
        losses.append(loss.detach())
        if settings.max_seconds is not None and time.perf_counter() - start > settings.max_seconds:
            break
    network.eval()
    values = torch.stack(losses).float().cpu().numpy()
    window = min(20, len(values))
    summary = TrainingSummary(
        steps=len(values),
        seconds=round(time.perf_counter() - start, 2),
        first_loss=float(np.mean(values[:window])),
        last_loss=float(np.mean(values[-window:])),
        samples=len(samples),
    )
    return network, summary


def detector_bytes(network: AnomalyDetector, extra: dict[str, Any] | None = None) -> bytes:
    """A detector checkpoint's bytes (CPU tensors, plain values).

    Serialised in memory: the same network gives the same bytes (saved to a
    file, torch names its entries after the file, a temporary's random name),
    and a full disk is met by the write, which names the file, not inside
    ``torch.save``.
    """
    payload = {
        "format": DETECTOR_FORMAT,
        "spec": {key: list(value) for key, value in asdict(network.spec).items()},
        "kinds": list(KINDS),
        "state_dict": {k: v.detach().cpu() for k, v in network.state_dict().items()},
        "extra": extra or {},
    }
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    return buffer.getvalue()


def save_detector(
    path: Path, network: AnomalyDetector, extra: dict[str, Any] | None = None
) -> None:
    """Write a detector checkpoint atomically (:func:`detector_bytes`)."""
    atomic_write_bytes(Path(path), detector_bytes(network, extra))


def load_detector(path: Path, device: torch.device | str = "cpu") -> AnomalyDetector:
    """Read a detector checkpoint (``weights_only=True``) onto ``device``, in eval mode.

    ``detector.pt`` alone, when no such file is here, is the bundled detector
    (as on the command line).

    Raises:
        ModelError: missing file, a folder, not a detector checkpoint, other
            kinds, or one whose parts do not make a usable detector (a key
            missing, a spec this version does not know, weights that do not fit
            the spec, or NaN and Inf in them): one line naming the file.
        LenspairError: a device this machine does not have (``cuda`` without
            one); ``device`` takes ``auto``, as the command line does.
    """
    path = file_or_sample(str(path), ".pt")
    if path.is_dir():
        inside = path / "detector.pt"
        hint = f"; the run's detector is {inside}" if inside.is_file() else ""
        raise ModelError(f"{path}: a folder, not a detector checkpoint{hint}")
    if not path.is_file():
        raise ModelError(f"{path}: no such detector checkpoint")
    data = read_torch_file(path, "detector checkpoint")
    if not isinstance(data, dict) or data.get("format") != DETECTOR_FORMAT:
        raise ModelError(f"{path}: not a detector checkpoint (train one with train-detector)")
    unusable = f"{path}: not a usable detector checkpoint"
    try:
        kinds = tuple(data["kinds"])
        # operator.index: a float size is refused, not cut to a whole number
        fields = {key: tuple(map(operator.index, value)) for key, value in data["spec"].items()}
        spec = DetectorSpec(**fields)  # type: ignore[arg-type]
        weights = dict(data["state_dict"])
    except KeyError as exc:
        raise ModelError(f"{unusable} (no {exc} in it)") from None
    except (TypeError, ValueError, AttributeError) as exc:
        raise ModelError(f"{unusable} ({first_line(exc)})") from None
    if kinds != KINDS:
        raise ModelError(f"{path}: kinds {list(kinds)} differ from this version's {KINDS}")
    check_finite_weights(weights, str(path))
    network = AnomalyDetector(spec)
    try:
        network.load_state_dict(weights)
    except RuntimeError as exc:
        # torch's first line says only "Error(s) in loading state_dict": the first error instead
        said = [line.strip() for line in str(exc).splitlines()[1:] if line.strip()]
        detail = said[0] if said else first_line(exc)
        raise ModelError(f"{unusable} (its weights do not fit its spec: {detail})") from None
    return network.to(resolve_device(device)).eval()
