"""Evaluate a restoration checkpoint on paired images: scores, means and latency.

:func:`evaluate_checkpoint` loads a checkpoint, scores it on every pair
(:mod:`lenspair.model.evaluation.scoring`, which says what is scored and
under which metric conventions), takes the means over all pairs and per
difficulty (:mod:`lenspair.model.evaluation.summary`) and times the network
as deployed.

The reports (CSV, JSON, Markdown, contact sheet) are written by
:func:`lenspair.model.evaluation.report.write_report`.
"""

import logging
from collections.abc import Collection, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from lenspair.core.config import to_plain
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.layouts import detect_layout
from lenspair.model.checkpoint import LoadedModel, load_model
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.latency import Latency, measure_latency
from lenspair.model.evaluation.scoring import SheetRow, agreement_with_fp32, score_pairs
from lenspair.model.evaluation.summary import ImageScore, Summary, breakdown, summarize
from lenspair.model.inference.backends import deploy
from lenspair.model.metrics import PSNR_CAP_DB, parse_metric_convention
from lenspair.model.training.config import DataConfig, split_until
from lenspair.model.training.datasets import pairs_digest, recorded_digest, validation_split
from lenspair.model.training.holdout import holdout_indices
from lenspair.model.training.pairs import (
    PairItem,
    PairSource,
    SubsetSource,
    Unread,
    channels_of,
    conversion_note,
    open_eval_pairs,
    read_pair,
)

log = logging.getLogger(__name__)


@dataclass
class EvalResult:
    """Everything one evaluation measured.

    Attributes:
        checkpoint: what was evaluated.
        data: the paired images (folder and split).
        convention: metric convention.
        precision: inference precision of the scored outputs.
        scores: per-image scores, in dataset order.
        overall: means over all images.
        by_difficulty: means per difficulty (empty when unknown).
        input_overall: means of the inputs themselves (no restoration).
        input_by_difficulty: the same per difficulty.
        latency: timings (CPU, and CUDA when the device is CUDA).
        samples: contact-sheet rows (input, output, target).
        model: the checkpoint's ``model`` config section (plain data).
        versus_fp32: means of the output scored against the fp32 output
            (reduced precisions only): what the precision costs.
        precision_reason: why this precision (``lenspair.model.precision``).
        unread: pairs that could not be read or scored, and why (not in any mean).
        data_path: the scored folder, resolved, as ``lenspair eval`` sets it
            (it tells evaluations of namesake datasets apart by it).
        calibration: int8 only: the images the quantisation was calibrated on
            (the scored ones themselves make its accuracy optimistic).
        conversion: how the pairs' channels were converted to the network's
            (a mono network scored on colour pairs scores luma), or "".
        trained_on_scored: how many of the scored pairs the checkpoint trained
            on (:func:`trained_on_scored`): 0 for other data, None when its
            run recorded no dataset.

    """

    checkpoint: str
    data: str
    convention: str
    precision: str
    scores: list[ImageScore]
    overall: Summary
    by_difficulty: dict[str, Summary]
    input_overall: Summary | None = None
    input_by_difficulty: dict[str, Summary] = field(default_factory=dict)
    latency: list[Latency] = field(default_factory=list)
    samples: list[SheetRow] = field(default_factory=list)
    model: dict[str, Any] = field(default_factory=dict)
    versus_fp32: Summary | None = None
    precision_reason: str = ""
    unread: list[Unread] = field(default_factory=list)
    data_path: str = ""
    calibration: str = ""
    conversion: str = ""
    trained_on_scored: int | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready means (per-image scores stay in the CSV)."""
        return {
            "checkpoint": self.checkpoint,
            "model": self.model,
            "data": self.data,
            "data_path": self.data_path,
            "convention": self.convention,
            "precision": self.precision,
            "psnr_cap_db": PSNR_CAP_DB,
            "overall": asdict(self.overall),
            "by_difficulty": {k: asdict(v) for k, v in self.by_difficulty.items()},
            "input": {
                "overall": None if self.input_overall is None else asdict(self.input_overall),
                "by_difficulty": {k: asdict(v) for k, v in self.input_by_difficulty.items()},
            },
            "latency": [lat.as_dict() for lat in self.latency],
            "versus_fp32": None if self.versus_fp32 is None else asdict(self.versus_fp32),
            "precision_reason": self.precision_reason,
            "calibration": self.calibration or None,
            "conversion": self.conversion or None,
            "unread": [asdict(u) for u in self.unread],
            "trained_on_scored_pairs": self.trained_on_scored,
        }


def evaluate_checkpoint(
    checkpoint: Path | LoadedModel,
    data: Path,
    split: str,
    device: torch.device,
    convention: str = "skimage-gaussian",
    precision: str = "fp32",
    latency_runs: int = 30,
    calibration: PairSource | None = None,
    precision_reason: str = "",
) -> EvalResult:
    """Load a checkpoint, score it on ``data`` and time it as deployed.

    Latency: batch 1 at the size of the first pair, on the CPU (always) and
    on CUDA (when available), at ``precision`` where the device supports it;
    ``latency_runs=0`` skips timing. ``int8`` runs the network through ONNX
    Runtime static quantisation (:mod:`lenspair.model.evaluation.quantize`),
    calibrated on ``calibration`` (default: the evaluated pairs themselves),
    CPU only. Any precision other than fp32 is also scored against the fp32
    output (``versus_fp32``). ``checkpoint`` may be one already loaded on
    ``device`` (``lenspair eval`` loads it before its precision line).

    Raises:
        ModelError: unreadable checkpoint, unknown convention; DatasetError.

    """
    parse_metric_convention(convention)
    if isinstance(checkpoint, LoadedModel):
        loaded, checkpoint = checkpoint, checkpoint.path
    else:
        loaded = load_model(checkpoint, device)
    channels = loaded.config.model.channels or 1
    pairs = open_eval_pairs(data, split)
    if len(pairs) == 0:
        raise ModelError(
            f"{data}: split {split!r} holds no pairs (dataset-build leaves a split empty when "
            "there are too few recordings or segments); evaluate another one with --split"
        )
    leading: list[Unread] = []
    first = _first_readable(pairs, leading)
    if note := conversion_note(channels, channels_of(first.input), data):
        log.warning("%s", note)
    calibrated = ""
    if precision == "int8":
        calibrated = (
            "the evaluated pairs themselves: int8's accuracy here is optimistic"
            if calibration is None
            else f"{getattr(calibration, 'root', 'the given pairs')} (an evenly spaced "
            f"sample of its {len(calibration)} pairs' inputs)"
        )
    size = (int(first.input.shape[0]), int(first.input.shape[1]))
    source = pairs if calibration is None else calibration
    network = _deployed(loaded, channels, device, precision, source, size)
    scores, samples, unread, mixed = score_pairs(
        network, pairs, channels, device, convention, precision, unread=leading
    )
    if not scores:
        raise ModelError(
            f"none of the {len(pairs)} pairs can be scored; the first: {unread[0].reason}"
        )
    bad = {u.index for u in unread}
    scored = SubsetSource(pairs, [i for i in range(len(pairs)) if i not in bad]) if bad else pairs
    trained_on = trained_on_scored(loaded, pairs, bad)
    if trained_on:
        log.warning(
            "%s trained on %d of the %d scored pairs of %s, which flatter its scores; score "
            "pairs it did not train on (a test split) for its accuracy",
            checkpoint,
            trained_on,
            len(scores),
            getattr(pairs, "root", data),
        )
    versus_fp32 = None
    if precision != "fp32":
        versus_fp32 = agreement_with_fp32(
            network, loaded.network, scored, channels, device, convention, precision
        )
    latency: list[Latency] = []
    if bad:  # timed at a scored pair's size: the first readable one may be too small to run
        first = scored[0]
        size = (int(first.input.shape[0]), int(first.input.shape[1]))
    if latency_runs > 0:
        latency = _deployed_latency(
            network, loaded.network, channels, device, size, precision, latency_runs
        )
        loaded.network.to(device)
    split_text = (
        ""
        if Path(getattr(pairs, "root", data)).resolve() == Path(data).resolve()
        else f" (split {split})"
    )
    return EvalResult(
        checkpoint=str(checkpoint),
        data=f"{data}{split_text}",
        convention=convention,
        precision=precision,
        scores=scores,
        overall=summarize(scores),
        by_difficulty=breakdown(scores),
        input_overall=summarize(scores, "input"),
        input_by_difficulty=breakdown(scores, "input"),
        latency=latency,
        samples=samples,
        model=to_plain(loaded.config.model),
        versus_fp32=versus_fp32,
        precision_reason=precision_reason,
        unread=unread,
        calibration=calibrated,
        # every converted pair counted: from the first pair alone, a grey pair among colour
        # ones, or colour pairs after a grey first one, left no trace in the reports
        conversion=mixed,
        trained_on_scored=trained_on,
    )


def trained_on_scored(
    loaded: LoadedModel, pairs: PairSource, unread: Collection[int]
) -> int | None:
    """How many of ``pairs`` (less the ``unread`` indices) ``loaded`` trained on.

    Its run recorded the folder it trained on (``runtime.data_path``, and
    those of the sessions it resumed from: ``runtime.earlier_data``) and
    its ``data`` section says how the pairs were split, as
    :func:`~lenspair.model.training.datasets.paired_training_data` splits
    them: a dataset's ``data.train_split`` is trained on whole, unless it has
    no validation split, and a split-less paired folder (or that train split)
    less the pairs held out by name hash (:func:`holdout_indices`).

    A copy of the folder it trained on (the same pair names in its splits,
    by the digest the run recorded) counts as that folder.

    Returns:
        The count; 0 when ``pairs`` are another folder than the one trained
        on (another split), or the run trained on synthetic drops; None when
        the run recorded no folder (written before it was).
    """
    runtime = loaded.config.runtime
    if runtime is None or not runtime.data_path:
        return None
    names = getattr(pairs, "names", None)
    root = getattr(pairs, "root", None)
    if runtime.synthetic or names is None or root is None:
        return 0
    data = loaded.config.data
    # a resumed run trained on each folder it was resumed from too ("/old/DS until step 300")
    earlier = (split_until(entry)[0] for entry in runtime.earlier_data)
    for folder in (runtime.data_path, *earlier):
        count = _count_trained(Path(folder), data, Path(root), names, unread)
        if count is not None:
            return count
    # a copy of the data it trained on (cp -r elsewhere): another path, the same pairs
    digest = recorded_digest(runtime.data)
    for copy in (Path(root), Path(root).parent):
        if digest is not None and pairs_digest(copy, data) == digest:
            return _count_trained(copy, data, Path(root), names, unread) or 0
    return 0


def _count_trained(
    path: Path, data: DataConfig, root: Path, names: Sequence[object], unread: Collection[int]
) -> int | None:
    """How many pairs of ``root`` a run trained on ``path`` trained on; None: not ``path``'s."""
    split_less = detect_layout(path) is not None
    trained = path if split_less else path / data.train_split
    if root.resolve() != trained.resolve():
        return None
    kept: Collection[int] = range(len(names))
    if split_less or not _validated_on_a_split(path, data):
        try:
            kept, _ = holdout_indices([str(n) for n in names], data.val_fraction, trained)
        except ModelError:  # fewer than two pairs: not what any run trained on
            return 0
    return len(set(kept) - set(unread))


def _validated_on_a_split(dataset: Path, data: DataConfig) -> bool:
    """Whether training on ``dataset`` validated on its validation split (held nothing out)."""
    try:
        return validation_split(dataset, data, notes=[]) is not None
    except DatasetError:  # broken since: training refuses such a split, so it validated on it
        return True


def _first_readable(pairs: PairSource, unread: list[Unread]) -> PairItem:
    """The first pair that can be read (the unreadable ones before it go to ``unread``).

    Raises:
        ModelError: no pair can be read (naming the first problem).

    """
    for index in range(len(pairs)):
        if (item := read_pair(pairs, index, unread)) is not None:
            return item
    raise ModelError(f"none of the {len(pairs)} pairs can be read; the first: {unread[0].reason}")


def _deployed(
    loaded: LoadedModel,
    channels: int,
    device: torch.device,
    precision: str,
    calibration: PairSource,
    size: tuple[int, int],
) -> nn.Module:
    """``loaded``'s network as restore deploys it on ``device``, or its int8 quantisation.

    int8 runs through ONNX Runtime static quantisation, calibrated on
    ``calibration`` at ``size`` = (H, W).
    """
    # laid out as restore deploys it (channels-last on the CPU), so that the scores are
    # those of what restore writes: the layouts' rounding differs, most on nearly flat frames
    network: nn.Module = deploy(loaded.network, device)
    if precision == "int8":
        # here, not at the top: only int8 needs ONNX Runtime, which is slow to import
        from lenspair.model.evaluation.quantize import Int8Network, calibration_images

        images = calibration_images(calibration, channels, size)
        network = Int8Network(loaded.network, channels, images)
    return network


def _deployed_latency(
    network: nn.Module,
    fp32_network: nn.Module,
    channels: int,
    device: torch.device,
    size: tuple[int, int],
    precision: str,
    runs: int,
) -> list[Latency]:
    """Batch-1 timings at ``size`` = (H, W): on the CPU, and on ``device`` when it is CUDA.

    ``--device cpu`` on a machine with a GPU times the CPU only: the GPU may be
    busy, or kept from this run (it was timed, and the network moved onto it,
    whenever one was there). fp16 is timed
    at fp32 on the CPU; int8 (ONNX Runtime) on the CPU only. Where a device
    ran a reduced precision, ``fp32_network`` is timed there too: what the
    precision saves in time, beside what it costs (``versus_fp32``).
    """
    devices = [torch.device("cpu")] + ([device] if device.type == "cuda" else [])
    latency = []
    for where in devices:
        if precision == "int8" and where.type != "cpu":
            continue
        timed_precision = "fp32" if (precision == "fp16" and where.type == "cpu") else precision
        latency.append(measure_latency(network, channels, where, size, timed_precision, runs=runs))
        if timed_precision != "fp32":
            latency.append(measure_latency(fp32_network, channels, where, size, "fp32", runs=runs))
    return latency
