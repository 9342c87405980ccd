"""The exposure behind the glass: noise after the glass, nothing drawn where it did nothing."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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


def _clear_glass(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A glass whose footprint changes nothing (as a drop over flat, saturated light)."""
    return image.copy(), _footprint(image.shape)


def _darkening_glass(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mask = _footprint(image.shape)
    out = image.copy()
    out[mask > 0] = (out[mask > 0] * 0.5).astype(image.dtype)
    return out, mask


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
    # the same draw: the noiseless darkened light plus it, as exposed, is what was written
    bare = expose(linear, 1.0, 0.0, None, np.uint16)
    darkened, _ = _darkening_glass(bare)
    unchanged = darkened == bare
    assert np.array_equal(obstructed[inside & unchanged], clear[inside & unchanged])


def test_without_noise_the_glass_acts_on_the_clear_view_and_without_glass_nothing() -> None:
    linear = _scene(0.5)
    clear, obstructed, _ = expose_through_glass(linear, 1.0, 0.0, SEED, np.uint8, _darkening_glass)
    assert np.array_equal(obstructed, _darkening_glass(clear)[0])
    clear, same, mask = expose_through_glass(linear, 1.0, 0.02, SEED, np.uint8, None)
    assert np.array_equal(same, clear) and not mask.any()
