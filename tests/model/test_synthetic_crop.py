"""Rendering only a crop's window keeps the drops' density of the whole frame."""

import dataclasses

import numpy as np
import pytest

from lenspair.model.training.synthetic import OUR_DROPS, render_crop
from lenspair.simulate.effects.spec import (
    DefocusSpec,
    DirtSpec,
    DustSpec,
    EffectsSpec,
    RaindropsSpec,
)
from lenspair.simulate.render import render_effects

EFFECTS = EffectsSpec(
    raindrops=RaindropsSpec(count=60, radius_px=(3.0, 10.0)),
    defocus=DefocusSpec(shift_px=2.0),
)


def _clean(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(20, 235, size=(240, 320), dtype=np.uint8)


def test_changed_share_of_a_crop_matches_the_whole_frame_render() -> None:
    clean = _clean()
    box = (80, 120, 64, 64)
    window = (slice(80, 144), slice(120, 184))
    full, cropped = [], []
    for seed in range(60):
        whole, _ = render_effects(clean, EFFECTS, np.random.default_rng(seed))
        full.append(float((whole[window] != clean[window]).mean()))
        crop = render_crop(clean, EFFECTS, box, np.random.default_rng(1000 + seed))
        cropped.append(float((crop != clean[window]).mean()))
    assert np.mean(cropped) == pytest.approx(np.mean(full), rel=0.25)


@pytest.mark.parametrize("box", [(0, 0, 240, 320), (0, 0, 64, 64), (176, 256, 64, 64)])
def test_crop_shape_dtype_and_whole_frame_equivalence(box: tuple[int, int, int, int]) -> None:
    clean = _clean(1)
    crop = render_crop(clean, OUR_DROPS, box, np.random.default_rng(3))
    assert crop.dtype == clean.dtype and crop.shape == (box[2], box[3])
    if box[2:] == clean.shape:
        whole, _ = render_effects(clean, OUR_DROPS, np.random.default_rng(3))
        np.testing.assert_array_equal(crop, whole)


@pytest.mark.parametrize(
    "idle",
    [
        {"dirt": DirtSpec(count=5, opacity=(0.0, 0.0))},
        {"defocus": DefocusSpec(shift_px=0.0)},
        {"dust": DustSpec(attenuation=(1.0, 1.0))},
    ],
    ids=["dirt of opacity 0", "defocus of no blur", "dust of attenuation 1"],
)
@pytest.mark.parametrize("seed", range(3))
def test_an_effect_that_does_nothing_leaves_the_drops_of_a_crop_as_they_were(
    idle: dict[str, object], seed: int
) -> None:
    # listing dirt drew its count from the drops' generator and moved every later draw;
    # a zero-size defocus grew the window by 2 px, which changed the drops' binomial count
    clean = _clean(seed)
    drops = EffectsSpec(raindrops=RaindropsSpec(count=100, radius_px=(3.0, 20.0)))
    box = (60, 100, 96, 96)
    plain = render_crop(clean, drops, box, np.random.default_rng(seed))
    assert (plain != clean[60:156, 100:196]).any()  # the premise: drops in the crop
    listed = dataclasses.replace(drops, **idle)
    np.testing.assert_array_equal(
        render_crop(clean, listed, box, np.random.default_rng(seed)), plain
    )
