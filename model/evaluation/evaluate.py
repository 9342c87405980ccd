"""Evaluate a restoration network on paired images: PSNR/SSIM per image and means.

What is scored: the network's final (enhanced) output for the whole image,
batch 1, clamped to [0, 1] and rounded to the bit depth of the target (what
a deployed model would write), against the target. Both are converted to the
network's channel count first (Rec. 601 luma for a mono network on RGB data).

Metric conventions (:mod:`lenspair.model.metrics`), named in every table:

* ``skimage-gaussian``: scikit-image's ``peak_signal_noise_ratio`` and
  ``structural_similarity(gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False)`` on the [0, 1] images (Wang et al.).
* ``deraindrop-y``: DeRaindrop's published protocol: uint8, the Y channel,
  a 7x7 uniform SSIM window.

PSNR is infinite when output and target are identical; such an image keeps
``inf`` in the per-image CSV, and means cap it at :data:`PSNR_CAP_DB`
(reported with the count of capped images), so one perfect image cannot
make a mean infinite.

The reports (CSV, JSON, Markdown, contact sheet) are written by
:func:`lenspair.model.evaluation.report.write_report`.
"""

import logging
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
import torch
from torch import nn

from lenspair.core.config import to_plain
from lenspair.core.errors import LenspairError, listed
from lenspair.core.imageio import max_value
from lenspair.core.progress import progress
from lenspair.dataset.curation import channel_max
from lenspair.model import metrics
from lenspair.model.checkpoint import LoadedModel, load_model
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.latency import Latency, autocast_context, measure_latency
from lenspair.model.inference.backends import deploy
from lenspair.model.metrics import PSNR_CAP_DB, image_metrics, parse_metric_convention
from lenspair.model.training.pairs import (
    PairItem,
    PairSource,
    SubsetSource,
    Unread,
    channels_of,
    conversion_note,
    open_eval_pairs,
    read_pair,
    to_tensor,
)

log = logging.getLogger(__name__)

CONVENTIONS = tuple(c.value for c in metrics.MetricConvention)
DIFFICULTY_ORDER = ("easy", "medium", "hard", "clean")


def score_tensors(
    output: torch.Tensor,
    target: torch.Tensor,
    convention: str,
    valid: torch.Tensor | None = None,
) -> tuple[float, float]:
    """PSNR (dB) and SSIM of one ``(1, C, H, W)`` output against its target, in [0, 1].

    ``valid`` (``(1, 1, H, W)``, non-zero where trustworthy; a dataset's
    ``mask/`` marks the others) leaves the untrustworthy pixels out, as
    training leaves them out of its loss (:mod:`lenspair.model.metrics`).

    Raises:
        ModelError: unknown convention; no trustworthy pixel to score.

    """
    scores = image_metrics(output, target, parse_metric_convention(convention), valid)
    return float(scores.psnr[0]), float(scores.ssim[0])


def trusted(item: PairItem) -> torch.Tensor | None:
    """The pair's trustworthy pixels as ``(1, 1, H, W)`` (its ``mask/`` is 0), or None."""
    return None if item.mask is None else torch.from_numpy(channel_max(item.mask) == 0)[None, None]


def mean_psnr(values: Sequence[float]) -> float:
    """Mean PSNR, each value capped at :data:`PSNR_CAP_DB` (``inf`` -> cap); NaN when empty."""
    if not values:
        return math.nan
    return metrics.mean_psnr(torch.tensor(list(values), dtype=torch.float64))


@dataclass(frozen=True)
class ImageScore:
    """Scores of one pair (PSNR may be ``inf``).

    ``psnr_db``/``ssim`` score the network's output against the target;
    ``input_psnr_db``/``input_ssim`` score the input itself (no restoration),
    the baseline any restoration has to beat.
    """

    name: str
    difficulty: str | None
    height: int
    width: int
    psnr_db: float
    ssim: float
    input_psnr_db: float = math.nan
    input_ssim: float = math.nan


@dataclass(frozen=True)
class Summary:
    """Means over a set of images.

    Attributes:
        pairs: number of images.
        psnr_db: mean PSNR, infinite values capped at :data:`PSNR_CAP_DB`.
        ssim: mean SSIM.
        capped: images whose PSNR was infinite.

    """

    pairs: int
    psnr_db: float
    ssim: float
    capped: int


def summarize(scores: Sequence[ImageScore], of: Literal["output", "input"] = "output") -> Summary:
    """Means of ``scores`` (see :class:`Summary`): of the outputs, or of the inputs."""
    psnrs = [s.psnr_db if of == "output" else s.input_psnr_db for s in scores]
    ssims = [s.ssim if of == "output" else s.input_ssim for s in scores]
    return Summary(
        pairs=len(scores),
        psnr_db=mean_psnr(psnrs),
        ssim=float(np.mean(ssims)) if scores else math.nan,
        capped=sum(1 for value in psnrs if math.isinf(value)),
    )


@dataclass(frozen=True)
class SheetRow:
    """One contact-sheet row: float ``(H, W, C)`` input, output and target, a label for each."""

    labels: tuple[str, str, str]
    difficulty: str | None
    images: tuple[np.ndarray, np.ndarray, np.ndarray]


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
        latency: timings (CPU, and CUDA when present).
        samples: contact-sheet rows (input, output, target).
        model: the checkpoint's ``model`` config section (plain data).
        versus_fp32: means of the output scored against the fp32 output
            (reduced precisions only): what the precision costs.
        precision_reason: why this precision (``lenspair.model.precision``).
        unread: pairs that could not be read or scored, and why (not in any mean).
        data_path: the scored folder, resolved, as ``lenspair eval`` sets it
            (it tells evaluations of namesake datasets apart by it).

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
            "unread": [asdict(u) for u in self.unread],
        }


def _to_numpy(batch: torch.Tensor) -> np.ndarray:
    return np.asarray(batch[0].detach().float().cpu().numpy().transpose(1, 2, 0))


def _quantize(image: torch.Tensor, dtype: np.dtype[Any]) -> torch.Tensor:
    scale = max_value(dtype)
    return torch.round(image.clamp(0.0, 1.0) * scale) / scale


class Scored(NamedTuple):
    """What :func:`score_pairs` returns."""

    scores: list[ImageScore]
    samples: list[SheetRow]
    unread: list[Unread]


@torch.inference_mode()
def score_pairs(
    network: nn.Module,
    pairs: PairSource,
    channels: int,
    device: torch.device,
    convention: str = "skimage-gaussian",
    precision: str = "fp32",
    samples_per_difficulty: int = 2,
    max_samples: int = 6,
    unread: Sequence[Unread] = (),
) -> Scored:
    """Score ``network`` on every pair, one whole image at a time (batch 1).

    On the CPU each input is channels-last, as restore's backend gives it.

    Args:
        network: forward(x) -> (generator_out, enhanced_out); eval mode is set.
        pairs: pairs from ``lenspair.dataset.readers`` (any image size, odd ones too).
        channels: the network's channels.
        device: where to run it.
        convention: ``skimage-gaussian`` or ``deraindrop-y``.
        precision: ``fp32``, ``bf16`` or ``fp16`` (autocast).
        samples_per_difficulty: contact-sheet rows per difficulty, when known.
        max_samples: contact-sheet rows when difficulties are unknown.
        unread: pairs already known to be unreadable: skipped, and returned.

    Returns:
        Per-image scores, contact-sheet rows in easy/medium/hard order, and
        the pairs that could not be read (each logged once): one bad pair
        costs only itself.

    """
    network.to(device).eval()
    scores: list[ImageScore] = []
    samples: list[SheetRow] = []
    taken: dict[str, int] = {}
    bad = list(unread)
    known = {u.index for u in bad}
    converted: list[str] = []
    read = 0
    for index in progress(range(len(pairs)), "evaluating", total=len(pairs), unit="image"):
        if index in known or (item := read_pair(pairs, index, bad)) is None:
            continue
        read += 1
        if channels_of(item.input) != channels:
            converted.append(item.name)
        try:
            x = to_tensor(item.input, channels)[None].to(device)
            if device.type == "cpu":  # as restore's backend runs it (its output, to the code)
                x = x.contiguous(memory_format=torch.channels_last)
            target = to_tensor(item.target, channels)[None].to(device)
            valid = trusted(item)
            with autocast_context(device, precision):
                output = network(x)[1]
            output = _quantize(output.float(), item.target.dtype)
            psnr, ssim = score_tensors(output, target, convention, valid)
            input_psnr, input_ssim = score_tensors(x.float(), target, convention, valid)
        except LenspairError as exc:  # e.g. smaller than the SSIM window: this pair only
            log.warning("skipped pair %d: %s: %s", index, item.name, exc)
            bad.append(Unread(index, f"{item.name}: {exc}"))
            continue
        height, width = item.input.shape[:2]
        scores.append(
            ImageScore(
                item.name, item.difficulty, height, width, psnr, ssim, input_psnr, input_ssim
            )
        )
        key = item.difficulty or ""
        if taken.get(key, 0) < (samples_per_difficulty if key else max_samples):
            taken[key] = taken.get(key, 0) + 1
            samples.append(
                SheetRow(
                    (
                        f"{key or 'input'} input {fmt_psnr(input_psnr)} dB",
                        f"output {fmt_psnr(psnr)} dB",
                        f"target {item.name}",
                    ),
                    item.difficulty,
                    (_to_numpy(x), _to_numpy(output), _to_numpy(target)),
                )
            )
    if 0 < len(converted) < read:  # mixed; all converted is said by evaluate, from the first
        log.warning(
            "%d pair(s) have another channel count than the network's %d and were converted "
            "(%s): %s",
            len(converted),
            channels,
            "to luma" if channels == 1 else "grey repeated",
            listed(converted),
        )
    order = {name: i for i, name in enumerate(DIFFICULTY_ORDER)}
    samples.sort(key=lambda row: order.get(row.difficulty or "", len(order)))
    return Scored(scores, samples, sorted(bad, key=lambda u: u.index))


@torch.inference_mode()
def scorable_pairs(
    pairs: PairSource, channels: int, convention: str
) -> tuple[PairSource, list[Unread]]:
    """Read every pair and score its input once (no network): the usable ones, and why not.

    For scoring the same pairs many times (``tradeoff`` scores each variant
    and precision after training it): a truncated file, a size mismatch or
    an image under the SSIM window is found, and said, before any training.

    Returns:
        ``pairs`` itself when all are usable, else a :class:`SubsetSource` of
        the usable ones; and the others, by their index in ``pairs``.
    """
    unread: list[Unread] = []
    good = []
    for index in range(len(pairs)):
        if (item := read_pair(pairs, index, unread)) is None:
            continue
        try:
            x, target = (to_tensor(image, channels)[None] for image in (item.input, item.target))
            score_tensors(x, target, convention, trusted(item))
        except LenspairError as exc:
            log.warning("skipped pair %d: %s: %s", index, item.name, exc)
            unread.append(Unread(index, f"{item.name}: {exc}"))
            continue
        good.append(index)
    return (pairs if not unread else SubsetSource(pairs, good)), unread


@torch.inference_mode()
def agreement_with_fp32(
    network: nn.Module,
    reference: nn.Module,
    pairs: PairSource,
    channels: int,
    device: torch.device,
    convention: str,
    precision: str,
) -> Summary:
    """Means of ``network``'s output (at ``precision``) scored against fp32 ``reference``'s.

    Both outputs are clamped to [0, 1] and kept in float (no rounding to the
    target's bit depth), so this isolates what the precision changes. Pairs
    that cannot be read or scored are left out (:func:`score_pairs` names them).
    """
    reference.to(device).eval()
    rows = []
    for index in progress(range(len(pairs)), "versus fp32", total=len(pairs), unit="image"):
        try:
            item = pairs[index]
            x = to_tensor(item.input, channels)[None].to(device)
            with autocast_context(device, precision):
                output = network(x)[1].float().clamp(0, 1).to(device)
            expected = reference(x)[1].float().clamp(0, 1)
            psnr, ssim = score_tensors(output, expected, convention)
        except LenspairError:  # said by score_pairs, which met it first
            continue
        height, width = item.input.shape[:2]
        rows.append(ImageScore(item.name, item.difficulty, height, width, psnr, ssim, 0, 0))
    return summarize(rows)


def breakdown(
    scores: Sequence[ImageScore], of: Literal["output", "input"] = "output"
) -> dict[str, Summary]:
    """Means per difficulty, in easy/medium/hard/clean order (empty when unknown)."""
    groups: dict[str, list[ImageScore]] = {}
    for score in scores:
        if score.difficulty:
            groups.setdefault(score.difficulty, []).append(score)
    order = {name: i for i, name in enumerate(DIFFICULTY_ORDER)}
    return {
        k: summarize(groups[k], of) for k in sorted(groups, key=lambda k: (order.get(k, 99), k))
    }


def fmt_psnr(value: float) -> str:
    """A PSNR in dB for tables and labels: two decimals, or ``inf``."""
    return "inf" if math.isinf(value) else f"{value:.2f}"


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
    size = (int(first.input.shape[0]), int(first.input.shape[1]))
    # laid out as restore deploys it (channels-last on the CPU), so that the scores are
    # those of what restore writes: the layouts' rounding differs, most on nearly flat frames
    network: nn.Module = deploy(loaded.network, device)
    if precision == "int8":
        # here, not at the top: only int8 needs ONNX Runtime, which is slow to import
        from lenspair.model.evaluation.quantize import Int8Network, calibration_images

        source = pairs if calibration is None else calibration
        images = calibration_images(source, channels, size)
        network = Int8Network(loaded.network, channels, images)
    scores, samples, unread = score_pairs(
        network, pairs, channels, device, convention, precision, unread=leading
    )
    if not scores:
        raise ModelError(
            f"none of the {len(pairs)} pairs can be scored; the first: {unread[0].reason}"
        )
    bad = {u.index for u in unread}
    scored = SubsetSource(pairs, [i for i in range(len(pairs)) if i not in bad]) if bad else pairs
    versus_fp32 = None
    if precision != "fp32":
        versus_fp32 = agreement_with_fp32(
            network, loaded.network, scored, channels, device, convention, precision
        )
    latency = []
    if bad:  # timed at a scored pair's size: the first readable one may be too small to run
        first = scored[0]
        size = (int(first.input.shape[0]), int(first.input.shape[1]))
    if latency_runs > 0:
        cuda = device if device.type == "cuda" else torch.device("cuda")
        devices = [torch.device("cpu")] + ([cuda] if torch.cuda.is_available() else [])
        for where in devices:
            timed_precision = "fp32" if (precision == "fp16" and where.type == "cpu") else precision
            if precision == "int8" and where.type != "cpu":
                continue
            latency.append(
                measure_latency(
                    network,
                    channels,
                    where,
                    (size[0], size[1]),
                    timed_precision,
                    runs=latency_runs,
                )
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
    )


def _first_readable(pairs: PairSource, unread: list[Unread]) -> PairItem:
    """The first pair that can be read (the unreadable ones before it go to ``unread``).

    Raises:
        ModelError: no pair can be read (naming the first problem).

    """
    for index in range(len(pairs)):
        if (item := read_pair(pairs, index, unread)) is not None:
            return item
    raise ModelError(f"none of the {len(pairs)} pairs can be read; the first: {unread[0].reason}")
