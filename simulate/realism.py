"""How real do synthetic drops look: the statistics of issue 12's table.

For a pair (obstructed, clean), both converted to grey in ``[0, 1]`` (the
encoded values, as stored; RGB is reduced with the ITU-R 601 luma weights
of ``cv2.cvtColor``) and ``d = obstructed - clean``:

* ``coverage``: share of pixels where ``|GaussianBlur(d, sigma 2)| > 0.05``:
  how much of the frame the glass visibly changes.
* ``high_frequency``: ``sum((d - GaussianBlur(d, sigma 4))^2) / sum(d^2)``:
  how sharp the change is (0 for a change that is smooth at that scale, 1
  for pixel noise); 0 when ``d`` is zero everywhere.
* ``mean_difference``: mean of ``d`` (positive: the glass brightens).
* ``contrast_ratio``: ``std(obstructed) / std(clean)`` (below 1: a veil).
* ``input_psnr``: PSNR of the obstructed image against the clean one, dB
  (scikit-image, data range 1; ``inf`` for identical images).

Gaussian blurs are OpenCV's with reflected borders and a kernel of
``2 * ceil(3 sigma) + 1`` taps. :data:`REAL_RANGES` holds the ranges measured
on four real Raindrop-like pairs (a camera behind wet glass, focused far),
from the issue.
"""

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, fields

import cv2
import numpy as np

from lenspair.core.pixels import check_image
from lenspair.core.quality import to_grey
from lenspair.simulate.effects.spec import EffectsSpec
from lenspair.simulate.errors import SimulateError
from lenspair.simulate.render import render_effects

COVERAGE_SIGMA = 2.0
COVERAGE_THRESHOLD = 0.05
HIGH_FREQUENCY_SIGMA = 4.0


@dataclass(frozen=True)
class RealismStatistics:
    """The table's statistics for one pair (see the module docstring).

    Attributes:
        coverage: share of visibly changed pixels, ``[0, 1]``.
        high_frequency: high-frequency share of the difference energy, ``[0, 1]``.
        mean_difference: mean of ``obstructed - clean``, grey ``[-1, 1]``.
        contrast_ratio: ``std(obstructed) / std(clean)``, >= 0.
        input_psnr: dB, ``inf`` for identical images.

    """

    coverage: float
    high_frequency: float
    mean_difference: float
    contrast_ratio: float
    input_psnr: float


STATISTIC_NAMES: tuple[str, ...] = tuple(f.name for f in fields(RealismStatistics))

STATISTIC_LABELS: dict[str, str] = {
    "coverage": "coverage: share where abs(GaussianBlur(d, 2)) > 0.05",
    "high_frequency": "high-frequency share of d (sigma 4)",
    "mean_difference": "mean of d (positive = brighter)",
    "contrast_ratio": "contrast ratio std(obstructed) / std(clean)",
    "input_psnr": "input PSNR (dB)",
}

REAL_RANGES: dict[str, tuple[float, float]] = {
    "coverage": (0.25, 0.58),
    "high_frequency": (0.11, 0.30),
    "mean_difference": (0.02, 0.09),
    "contrast_ratio": (0.68, 0.90),
    "input_psnr": (15.0, 20.8),
}
"""Real adherent drops, 4 Raindrop-like pairs (issue 12's table), min and max."""


def _blur(values: np.ndarray, sigma: float) -> np.ndarray:
    size = 2 * math.ceil(3 * sigma) + 1
    blurred: np.ndarray = cv2.GaussianBlur(
        values, (size, size), sigma, borderType=cv2.BORDER_REFLECT_101
    )
    return blurred


def _counted_blur(values: np.ndarray, counted: np.ndarray, sigma: float) -> np.ndarray:
    """:func:`_blur` over the counted pixels only: ``blur(d w) / blur(w)``, ``w`` = counted.

    A normalised convolution: a counted pixel's blurred value is the weighted
    mean of its counted neighbours, so the mask's shape changes nothing there
    (with the untrusted pixels set to zero and blurred, a constant difference
    lost about a quarter of its coverage beside a grid of small masks, and
    the mask's edges read as detail). Uncounted pixels get 0.
    """
    if counted.all():
        return _blur(values, sigma)
    weights = counted.astype(np.float32)
    spread = _blur(weights, sigma)
    blurred = _blur(values * weights, sigma)
    counted_mean: np.ndarray = np.divide(
        blurred, spread, out=np.zeros_like(blurred), where=spread > 1e-6
    )
    return counted_mean


def realism_statistics(
    obstructed: np.ndarray, clean: np.ndarray, untrusted: np.ndarray | None = None
) -> RealismStatistics:
    """The table's statistics for one (obstructed, clean) pair.

    Args:
        obstructed: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)``.
        clean: same height and width. Grey or RGB and 8 or 16 bits may
            differ from ``obstructed``: both are compared as grey ``[0, 1]``.
        untrusted: ``(H, W)`` (or ``(H, W, C)``: any channel set, as a
            dataset's mask file is read), non-zero where the pair cannot be trusted (an
            ingested recording's ``mask/``: residual parallax of near
            objects). Those pixels are left out of every statistic, the
            blurs too (:func:`_counted_blur`: their difference neither
            spreads into the pixels around them nor dilutes them), so a
            misregistration is not counted as the glass. None: every pixel
            counts.

    Returns:
        The statistics, all finite except ``input_psnr`` (``inf`` when the
        images are identical where they are counted).

    Raises:
        SimulateError: the sizes differ, every pixel is untrusted, or the
            clean image is flat where counted (its contrast ratio is undefined).

    """
    # Imported here: skimage.metrics pulls in scipy.stats (about 2 s), which
    # `lenspair realism --help` and the commands importing this module should not pay.
    from skimage.metrics import peak_signal_noise_ratio

    if obstructed.shape[:2] != clean.shape[:2]:
        raise SimulateError(
            f"pair: obstructed {obstructed.shape[1]}x{obstructed.shape[0]} and clean "
            f"{clean.shape[1]}x{clean.shape[0]} differ in size"
        )
    if untrusted is not None and untrusted.ndim == 3:  # (H, W, 1) indexed 2-D arrays in 3-D
        untrusted = untrusted.max(axis=2)
    if untrusted is not None and (untrusted.ndim != 2 or untrusted.shape != clean.shape[:2]):
        raise SimulateError(
            f"pair: mask {untrusted.shape[1]}x{untrusted.shape[0]} and images "
            f"{clean.shape[1]}x{clean.shape[0]} differ in size"
        )
    try:
        check_image(obstructed)
        check_image(clean)
        grey_obstructed, grey_clean = to_grey(obstructed), to_grey(clean)
    except ValueError as exc:
        raise SimulateError(str(exc)) from None
    counted = np.ones(clean.shape[:2], bool) if untrusted is None else untrusted == 0
    if not counted.any():
        raise SimulateError("every pixel is marked untrustworthy in the mask: nothing to measure")
    clean_std = float(grey_clean[counted].std(dtype=np.float64))
    if clean_std == 0.0:
        raise SimulateError("clean image is flat: its contrast ratio is undefined")
    difference = np.where(counted, grey_obstructed - grey_clean, 0.0).astype(np.float32)
    energy = float(np.square(difference[counted], dtype=np.float64).sum())
    detail = difference - _counted_blur(difference, counted, HIGH_FREQUENCY_SIGMA)
    high = float(np.square(detail[counted], dtype=np.float64).sum()) / energy if energy > 0 else 0.0
    visible = np.abs(_counted_blur(difference, counted, COVERAGE_SIGMA)) > COVERAGE_THRESHOLD
    psnr = (
        math.inf
        if energy == 0
        else float(
            peak_signal_noise_ratio(grey_clean[counted], grey_obstructed[counted], data_range=1.0)
        )
    )
    return RealismStatistics(
        coverage=float(visible[counted].mean()),
        high_frequency=min(high, 1.0),
        mean_difference=float(difference[counted].mean(dtype=np.float64)),
        contrast_ratio=float(grey_obstructed[counted].std(dtype=np.float64)) / clean_std,
        input_psnr=psnr,
    )


@dataclass(frozen=True)
class StatisticRange:
    """Range of one statistic over a set of pairs, beside the real range.

    Attributes:
        name: statistic name (a :class:`RealismStatistics` field).
        low: smallest value over the pairs.
        high: largest value.
        median: median value.
        real: the real range from :data:`REAL_RANGES`.
        inside: how many of the pairs lie within the real range.
        count: how many pairs there are.

    """

    name: str
    low: float
    high: float
    median: float
    real: tuple[float, float]
    inside: int = 0
    count: int = 0

    @property
    def overlaps(self) -> bool:
        """Whether ``[low, high]`` and the real range intersect."""
        return self.low <= self.real[1] and self.high >= self.real[0]


def summarise(rows: Iterable[RealismStatistics]) -> list[StatisticRange]:
    """Min, max and median of every statistic over ``rows`` (at least one)."""
    table = list(rows)
    if not table:
        raise SimulateError("no pairs to summarise")
    ranges = []
    for name in STATISTIC_NAMES:
        values = np.array([getattr(row, name) for row in table], np.float64)
        real_low, real_high = REAL_RANGES[name]
        ranges.append(
            StatisticRange(
                name=name,
                low=float(values.min()),
                high=float(values.max()),
                median=float(np.median(values)),
                real=REAL_RANGES[name],
                inside=int(np.count_nonzero((values >= real_low) & (values <= real_high))),
                count=len(values),
            )
        )
    return ranges


def _number(name: str, value: float) -> str:
    if name == "input_psnr":
        return f"{value:.1f}"
    if name == "mean_difference":
        return f"{value:+.3f}"
    return f"{value:.2f}"


def format_ranges(columns: Sequence[tuple[str, Sequence[StatisticRange]]]) -> str:
    """A Markdown table: the real range, then each column's range, median and share inside it.

    A range can overlap the real one while most pairs miss it (a wide spread
    over different photographs): the median and how many pairs lie within
    the real range say which.

    Args:
        columns: ``(label, summarise(...))`` per set of pairs (a preset, a folder).

    Returns:
        The table; a cell is marked ``*`` when its range misses the real range.

    """
    labels = [label.replace("|", "\\|") for label, _ in columns]  # a folder a|b: one cell
    header = "| statistic | real adherent drops (4 pairs) | " + " | ".join(labels)
    lines = [header + " |", "|---|---|" + "---|" * len(columns)]
    for index, name in enumerate(STATISTIC_NAMES):
        low, high = REAL_RANGES[name]
        cells = [STATISTIC_LABELS[name], f"{_number(name, low)} - {_number(name, high)}"]
        for _, ranges in columns:
            entry = ranges[index]
            mark = "" if entry.overlaps else " *"
            cells.append(
                f"{_number(name, entry.low)} - {_number(name, entry.high)}{mark}, median "
                f"{_number(name, entry.median)} ({entry.inside}/{entry.count} within)"
            )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


@dataclass(frozen=True)
class PairStatistics:
    """The statistics of one named pair, or why it has none.

    Attributes:
        name: the pair's name.
        statistics: the statistics, or None when the pair was skipped.
        problem: why the pair was skipped (one line), else None.

    """

    name: str
    statistics: RealismStatistics | None
    problem: str | None = None


MeasuredPair = tuple[str, np.ndarray, np.ndarray, np.ndarray | None]
"""``(name, obstructed, clean, untrusted)``: see :func:`realism_statistics`."""


def measure_pairs(pairs: Iterable[MeasuredPair]) -> list[PairStatistics]:
    """Statistics of ``(name, obstructed, clean, untrusted)``; a bad pair is recorded, not fatal."""
    results = []
    for name, obstructed, clean, untrusted in pairs:
        try:
            results.append(PairStatistics(name, realism_statistics(obstructed, clean, untrusted)))
        except SimulateError as exc:
            results.append(PairStatistics(name, None, str(exc)))
        except MemoryError:  # its float copies (about 40 bytes a pixel): the others go on
            pixels = clean.shape[0] * clean.shape[1]
            problem = f"too large to measure in this memory ({pixels / 1e6:.0f} megapixels)"
            results.append(PairStatistics(name, None, problem))
    return results


def rendered_pairs(
    images: dict[str, np.ndarray], effects: EffectsSpec, seed: int
) -> Iterator[MeasuredPair]:
    """``(name, obstructed, clean, None)`` with ``effects`` rendered over each clean image.

    Image ``i`` (in the dict's order) gets the glass of ``default_rng((seed, i))``,
    so a preset's pairs do not depend on which other presets are measured.
    """
    for index, (name, clean) in enumerate(images.items()):
        obstructed, _ = render_effects(clean, effects, np.random.default_rng((seed, index)))
        yield name, obstructed, clean, None  # rendered: every pixel is the glass's doing
