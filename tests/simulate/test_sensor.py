"""The exposure behind the glass: the glass on unclipped light, noise after it, one clip."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.core.pixels import from_float, from_linear, to_linear
from lenspair.simulate.effects.spec import EffectsSpec, RaindropsSpec
from lenspair.simulate.render import apply_glass, apply_glass_linear, sample_glass
from lenspair.simulate.sensor import expose, expose_through_glass

SEED = np.random.SeedSequence(7)


def _scene(level: float) -> np.ndarray:
    """Linear light: a ramp around ``level`` (saturating above 1 at gain 1.5)."""
    ramp = np.linspace(level - 0.1, level + 0.1, 64, dtype=np.float32)
    return np.tile(ramp, (48, 1))


def _footprint(shape: tuple[int, ...]) -> np.ndarray:
    mask = np.zeros(shape[:2], np.uint8)
    mask[10:30, 20:50] = 255
    return mask


def _clear_glass(light: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A glass whose footprint changes no light."""
    return light.copy(), _footprint(light.shape)


def _darkening_glass(light: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mask = _footprint(light.shape)
    out = light.copy()
    out[mask > 0] *= np.float32(0.5)
    return out, mask


def _blurring_glass(light: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An out-of-focus glass over the whole frame."""
    return cv2.GaussianBlur(light, (0, 0), 4), np.full(light.shape[:2], 255, np.uint8)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("level", [0.45, 0.9, 1.4])
def test_where_the_glass_changes_nothing_the_clear_view_stands(level: float, dtype: type) -> None:
    # the noise was added a second time to the quantised, clipped pixel: a footprint-shaped
    # speckle in saturated light (41 % of the pixels) and +-1 codes elsewhere
    clear, obstructed, mask = expose_through_glass(
        _scene(level), 1.5, 0.02, SEED, dtype, _clear_glass
    )
    assert mask.any()
    assert np.array_equal(obstructed, clear)
    assert np.array_equal(
        clear, expose(_scene(level), 1.5, 0.02, np.random.default_rng(SEED), dtype)
    )


@given(level=st.floats(0.05, 1.5), noise=st.floats(0.001, 0.1))
@settings(max_examples=30, deadline=None)
def test_what_the_glass_changes_carries_the_clear_view_s_noise_draw(
    level: float, noise: float
) -> None:
    linear = _scene(level)
    clear, obstructed, mask = expose_through_glass(
        linear, 1.0, noise, SEED, np.uint16, _darkening_glass
    )
    inside = mask > 0
    assert np.array_equal(obstructed[~inside], clear[~inside])  # bit-identical outside
    # the same draw: the darkened light plus the clear view's noise, exposed once
    darkened, _ = _darkening_glass(linear)
    again = expose(darkened, 1.0, noise, np.random.default_rng(SEED), np.uint16)
    assert np.array_equal(obstructed, again)
    assert (obstructed[inside] <= clear[inside]).all()  # the same draw on less light
    assert obstructed[inside].mean() < clear[inside].mean()


def test_without_noise_the_glass_acts_on_the_light_and_without_glass_nothing() -> None:
    linear = _scene(0.5)
    clear, obstructed, _ = expose_through_glass(linear, 1.2, 0.0, SEED, np.uint8, _darkening_glass)
    assert np.array_equal(
        obstructed, from_float(from_linear(_darkening_glass(linear * 1.2)[0]), np.uint8)
    )
    clear, same, mask = expose_through_glass(linear, 1.0, 0.02, SEED, np.uint8, None)
    assert np.array_equal(same, clear) and not mask.any()


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_a_defocused_glass_over_a_light_above_full_scale_blooms_to_saturation(dtype: type) -> None:
    # the camera clipped the lamp to full scale before the glass blurred it: its centre came
    # out at 186 of 255 (a dim grey blob) and no pixel saturated, where one clip at the end,
    # as on a real lens, leaves 88 pixels saturated around the lamp
    linear = np.full((64, 64), 0.05, np.float32)
    linear[28:36, 28:36] = 4.0
    _, obstructed, _ = expose_through_glass(linear, 1.0, 0.0, SEED, dtype, _blurring_glass)
    top = np.iinfo(dtype).max
    assert obstructed[32, 32] == top
    assert (obstructed == top).sum() >= 64  # at least the lamp's own footprint
    below_full_scale = linear / 8  # the same scene dimmed: nothing saturates, both ways agree
    _, dim, _ = expose_through_glass(below_full_scale, 1.0, 0.0, SEED, dtype, _blurring_glass)
    assert (dim < top).all()


def test_the_renderer_on_linear_light_matches_it_on_codes_where_nothing_saturates() -> None:
    # apply_glass_linear is apply_glass before the encoding: on light within full scale the
    # two give the same codes, and the light one keeps what is over full scale
    rng = np.random.default_rng(3)
    codes = rng.integers(0, 200, (48, 64), dtype=np.uint8)
    glass = sample_glass(
        EffectsSpec(raindrops=RaindropsSpec()), codes.shape, np.random.default_rng(1)
    )
    encoded, mask = apply_glass(codes, glass)
    linear = to_linear(codes.astype(np.float32) / 255)
    light, mask_light = apply_glass_linear(linear, glass)
    assert np.array_equal(mask, mask_light) and mask.any()
    assert np.array_equal(from_float(from_linear(light), np.uint8), encoded)
    assert np.array_equal(light[mask == 0], linear[mask == 0])
    bright, _ = apply_glass_linear(linear * 8, glass)
    assert bright.max() > 1.0  # not clipped
