"""Labels of the detector: tile truth, the pair rule, kinds, and scoring."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.core.pixels import to_float, to_linear
from lenspair.model.detection.data import DetectorSample
from lenspair.model.detection.judge import Judgement
from lenspair.model.detection.labels import (
    kind_index,
    pair_anomaly_mask,
    tile_truth,
    tile_valid,
)
from lenspair.model.detection.score import score
from lenspair.model.networks.detector import KINDS
from lenspair.simulate.effects.spec import DirtSpec, DustSpec, EffectsSpec
from lenspair.simulate.render import render_effects
from tests.images import texture


@given(
    top=st.integers(0, 5), left=st.integers(0, 7), rows=st.integers(1, 3), cols=st.integers(1, 3)
)
@settings(max_examples=30, deadline=None)
def test_tile_truth_marks_exactly_the_covered_tiles(
    top: int, left: int, rows: int, cols: int
) -> None:
    mask = np.zeros((96, 128), np.uint8)
    mask[top * 16 : (top + rows) * 16, left * 16 : (left + cols) * 16] = 255
    truth = tile_truth(mask, (6, 8))
    expected = np.zeros((6, 8), bool)
    expected[top : top + rows, left : left + cols] = True
    np.testing.assert_array_equal(truth, expected)


def test_tile_truth_needs_a_tenth_of_a_tile() -> None:
    mask = np.zeros((16, 16), np.uint8)
    mask[:1, :] = 255  # 1/16 of the tile
    assert not tile_truth(mask, (1, 1)).any()
    mask[:2, :] = 255  # 1/8 of the tile
    assert tile_truth(mask, (1, 1)).all()


def test_tiles_mostly_untrusted_do_not_count() -> None:
    untrusted = np.zeros((32, 32), np.uint8)
    untrusted[:, :16] = 255
    assert tile_valid(untrusted, (2, 2)).tolist() == [[False, True], [False, True]]


def _scene(seed: int = 0) -> np.ndarray:
    return (texture((240, 320), seed) * 200 + 30).astype(np.uint8)


@given(gain=st.floats(0.6, 1.5))
@settings(max_examples=15, deadline=None)
def test_pair_rule_ignores_an_exposure_difference(gain: float) -> None:
    # levels 30..150, so that no gain up to 1.5 clips (clipping is a real difference)
    clean = (texture((240, 320), 0) * 120 + 30).astype(np.uint8)
    brighter = np.clip(clean.astype(np.float64) * gain, 0, 255).round().astype(np.uint8)
    covered = pair_anomaly_mask(brighter, clean)
    assert covered.mean() < 0.02


@pytest.mark.parametrize(
    "effects",
    [
        EffectsSpec(dirt=DirtSpec(count=8)),
        EffectsSpec(dust=DustSpec(attenuation=(0.4, 0.6), coverage=0.6)),
    ],
    ids=["dirt", "dust"],
)
def test_pair_rule_finds_the_rendered_footprint(effects: EffectsSpec) -> None:
    clean = _scene(1)
    obstructed, truth = render_effects(clean, effects, np.random.default_rng(4))
    covered = pair_anomaly_mask(obstructed, clean)
    inside = truth > 0
    # The footprint includes where the effect is faint; where it changes the
    # light by more than a quarter, the rule must see it.
    seen, reference = to_linear(to_float(obstructed)), to_linear(to_float(clean))
    change = np.abs(seen / np.maximum(reference, 1e-3) - 1.0)
    strong = cv2.GaussianBlur((change > 0.25).astype(np.float32), (0, 0), 3.0) > 0.9
    assert strong.sum() > 500
    assert covered[~inside].mean() < 0.03
    assert covered[strong].mean() > 0.8


def test_pair_rule_never_covers_untrusted_pixels() -> None:
    clean = _scene(2)
    obstructed, _ = render_effects(
        clean, EffectsSpec(dirt=DirtSpec(count=10)), np.random.default_rng(1)
    )
    untrusted = np.zeros(clean.shape, np.uint8)
    untrusted[:, :100] = 255
    assert not pair_anomaly_mask(obstructed, clean, untrusted)[:, :100].any()


def test_kind_index() -> None:
    assert kind_index(()) == 0
    assert kind_index(("rain",)) == KINDS.index("rain")
    assert kind_index(("raindrops",)) == KINDS.index("rain")
    assert kind_index(("fog", "Dust")) == KINDS.index("dust")
    assert kind_index(("fog",)) is None


def _sample(kind: int, tiles: np.ndarray) -> DetectorSample:
    return DetectorSample(
        np.zeros((8, 8), np.float32),
        kind,
        tiles.astype(np.float32),
        np.ones(tiles.shape, bool),
        "x",
        "g",
    )


def test_scores_of_a_perfect_and_of_a_wrong_detector() -> None:
    maps = np.zeros((4, 2, 2), np.float32)
    maps[1, 0, 0] = maps[2, :, 0] = maps[3, 1, 1] = 1.0
    samples = [_sample(k, maps[k] > 0.5) for k in range(4)]
    kinds = np.eye(4, dtype=np.float32)
    perfect = Judgement(np.array([0.1, 0.9, 0.9, 0.9]), kinds, maps, np.zeros(4, bool))
    result = score(samples, perfect)
    assert (result.accuracy, result.f1, result.tile_iou) == (1.0, 1.0, 1.0)
    assert result.confusion == np.diag([1, 1, 1, 1]).tolist()
    wrong = Judgement(
        np.array([0.9, 0.1, 0.1, 0.1]), kinds[::-1].copy(), 1 - maps, np.zeros(4, bool)
    )
    result = score(samples, wrong)
    assert result.accuracy == 0.0 and result.f1 == 0.0 and result.tile_iou == 0.0
    assert result.confusion[0][KINDS.index("dirt")] == 1  # called obstructed, by dirt
