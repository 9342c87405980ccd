"""Brightness: a random subset of drops gets a linear-light gain."""

import numpy as np
import pytest

from lenspair.simulate.effects import brightness
from lenspair.simulate.effects.spec import BrightnessSpec, EffectsSpec, RaindropsSpec
from lenspair.simulate.render import render_effects, sample_glass


def test_gains_follow_fraction_and_range() -> None:
    rng = np.random.default_rng(0)
    assert (brightness.sample_gains(BrightnessSpec(fraction=0.0), 50, rng) == 1).all()
    gains = brightness.sample_gains(BrightnessSpec(fraction=1.0, gain=(2.0, 3.0)), 50, rng)
    assert gains.dtype == np.float32 and ((gains >= 2) & (gains <= 3)).all()
    mixed = brightness.sample_gains(BrightnessSpec(fraction=0.3), 2000, rng)
    assert np.mean(mixed != 1) == pytest.approx(0.3, abs=0.04)


def test_brighten_scales_each_drop_by_its_gain() -> None:
    colour = np.full((5, 3), 0.2, np.float32)
    owner = np.array([0, 0, 1, 2, 2])
    out = brightness.brighten(colour, owner, np.array([1.0, 2.0, 0.5], np.float32))
    np.testing.assert_allclose(out[:, 0], [0.2, 0.2, 0.4, 0.1, 0.1])


def test_brightened_drops_are_brighter_and_nothing_else_changes() -> None:
    image = np.random.default_rng(1).integers(20, 120, (80, 100, 3), dtype=np.uint8)
    drops = RaindropsSpec(count=15)
    plain, mask = render_effects(image, EffectsSpec(raindrops=drops), np.random.default_rng(2))
    bright_spec = EffectsSpec(
        raindrops=drops, brightness=BrightnessSpec(fraction=1.0, gain=(2.0, 2.0))
    )
    bright, bright_mask = render_effects(image, bright_spec, np.random.default_rng(2))
    np.testing.assert_array_equal(mask, bright_mask)  # same drops, same footprint
    inside = mask == 255
    assert (bright[inside].astype(int) >= plain[inside].astype(int)).all()
    assert bright[inside].astype(float).mean() > plain[inside].astype(float).mean() + 10
    np.testing.assert_array_equal(bright[~inside], image[~inside])


@pytest.mark.parametrize("gain", [0.0, 100.0])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_extreme_gains_stay_in_range(gain: float, dtype: type) -> None:
    top = np.iinfo(dtype).max
    image: np.ndarray = np.full((60, 70), top // 2, dtype)
    spec = EffectsSpec(
        raindrops=RaindropsSpec(count=10, radius_px=(8.0, 12.0), contact_angle_deg=(20.0, 40.0)),
        brightness=BrightnessSpec(fraction=1.0, gain=(gain, gain)),
    )
    glass = sample_glass(spec, image.shape, np.random.default_rng(3))
    out, mask = render_effects(image, spec, np.random.default_rng(3))
    assert out.dtype == dtype
    np.testing.assert_array_equal(mask, glass.mask)
    core = out[mask == 255]
    if gain == 0.0:
        assert core.min() == 0  # fully covered drop pixels go black
    else:
        assert core.max() == top  # saturated, clipped once at the end
