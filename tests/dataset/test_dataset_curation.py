import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from lenspair.capture.ingested import PairRecord
from lenspair.core.errors import ConfigError
from lenspair.dataset.config import (
    CurationConfig,
    DatasetConfig,
    SplitConfig,
    load_dataset_config,
    parse_fractions,
    with_overrides,
)
from lenspair.dataset.curation import (
    PSNR_CAP_DB,
    RULE_NAMES,
    Measured,
    curate,
    difficulty,
    find_duplicates,
    is_clean,
    level_normalised,
    measure_pair,
    quality_rule,
)
from tests.dataset.dataset_synth import add_drops, scene


def _pair(strength: float = 0.5, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    target = scene(rng, 48, 64)[:, :64]
    obstructed = add_drops(target, strength, np.random.default_rng(seed + 1))
    return (
        np.rint(obstructed * 255).astype(np.uint8),
        np.rint(target * 255).astype(np.uint8),
    )


def test_identical_views_are_clean_and_capped() -> None:
    _, target = _pair()
    stats = measure_pair(target, target, None, 0.03)
    assert stats.psnr_db == PSNR_CAP_DB
    assert stats.anomaly_fraction == 0.0
    assert is_clean(stats, CurationConfig())
    assert stats.thumbnail.shape == (24, 32) and stats.thumbnail.dtype == np.float32


def test_drops_are_seen_and_graded_by_psnr() -> None:
    config = CurationConfig()
    grades = []
    for strength in (0.15, 0.5, 0.9):
        stats = measure_pair(*_pair(strength), None, config.anomaly_delta)
        assert not is_clean(stats, config)
        grades.append(difficulty(stats.psnr_db, config))
    assert grades == ["easy", "medium", "hard"]


def test_difficulty_thresholds_are_configurable() -> None:
    config = CurationConfig(easy_min_psnr_db=30.0, hard_max_psnr_db=10.0)
    assert difficulty(25.0, config) == "medium"
    assert difficulty(31.0, config) == "easy"
    assert difficulty(9.0, config) == "hard"


def test_gain_offset_between_cameras_is_not_an_anomaly() -> None:
    _, target = _pair()
    brighter = np.clip(target.astype(np.int16) + 12, 0, 255).astype(np.uint8)
    stats = measure_pair(brighter, target, None, 0.03)
    assert stats.anomaly_fraction < 0.01


def test_mask_excludes_pixels_from_psnr() -> None:
    obstructed, target = _pair()
    damaged = obstructed.copy()
    damaged[:, :16] = 0
    mask = np.zeros(target.shape[:2], np.uint8)
    mask[:, :16] = 255
    with_mask = measure_pair(damaged, target, mask, 0.03)
    without_mask = measure_pair(damaged, target, None, 0.03)
    assert with_mask.psnr_db > without_mask.psnr_db + 3
    assert with_mask.mask_fraction == pytest.approx(0.25)


def test_sharpness_drops_with_blur_and_exposure_is_counted() -> None:
    _, target = _pair()
    sharp = measure_pair(target, target, None, 0.03).sharpness
    blurry = cv2.GaussianBlur(target, (0, 0), 4.0)
    assert measure_pair(blurry, blurry, None, 0.03).sharpness < sharp / 50
    half = target.copy()
    half[:24] = 255
    half[24:36] = 0
    stats = measure_pair(half, half, None, 0.03)
    assert stats.saturated == pytest.approx(0.5, abs=0.01)
    assert stats.black == pytest.approx(0.25, abs=0.01)


def test_sharpness_exposure_and_thumbnail_are_the_clean_view_s() -> None:
    # the drops are the anomaly, not the scene: measured on the input, defocused drops
    # failed pairs as motion blur, bright drops as overexposure, and duplicates followed them
    obstructed, target = _pair(0.9)
    stats = measure_pair(obstructed, target, None, 0.03)
    reference = measure_pair(target, target, None, 0.03)
    assert stats.sharpness == reference.sharpness
    assert (stats.saturated, stats.black) == (reference.saturated, reference.black)
    np.testing.assert_array_equal(stats.thumbnail, reference.thumbnail)
    burnt = np.full_like(obstructed, 255)  # an input burnt out whole: the target is fine
    assert measure_pair(burnt, target, None, 0.03).saturated == reference.saturated < 0.01


def test_sixteen_bit_pairs_measure_like_eight_bit() -> None:
    obstructed, target = _pair()
    eight = measure_pair(obstructed, target, None, 0.03)
    sixteen = measure_pair(
        obstructed.astype(np.uint16) * 257, target.astype(np.uint16) * 257, None, 0.03
    )
    assert sixteen.psnr_db == pytest.approx(eight.psnr_db, abs=1e-3)
    assert sixteen.sharpness == pytest.approx(eight.sharpness, rel=1e-2)  # 8-bit grey is rounded


def test_mismatched_images_raise() -> None:
    obstructed, target = _pair()
    with pytest.raises(ValueError, match="differ"):
        measure_pair(obstructed[:, :32], target, None, 0.03)
    with pytest.raises(ValueError, match="mask"):
        measure_pair(obstructed, target, np.zeros((4, 4), np.uint8), 0.03)


def test_duplicates_keep_the_first_of_a_run_and_follow_drift() -> None:
    base = np.zeros((24, 32), np.float32)
    thumbs = [base, base + 0.001, base + 0.002, base + 0.5, base + 0.5]
    assert find_duplicates(thumbs, 0.004) == [False, True, True, False, True]
    drift = [base + 0.003 * i for i in range(6)]  # compared with the last *kept* frame
    assert find_duplicates(drift, 0.004) == [False, True, False, True, False, True]


def _stats(**figures: float) -> object:
    _, target = _pair()
    stats = measure_pair(target, target, None, 0.03)
    return stats if not figures else type(stats)(**{**stats.__dict__, **figures})


@pytest.mark.parametrize(
    ("record", "rule"),
    [
        (PairRecord(1, "kept", residual_px=3.0), "residual"),
        (PairRecord(1, "kept", photometric_residual=0.2), "photometric"),
        (PairRecord(1, "kept", inliers=5), "inliers"),
        (PairRecord(1, "kept", mask_fraction=0.9), "mask"),
        (PairRecord(1, "kept", sharpness=1.0), "sharpness"),
        (PairRecord(1, "kept", saturated=0.5), "exposure"),
        (PairRecord(1, "kept", black=0.5), "exposure"),
        (PairRecord(1, "kept", residual_px=0.5, inliers=50), None),
    ],
)
def test_quality_rules(record: PairRecord, rule: str | None) -> None:
    found = quality_rule(record, _stats(), CurationConfig())  # type: ignore[arg-type]
    assert (found[0] if found else None) == rule


def test_recorded_figures_take_precedence_over_measured_ones() -> None:
    blurry = _stats(sharpness=1.0)
    assert quality_rule(PairRecord(1, "kept"), blurry, CurationConfig()) is not None  # type: ignore[arg-type]
    assert quality_rule(PairRecord(1, "kept", sharpness=500.0), blurry, CurationConfig()) is None  # type: ignore[arg-type]


def test_curate_counts_each_pair_once_in_rule_order() -> None:
    obstructed, target = _pair()
    good = measure_pair(obstructed, target, None, 0.03)
    clean = measure_pair(target, target, None, 0.03)
    items = [
        Measured(0, 0, PairRecord(10, "kept"), {}, {}, good),
        Measured(0, 1, PairRecord(20, "kept"), {}, {}, good),  # duplicate of 0
        Measured(0, 2, PairRecord(30, "kept", residual_px=9.0, sharpness=0.0), {}, {}, good),
        Measured(0, 3, PairRecord(40, "rejected"), {}, {}, None, "ingest_rejected", "x"),
        Measured(1, 0, PairRecord(10, "kept"), {}, {}, clean),  # other recording: no dup
    ]
    removed = curate(items, CurationConfig())
    assert {key: rule for key, (rule, _) in removed.items()} == {
        (0, 1): "duplicate",
        (0, 2): "residual",
        (0, 3): "ingest_rejected",
    }
    removed = curate(items, CurationConfig(clean_pairs="exclude"))
    assert removed[(1, 0)][0] == "clean"
    assert set(RULE_NAMES) >= {rule for rule, _ in removed.values()}


def test_an_excluded_clean_frame_does_not_stand_for_a_run_that_shows_the_anomaly() -> None:
    # the robot stands still while drops form: frame 0 shows none yet, 1-3 do. Duplicates
    # were sought among all, so 1-3 went as duplicates of 0, and 0 went as clean: no pair
    obstructed, target = _pair()
    clean = measure_pair(target, target, None, 0.03)
    drops = measure_pair(obstructed, target, None, 0.03)  # the same clean view: same thumbnail
    items = [Measured(0, 0, PairRecord(10, "kept"), {}, {}, clean)]
    items += [Measured(0, i, PairRecord(10 * (i + 1), "kept"), {}, {}, drops) for i in (1, 2, 3)]
    removed = curate(items, CurationConfig(clean_pairs="exclude"))
    assert {key: rule for key, (rule, _) in removed.items()} == {
        (0, 0): "clean",
        (0, 2): "duplicate",
        (0, 3): "duplicate",
    }
    # kept, clean frames stand for their runs as any other
    assert set(curate(items, CurationConfig())) == {(0, 1), (0, 2), (0, 3)}


def test_config_yaml_sections_overrides_and_errors(tmp_path: Path) -> None:
    assert load_dataset_config(None) == DatasetConfig()
    file = tmp_path / "curation.yaml"
    file.write_text("curation:\n  min_sharpness: 5\nsplit:\n  fractions: [0.5, 0.25, 0.25]\n")
    config = load_dataset_config(file)
    assert config.curation.min_sharpness == 5.0
    assert config.split.fractions == (0.5, 0.25, 0.25)
    assert with_overrides(config, split={"seed": 7, "group_by": None}).split.seed == 7
    file.write_text("curation:\n  min_sharpnes: 5\n")
    with pytest.raises(ConfigError, match=r"curation\.yaml: curation\.min_sharpnes: unknown key"):
        load_dataset_config(file)
    file.write_text("split:\n  fractions: [0.5, 0.2, 0.2]\n")
    with pytest.raises(ConfigError, match="must sum to 1"):
        load_dataset_config(file)
    file.write_text("curation:\n  max_black: 2\n")
    with pytest.raises(ConfigError, match=r"max_black: expected a fraction"):
        load_dataset_config(file)
    with pytest.raises(ValueError, match="three"):
        parse_fractions("0.8,0.2")
    assert parse_fractions("0.7, 0.2, 0.1") == (0.7, 0.2, 0.1)
    with pytest.raises(ValueError, match="gap"):
        SplitConfig(segment_frames=3, segment_gap_frames=3)
    for seed in (-7, 2**32):  # --seed refused them; split.seed in a --config took them
        file.write_text(f"split:\n  seed: {seed}\n")
        with pytest.raises(
            ConfigError, match=rf"split\.seed: expected 0 \.\. 4294967295, got {seed}"
        ):
            load_dataset_config(file)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("name", ["max_residual_px", "duplicate_threshold", "easy_min_psnr_db"])
def test_a_non_finite_threshold_is_refused_however_it_is_given(name: str, value: float) -> None:
    # NaN passes every comparison, so a range check alone let it through and
    # silently switched the rule off (and wrote NaN into dataset.json).
    with pytest.raises(ValueError, match=f"{name}: expected a finite number"):
        with_overrides(DatasetConfig(), curation={name: value})


def test_duplicates_are_found_in_time_order_whatever_the_file_order() -> None:
    # pairs.jsonl out of time order (a merged or hand-edited file): duplicates were
    # compared in file order, so a slow drift kept other frames than in time order
    halves = np.ones((24, 32), np.float32)
    halves[:, 16:] = -1  # the scene drifts, its level stays
    thumbnails = [0.5 + 0.003 * i * halves for i in range(6)]
    config = CurationConfig(duplicate_threshold=0.004)
    flags = find_duplicates([level_normalised(t) for t in thumbnails], 0.004)
    assert 0 < sum(flags) < len(flags)  # a drift: some frames kept, some not
    items = [
        Measured(0, i, PairRecord(10 * (i + 1), "kept"), {}, {}, _stats(thumbnail=t))  # type: ignore[arg-type]
        for i, t in enumerate(thumbnails)
    ]
    in_order = curate(items, config)
    assert sorted(k for k, v in in_order.items() if v[0] == "duplicate") == [
        (0, i) for i, flag in enumerate(flags) if flag
    ]
    assert curate(items[::-1], config) == in_order
