"""Per-image scores and their means: over a set of images and per difficulty.

PSNR is infinite when output and target are identical; such an image keeps
``inf`` in the per-image CSV, and means cap it at :data:`PSNR_CAP_DB`
(:mod:`lenspair.model.metrics`; reported with the count of capped images),
so one perfect image cannot make a mean infinite.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from lenspair.model import metrics
from lenspair.model.metrics import PSNR_CAP_DB

DIFFICULTY_ORDER = ("easy", "medium", "hard", "clean")


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
        psnr_db: mean PSNR, values above :data:`PSNR_CAP_DB` (inf too) counted as it.
        ssim: mean SSIM.
        capped: images whose PSNR was above :data:`PSNR_CAP_DB` (infinite, or a
            difference of a few codes in a 16-bit image): their mean counts the cap.

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
        capped=sum(1 for value in psnrs if value > PSNR_CAP_DB),  # inf and finite ones above
    )


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
