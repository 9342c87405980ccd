"""Curation rules: image figures of one pair, the filters, near-duplicates, difficulty.

Pure functions on arrays (images per :mod:`lenspair.core.pixels`: ``uint8``/``uint16``,
``(H, W)`` or ``(H, W, 3)`` RGB) and :class:`lenspair.capture.ingested.PairRecord`.

Rules run in the order of :data:`RULES`; a pair is removed by the first rule
it fails, so the removed counts of the rules add up to the pairs removed.
Quality rules, and the clean rule where clean pairs are excluded, come before
the duplicate rule, so that the frame that stands for a run of identical
frames is one that passed them: a clean frame standing for a run of frames
that show the anomaly took the whole run with it when it was excluded.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lenspair.capture.ingested import PairRecord
from lenspair.core.pixels import check_image, max_value
from lenspair.core.quality import (
    anomaly_cells,
    exposure_fractions,
    laplacian_variance,
    to_grey,
)
from lenspair.dataset.config import CurationConfig, Difficulty

RULES: tuple[tuple[str, str], ...] = (
    ("ingest_rejected", "rejected by capture-ingest (status 'rejected' in pairs.jsonl)"),
    ("missing_file", "an image named in pairs.jsonl is missing"),
    ("checksum", "an image's sha256 differs from the one recorded in pairs.jsonl"),
    ("bad_image", "an image cannot be read, or input/target/mask do not match in size or type"),
    ("residual", "registration residual_px > max_residual_px"),
    ("photometric", "photometric_residual > max_photometric_residual"),
    ("inliers", "inliers < min_inliers"),
    ("mask", "fraction of untrustworthy (masked) pixels > max_mask_fraction"),
    ("sharpness", "clean-view variance of Laplacian < min_sharpness (motion blur)"),
    ("exposure", "clean view saturated > max_saturated or black > max_black"),
    ("clean", "no visible anomaly (removed only with clean_pairs: exclude, else tagged)"),
    ("duplicate", "near-identical to the last kept frame of its recording (robot standing still)"),
    ("split_gap", "dropped before a segment border between two splits (no leakage)"),
)
"""(rule name, what it removes), in the order the rules are applied."""

RULE_NAMES: tuple[str, ...] = tuple(name for name, _ in RULES)
THUMBNAIL_SIZE: tuple[int, int] = (32, 24)
"""(width, height) of the grey thumbnails compared for near-duplicates."""
PSNR_CAP_DB = 100.0
"""PSNR reported for identical images (instead of infinity)."""
THUMBNAIL_LEVEL = 0.5
"""Mean grey :func:`level_normalised` scales each thumbnail to before duplicates are sought."""
MIN_THUMBNAIL_LEVEL = 0.02
"""Smallest mean grey :func:`level_normalised` divides by (a black frame is not amplified)."""


@dataclass(frozen=True, eq=False)
class PairStats:
    """Figures measured on the images of one pair.

    Attributes:
        psnr_db: PSNR of input against target over trustworthy pixels, all
            channels, data range 1 (capped at :data:`PSNR_CAP_DB`).
        anomaly_fraction: fraction of trustworthy pixels (at 1/4 resolution)
            where input and target differ by more than ``anomaly_delta``.
        sharpness: variance of the 3x3 Laplacian of the target's grey image,
            on the 8-bit scale.
        saturated: fraction of target pixels with a channel at full scale.
        black: fraction of target pixels with every channel at zero.
        mask_fraction: fraction of pixels marked untrustworthy (0 without mask).
        thumbnail: ``float32`` ``(24, 32)`` grey target in [0, 1].
    """

    psnr_db: float
    anomaly_fraction: float
    sharpness: float
    saturated: float
    black: float
    mask_fraction: float
    thumbnail: np.ndarray


def channel_max(image: np.ndarray) -> np.ndarray:
    """Largest channel value per pixel, ``(H, W)`` (the image itself when mono)."""
    if image.ndim == 2:
        return image
    return np.asarray(np.maximum(np.maximum(image[:, :, 0], image[:, :, 1]), image[:, :, 2]))


def check_pair(input: np.ndarray, target: np.ndarray, mask: np.ndarray | None) -> None:
    """Raise ``ValueError`` unless input/target/mask are images of one size and type."""
    check_image(input, "input")
    check_image(target, "target")
    if input.shape != target.shape or input.dtype != target.dtype:
        raise ValueError(
            f"input {input.shape} {input.dtype} and target {target.shape} {target.dtype} differ"
        )
    if mask is not None and mask.shape[:2] != input.shape[:2]:
        raise ValueError(f"mask {mask.shape} does not match input {input.shape}")


def measure_pair(
    input: np.ndarray,
    target: np.ndarray,
    mask: np.ndarray | None,
    anomaly_delta: float,
) -> PairStats:
    """Measure the curation figures of one pair.

    Args:
        input: obstructed view, ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)``.
        target: clean view, same shape and dtype.
        mask: ``(H, W)`` (or ``(H, W, 3)``) image, non-zero where untrustworthy;
            or None.
        anomaly_delta: grey difference (in [0, 1]) that counts as an anomaly.

    Raises:
        ValueError: the images do not form a pair (shape, dtype).
    """
    check_pair(input, target, mask)
    untrusted = None if mask is None else channel_max(mask) != 0
    mask_fraction = 0.0
    valid = None
    if untrusted is not None:
        mask_fraction = float(np.count_nonzero(untrusted)) / untrusted.size
        valid = None if mask_fraction in (0.0, 1.0) else ~untrusted

    squared = np.square(cv2.absdiff(input, target).astype(np.float32))
    if valid is not None:
        squared = squared[valid]
    mse = float(np.mean(squared, dtype=np.float64)) / max_value(input.dtype) ** 2
    psnr = PSNR_CAP_DB if mse <= 1e-10 else min(PSNR_CAP_DB, 10.0 * float(np.log10(1.0 / mse)))

    target_grey = to_grey(target)
    saturated, black = exposure_fractions(target)
    return PairStats(
        psnr_db=psnr,
        anomaly_fraction=anomaly_fraction(to_grey(input), target_grey, valid, anomaly_delta),
        sharpness=laplacian_variance(target_grey),
        saturated=saturated,
        black=black,
        mask_fraction=mask_fraction,
        thumbnail=cv2.resize(target_grey, THUMBNAIL_SIZE, interpolation=cv2.INTER_AREA),
    )


def anomaly_fraction(
    input_grey: np.ndarray, target_grey: np.ndarray, valid: np.ndarray | None, delta: float
) -> float:
    """Fraction of trustworthy cells where the views differ by more than ``delta``.

    The cells are :func:`lenspair.core.quality.anomaly_cells`' (1/4 resolution,
    median offset removed).
    """
    anomalous, trusted = anomaly_cells(input_grey, target_grey, valid, delta)
    return int(np.count_nonzero(anomalous)) / int(np.count_nonzero(trusted))


def quality_rule(
    record: PairRecord, stats: PairStats, config: CurationConfig
) -> tuple[str, str] | None:
    """First quality rule the pair fails, as ``(rule, reason)``; None when it passes.

    Registration figures come from ``record`` (a missing figure passes); image
    figures come from ``record`` when present, else from ``stats``.
    """
    if record.residual_px is not None and record.residual_px > config.max_residual_px:
        return "residual", f"residual {record.residual_px:.3g} px > {config.max_residual_px:g}"
    photometric = record.photometric_residual
    if photometric is not None and photometric > config.max_photometric_residual:
        limit = config.max_photometric_residual
        return "photometric", f"photometric residual {photometric:.3g} > {limit:g}"
    if record.inliers is not None and record.inliers < config.min_inliers:
        return "inliers", f"{record.inliers} inliers < {config.min_inliers}"
    masked = _first(record.mask_fraction, stats.mask_fraction)
    if masked > config.max_mask_fraction:
        return "mask", f"mask fraction {masked:.3g} > {config.max_mask_fraction:g}"
    sharpness = _first(record.sharpness, stats.sharpness)
    if sharpness < config.min_sharpness:
        return "sharpness", f"sharpness {sharpness:.3g} < {config.min_sharpness:g}"
    saturated = _first(record.saturated, stats.saturated)
    if saturated > config.max_saturated:
        return "exposure", f"saturated fraction {saturated:.3g} > {config.max_saturated:g}"
    black = _first(record.black, stats.black)
    if black > config.max_black:
        return "exposure", f"black fraction {black:.3g} > {config.max_black:g}"
    return None


def level_normalised(thumbnail: np.ndarray) -> np.ndarray:
    """``thumbnail`` scaled to a mean grey of :data:`THUMBNAIL_LEVEL`.

    The difference between two views of a scene scales with the frames'
    exposure: without this, a darker camera or a night session (half the
    level) would call twice as many frames duplicates. A mean below
    :data:`MIN_THUMBNAIL_LEVEL` is taken as that level.
    """
    level = max(float(np.mean(thumbnail)), MIN_THUMBNAIL_LEVEL)
    scaled: np.ndarray = thumbnail * np.float32(THUMBNAIL_LEVEL / level)
    return scaled


def find_duplicates(thumbnails: Sequence[np.ndarray], threshold: float) -> list[bool]:
    """Mark near-duplicates in a time-ordered sequence of thumbnails of one recording.

    Each frame is compared with the last frame that was *kept*, so a run of
    near-identical frames keeps its first frame, and slow drift still keeps
    a frame whenever the scene has changed by ``threshold`` since.

    Args:
        thumbnails: ``float32`` ``(24, 32)`` grey thumbnails in [0, 1], in time order.
        threshold: mean absolute difference below which a frame is a duplicate.

    Returns:
        One flag per thumbnail, True for a duplicate (to be removed).
    """
    flags: list[bool] = []
    last: np.ndarray | None = None
    for thumb in thumbnails:
        duplicate = last is not None and float(np.mean(np.abs(thumb - last))) < threshold
        flags.append(duplicate)
        if not duplicate:
            last = thumb
    return flags


def is_clean(stats: PairStats, config: CurationConfig) -> bool:
    """True when the obstructed and clean views barely differ (no visible anomaly)."""
    return stats.anomaly_fraction < config.min_anomaly_fraction


def difficulty(psnr_db: float, config: CurationConfig) -> Difficulty:
    """``easy`` above ``easy_min_psnr_db``, ``hard`` below ``hard_max_psnr_db``, else ``medium``."""
    if psnr_db > config.easy_min_psnr_db:
        return "easy"
    if psnr_db < config.hard_max_psnr_db:
        return "hard"
    return "medium"


def _first(recorded: float | None, measured: float) -> float:
    return measured if recorded is None else recorded


@dataclass(frozen=True)
class Measured:
    """One line of ``pairs.jsonl`` after its images were read and measured.

    Attributes:
        source: index of the recording in the list of sources.
        index: line index in ``pairs.jsonl``.
        record: the line.
        files: ``input``/``target``/``mask`` -> absolute path of the source image.
        sha256: checksums of those files (empty when the pair was removed).
        stats: measured figures; None when the pair was removed before measuring.
        rule: the rule that removed the pair before measuring (``ingest_rejected``,
            ``missing_file``, ``checksum``, ``bad_image``), or None.
        reason: why, for the log.
    """

    source: int
    index: int
    record: PairRecord
    files: dict[str, Path]
    sha256: dict[str, str]
    stats: PairStats | None = None
    rule: str | None = None
    reason: str | None = None


Removals = dict[tuple[int, int], tuple[str, str]]
"""``(source, index) -> (rule, reason)`` for every removed pair."""


def curate(measured: Sequence[Measured], config: CurationConfig) -> Removals:
    """Apply the quality, clean and duplicate rules to measured pairs.

    Args:
        measured: every line of every source (any order).
        config: thresholds.

    Returns:
        The removed pairs with their rule; pairs removed before measuring keep
        their rule. Survivors are the pairs not in the result.
    """
    removed: Removals = {}
    survivors: dict[int, list[tuple[Measured, PairStats]]] = {}
    for item in measured:
        key = (item.source, item.index)
        if item.rule is not None or item.stats is None:
            removed[key] = (item.rule or "bad_image", item.reason or "")
            continue
        failed = quality_rule(item.record, item.stats, config)
        if failed is None and config.clean_pairs == "exclude" and is_clean(item.stats, config):
            failed = ("clean", "no visible anomaly")
        if failed is not None:
            removed[key] = failed
        else:
            survivors.setdefault(item.source, []).append((item, item.stats))
    for items in survivors.values():
        items.sort(key=lambda pair: pair[0].record.t_ns)
        thumbnails = [level_normalised(stats.thumbnail) for _, stats in items]
        flags = find_duplicates(thumbnails, config.duplicate_threshold)
        for (item, _), duplicate in zip(items, flags, strict=True):
            if duplicate:
                removed[(item.source, item.index)] = (
                    "duplicate",
                    "near-identical to the last kept frame",
                )
    return removed
