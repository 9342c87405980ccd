"""Score a restoration network on paired images: PSNR/SSIM of each pair, one at a time.

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

A pair that cannot be read or scored costs only itself: it is logged once
and returned with its reason (:class:`~lenspair.model.training.pairs.Unread`).
"""

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn

from lenspair.core.errors import LenspairError, listed
from lenspair.core.pixels import max_value
from lenspair.core.progress import progress
from lenspair.dataset.curation import channel_max
from lenspair.model.errors import ModelError, NonFiniteOutputError, is_out_of_memory
from lenspair.model.evaluation.latency import autocast_context
from lenspair.model.evaluation.summary import (
    DIFFICULTY_ORDER,
    ImageScore,
    Summary,
    fmt_psnr,
    summarize,
)
from lenspair.model.metrics import image_metrics, parse_metric_convention
from lenspair.model.training.pairs import (
    PairItem,
    PairSource,
    SubsetSource,
    Unread,
    channels_of,
    read_pair,
    to_tensor,
)

log = logging.getLogger(__name__)


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


@dataclass(frozen=True)
class SheetRow:
    """One contact-sheet row: float ``(H, W, C)`` input, output and target, a label for each."""

    labels: tuple[str, str, str]
    difficulty: str | None
    images: tuple[np.ndarray, np.ndarray, np.ndarray]


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
    conversion: str = ""
    """How many scored pairs had another channel count than the network and were
    converted, and which ("" when none): for the reports, not only the log."""


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
    *,
    skip_out_of_memory: bool = True,
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
        skip_out_of_memory: a pair the network runs out of memory on is
            skipped and returned with the unread ones; False: a
            :class:`~lenspair.model.errors.ModelError` naming it (the
            tradeoff, whose rows must cover the same pairs).

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
                output = network(x)[1].float()
            # checked before the quantisation, whose clamp turns Inf into 1
            if not bool(torch.isfinite(output).all()) and bool(torch.isfinite(x).all()):
                raise NonFiniteOutputError(
                    f"{item.name}: the network's output at {precision} holds NaN or Inf on a "
                    "finite input: the checkpoint (or this precision) is broken, not the pair; "
                    "no mean over the other pairs is written"
                )
            output = _quantize(output, item.target.dtype)
            psnr, ssim = score_tensors(output, target, convention, valid)
            input_psnr, input_ssim = score_tensors(x.float(), target, convention, valid)
        except NonFiniteOutputError:
            raise  # the network's problem: a mean over the pairs it did not break would hide it
        except LenspairError as exc:  # e.g. smaller than the SSIM window: this pair only
            log.warning("skipped pair %d: %s: %s", index, item.name, exc)
            bad.append(Unread(index, f"{item.name}: {exc}"))
            continue
        except Exception as exc:  # torch's, numpy's allocator: a pair too large costs itself
            if not is_out_of_memory(exc):
                raise
            why = _left_out(item.name, item.input.shape, device, precision, skip_out_of_memory)
            log.warning("skipped pair %d: %s: %s", index, item.name, why)
            bad.append(Unread(index, f"{item.name}: {why}"))
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
    conversion = ""
    if converted:
        conversion = (
            f"{len(converted)} of {read} pair(s) have another channel count than the "
            f"network's {channels} and were converted "
            f"({'to luma' if channels == 1 else 'grey repeated'}): {listed(converted)}"
        )
    if 0 < len(converted) < read:  # mixed; all converted is said by evaluate, from the first
        log.warning("%s", conversion)
    order = {name: i for i, name in enumerate(DIFFICULTY_ORDER)}
    samples.sort(key=lambda row: order.get(row.difficulty or "", len(order)))
    return Scored(scores, samples, sorted(bad, key=lambda u: u.index), conversion)


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


def _left_out(
    name: str, shape: tuple[int, ...], device: torch.device, precision: str, skip: bool
) -> str:
    """Why a pair the network ran out of memory on is left out; or, unless ``skip``, an error.

    Raises:
        ModelError: ``skip`` False (the tradeoff: every row scores the same pairs).
    """
    height, width = shape[:2]
    why = (
        f"out of memory scoring one {width}x{height} frame on {device} ({precision}): eval "
        "scores whole frames; score a crop of it, or restore it in tiles (restore --tile)"
    )
    if not skip:
        raise ModelError(f"{name}: {why}; every row scores the same pairs, so none is left out")
    if device.type == "cuda":  # what the failed pair held (its tensors went with the exception)
        torch.cuda.empty_cache()
    return why


@torch.inference_mode()
def agreement_with_fp32(
    network: nn.Module,
    reference: nn.Module,
    pairs: PairSource,
    channels: int,
    device: torch.device,
    convention: str,
    precision: str,
    *,
    skip_out_of_memory: bool = True,
) -> Summary:
    """Means of ``network``'s output (at ``precision``) scored against fp32 ``reference``'s.

    Both outputs are clamped to [0, 1] and kept in float (no rounding to the
    target's bit depth), so this isolates what the precision changes. Pairs
    that cannot be read or scored are left out (:func:`score_pairs` names them);
    so is a pair either network runs out of memory on, said here (fp32 needs
    more than a reduced precision), or, with ``skip_out_of_memory`` False, a
    :class:`~lenspair.model.errors.ModelError` naming it.
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
        except Exception as exc:  # out of memory: fp32 may need more than the precision did
            if not is_out_of_memory(exc):
                raise
            both = f"fp32 and {precision}"
            why = _left_out(item.name, item.input.shape, device, both, skip_out_of_memory)
            log.warning("pair %d: %s left out of the fp32 agreement: %s", index, item.name, why)
            continue
        height, width = item.input.shape[:2]
        rows.append(ImageScore(item.name, item.difficulty, height, width, psnr, ssim, 0, 0))
    return summarize(rows)
