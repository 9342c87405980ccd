"""Repeated runs: mean +/- spread over seeds, which differences to claim, convergence.

Short training on a CPU is noisy: two networks trained with different seeds
differ by tenths of a dB. Every accuracy figure lenspair reports from
training is therefore a mean over seeds with its *spread*, the sample
standard deviation over the seeds (``ddof = 1``; 0 for a single seed, which
then supports no claim), and a difference is claimed only when it is larger
than the spread of either side (:func:`clearly_better`).

A budget is long enough when the learning curve has flattened: over the
last 20 % of the budget, the trend of validation PSNR (a least-squares
line, robust to the GAN's validation noise) changed it by less than the
seed spread (:func:`converged`).
"""

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

CONVERGENCE_TAIL = 0.2
"""Share of the budget at the end of training that the convergence check looks at."""


@dataclass(frozen=True)
class SeedSummary:
    """One figure over seeds.

    Attributes:
        values: the per-seed values, in seed order.
        mean: their mean.
        spread: their sample standard deviation (0 for one seed).

    """

    values: tuple[float, ...]
    mean: float
    spread: float

    @property
    def seeds(self) -> int:
        """Number of seeds."""
        return len(self.values)

    def format(self, digits: int = 2) -> str:
        """``25.31 +/- 0.12`` (or the mean alone for one seed)."""
        if self.seeds < 2:
            return f"{self.mean:.{digits}f}"
        return f"{self.mean:.{digits}f} +/- {self.spread:.{digits}f}"


def summarise_seeds(values: Sequence[float]) -> SeedSummary:
    """Mean and spread of per-seed values (finite values only; at least one).

    Raises:
        ValueError: no finite value.

    """
    finite = tuple(float(v) for v in values if math.isfinite(v))
    if not finite:
        raise ValueError("no finite value to summarise")
    spread = statistics.stdev(finite) if len(finite) > 1 else 0.0
    return SeedSummary(values=finite, mean=statistics.fmean(finite), spread=spread)


def clearly_better(first: SeedSummary, second: SeedSummary) -> bool:
    """``first`` beats ``second`` by more than either one's spread (and both have >= 2 seeds)."""
    if first.seeds < 2 or second.seeds < 2:
        return False
    return first.mean - second.mean > max(first.spread, second.spread)


def converged(
    curve: Sequence[tuple[float, float]], budget: float, spread: float
) -> tuple[bool, float] | None:
    """Whether validation PSNR moved no more than ``spread`` over the last 20 % of the budget.

    The change is read off the least-squares line through the points of the
    last 20 % (from the last point at or before 80 % of the budget to the
    end), as its rise over that span: a GAN's validation PSNR jumps by tenths
    of a dB between validations, and the difference of two single points
    would call that noise a trend. With two points it is their difference.

    Args:
        curve: ``(progress, psnr_db)`` points (steps or seconds), any order.
        budget: the budget in the same unit (the last point's progress when
            training stopped early).
        spread: the seed spread of the final PSNR, dB.

    Returns:
        ``(holds, change_db)``; None when no point lies at or before 80 %
        or no point after it.

    """
    points = sorted((p, v) for p, v in curve if math.isfinite(v))
    cut = (1.0 - CONVERGENCE_TAIL) * budget
    before = [point for point in points if point[0] <= cut]
    if not before or points[-1][0] <= before[-1][0]:
        return None
    tail = points[len(before) - 1 :]
    slope, _ = statistics.linear_regression([p for p, _ in tail], [v for _, v in tail])
    change = slope * (tail[-1][0] - tail[0][0])
    return abs(change) <= spread, change  # a flat curve holds when the seeds agree exactly


def robust_pareto(times: Sequence[float | None], scores: Sequence[SeedSummary]) -> list[int]:
    """Indices no other point beats: faster or as fast *and* clearly better (beyond the spread).

    A point with an unknown or NaN time is never on the front. Times are
    medians measured in one run and treated as exact; only accuracy carries
    a spread. With one seed nothing is clearly better, so every point with a
    time is on the front: one seed cannot rank networks.
    """
    valid = [i for i, t in enumerate(times) if t is not None and not math.isnan(t)]
    front = []
    for i in valid:
        time_i = times[i]
        assert time_i is not None
        dominated = False
        for j in valid:
            time_j = times[j]
            assert time_j is not None
            if j != i and time_j <= time_i and clearly_better(scores[j], scores[i]):
                dominated = True
                break
        if not dominated:
            front.append(i)
    return front
