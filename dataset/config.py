"""Typed configuration of ``dataset-build``: curation thresholds and split settings.

Loaded from YAML through :func:`lenspair.core.config.load_yaml` (unknown keys and
wrong types are rejected with their dotted path); every key is optional::

    curation:
      max_residual_px: 2.0          # registration residual (px)
      max_photometric_residual: 0.06
      min_inliers: 20
      max_mask_fraction: 0.5
      min_sharpness: 20.0           # variance of the Laplacian, 8-bit grey scale
      max_saturated: 0.2
      max_black: 0.2
      duplicate_threshold: 0.004    # mean |diff| of 32x24 grey thumbnails at mean grey 0.5
      anomaly_delta: 0.03
      min_anomaly_fraction: 0.002
      clean_pairs: keep             # keep (tagged difficulty "clean") or exclude
      easy_min_psnr_db: 25.0
      hard_max_psnr_db: 20.0
    split:
      fractions: [0.8, 0.1, 0.1]    # train, val, test
      seed: 0
      group_by: auto                # auto, recording or segment
      min_groups_per_split: 3
      segment_frames: 100
      segment_gap_frames: 3

The resolved configuration is written beside the dataset as ``config.yaml``
and copied into the dataset card.
"""

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

from lenspair.core.config import MAX_SEED, load_yaml

SPLITS: tuple[str, str, str] = ("train", "val", "test")
"""Split names, in the order of :attr:`SplitConfig.fractions`."""

Difficulty = Literal["easy", "medium", "hard", "clean"]
DIFFICULTIES: tuple[Difficulty, ...] = ("easy", "medium", "hard", "clean")


@dataclass(frozen=True)
class CurationConfig:
    """Thresholds of the curation rules (a pair failing any rule is removed).

    A rule whose figure is missing from ``pairs.jsonl`` (``None``) and cannot be
    measured from the images (registration figures) passes.

    Attributes:
        max_residual_px: largest registration residual ``residual_px`` (pixels).
        max_photometric_residual: largest ``photometric_residual`` (mean
            absolute difference outside anomalies, fraction of full scale).
        min_inliers: fewest feature matches supporting the homography.
        max_mask_fraction: largest fraction of untrustworthy pixels (``mask/``).
        min_sharpness: smallest variance of the 3x3 Laplacian of the clean
            view's grey image on the 8-bit scale (0..255); lower means motion
            blur or defocus. ``PairRecord.sharpness`` is used when present.
        max_saturated: largest fraction of clean-view pixels at full scale.
        max_black: largest fraction of clean-view pixels at zero.
        duplicate_threshold: consecutive frames of one recording whose 32x24
            grey target thumbnails differ by less than this mean absolute
            difference (in [0, 1], each thumbnail first scaled to a mean grey
            of 0.5, so that the camera's exposure does not move it) from the
            last kept frame are duplicates (a robot standing still); the first
            of such a run is kept.
        anomaly_delta: a pixel differs between input and target when its grey
            difference (at 1/4 resolution, after removing the median offset)
            exceeds this, in [0, 1].
        min_anomaly_fraction: pairs with fewer differing pixels than this
            fraction show (almost) no anomaly and are tagged ``clean``.
        clean_pairs: ``keep`` keeps such pairs with difficulty ``clean``
            (a model should learn to leave clean images alone); ``exclude``
            removes them (counted by the ``clean`` rule).
        easy_min_psnr_db: input-vs-target PSNR above which a pair is ``easy``.
        hard_max_psnr_db: PSNR below which a pair is ``hard``; in between,
            ``medium``.
    """

    max_residual_px: float = 2.0
    max_photometric_residual: float = 0.06
    min_inliers: int = 20
    max_mask_fraction: float = 0.5
    min_sharpness: float = 20.0
    max_saturated: float = 0.2
    max_black: float = 0.2
    duplicate_threshold: float = 0.004
    anomaly_delta: float = 0.03
    min_anomaly_fraction: float = 0.002
    clean_pairs: Literal["keep", "exclude"] = "keep"
    easy_min_psnr_db: float = 25.0
    hard_max_psnr_db: float = 20.0

    def __post_init__(self) -> None:
        """Check ranges; the loader reports a ``ValueError`` with the file name."""
        for name, value in vars(self).items():  # NaN passes every comparison below
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"{name}: expected a finite number, got {value}")
        for name in ("max_mask_fraction", "max_saturated", "max_black", "min_anomaly_fraction"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name}: expected a fraction in [0, 1], got {value}")
        for name in ("max_residual_px", "min_sharpness", "duplicate_threshold", "anomaly_delta"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}: must be >= 0, got {getattr(self, name)}")
        if self.hard_max_psnr_db > self.easy_min_psnr_db:
            raise ValueError(
                f"hard_max_psnr_db ({self.hard_max_psnr_db}) must not exceed "
                f"easy_min_psnr_db ({self.easy_min_psnr_db})"
            )


@dataclass(frozen=True)
class SplitConfig:
    """How pairs are grouped and assigned to train/val/test.

    Attributes:
        fractions: target fractions of groups for train, val and test (sum 1).
        seed: mixed into the group hash; another seed gives another split.
        group_by: ``recording`` keeps each recording in one split;
            ``segment`` cuts recordings into contiguous segments; ``auto``
            uses recordings when there are at least ``min_groups_per_split``
            of them per non-empty split, segments otherwise.
        min_groups_per_split: see ``group_by: auto``.
        segment_frames: length of a segment, in lines of ``pairs.jsonl``
            (obstructed frames, kept or rejected at ingest).
        segment_gap_frames: pairs dropped before a border between two splits
            within a recording, counted among the pairs that survived curation
            (see :mod:`lenspair.dataset.splits`).
    """

    fractions: tuple[float, float, float] = (0.8, 0.1, 0.1)
    seed: int = 0
    group_by: Literal["auto", "recording", "segment"] = "auto"
    min_groups_per_split: int = 3
    segment_frames: int = 100
    segment_gap_frames: int = 3

    def __post_init__(self) -> None:
        """Check that the fractions are a distribution and the lengths positive."""
        if any(f < 0 or not math.isfinite(f) for f in self.fractions):
            raise ValueError(f"fractions: expected values >= 0, got {self.fractions}")
        if abs(sum(self.fractions) - 1.0) > 1e-6:
            raise ValueError(f"fractions: must sum to 1, got {sum(self.fractions):.6g}")
        if self.fractions[0] <= 0:
            raise ValueError("fractions: the train fraction must be > 0")
        if not 0 <= self.seed <= MAX_SEED:  # the range --seed takes
            raise ValueError(f"seed: expected 0 .. {MAX_SEED}, got {self.seed}")
        for name in ("segment_frames", "min_groups_per_split"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected at least 1, got {getattr(self, name)}")
        if not 0 <= self.segment_gap_frames < self.segment_frames:
            raise ValueError(
                f"segment_gap_frames: expected 0 <= gap < segment_frames "
                f"({self.segment_frames}), got {self.segment_gap_frames}"
            )


@dataclass(frozen=True)
class DatasetConfig:
    """Everything ``dataset-build`` reads from ``--config``."""

    curation: CurationConfig = field(default_factory=CurationConfig)
    split: SplitConfig = field(default_factory=SplitConfig)


def load_dataset_config(path: Path | None) -> DatasetConfig:
    """Load ``path`` (YAML), or the defaults when ``path`` is None.

    Raises:
        ConfigError: unknown key, wrong type or out-of-range value, naming the
            file and the dotted key.
    """
    return DatasetConfig() if path is None else load_yaml(DatasetConfig, Path(path))


def parse_fractions(text: str) -> tuple[float, float, float]:
    """Parse ``"0.8,0.1,0.1"`` into three fractions, checked as :class:`SplitConfig` does.

    Raises:
        ValueError: not three comma-separated numbers, or not a distribution
            with a positive train fraction.
    """
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 3:
        raise ValueError(f"expected three comma-separated fractions (train,val,test), got {text!r}")
    try:
        train, val, test = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"expected numbers like 0.8,0.1,0.1, got {text!r}") from None
    try:
        SplitConfig(fractions=(train, val, test))
    except ValueError as exc:  # said of the text typed, not of a config key
        raise ValueError(f"{str(exc).removeprefix('fractions: ')} ({text!r})") from None
    return (train, val, test)


def with_overrides(
    config: DatasetConfig,
    curation: dict[str, object] | None = None,
    split: dict[str, object] | None = None,
) -> DatasetConfig:
    """Return ``config`` with the non-None values of the given fields replaced.

    Used by the CLI for the few thresholds it offers as flags; validation runs
    again in ``__post_init__``.
    """
    cur = {k: v for k, v in (curation or {}).items() if v is not None}
    spl = {k: v for k, v in (split or {}).items() if v is not None}
    return DatasetConfig(
        curation=replace(config.curation, **cur),  # type: ignore[arg-type]
        split=replace(config.split, **spl),  # type: ignore[arg-type]
    )
