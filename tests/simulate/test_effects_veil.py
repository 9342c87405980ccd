"""Veil of wet glass: contrast drops by exactly 1 - s, listed only, finite, dtype kept."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.core.pixels import to_float, to_linear
from lenspair.simulate.effects import veil
from lenspair.simulate.effects.spec import EffectsSpec, VeilSpec
from lenspair.simulate.render import render_effects


def _image(dtype: type, channels: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    shape = (40, 56) if channels == 1 else (40, 56, channels)
    return rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True, dtype=dtype)


@given(
    strength=st.floats(0.0, 1.0),
    level=st.floats(0.0, 3.0),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=50, deadline=None)
def test_apply_veil_scales_contrast_by_one_minus_strength(
    strength: float, level: float, seed: int
) -> None:
    values = np.random.default_rng(seed).random((500, 3), np.float32)
    light = veil.veil_light(values, veil.Veil(strength, level))
    out = veil.apply_veil(values, light, strength)
    assert out.dtype == np.float32 and np.isfinite(out).all()
    np.testing.assert_allclose(out.std(axis=0), (1 - strength) * values.std(axis=0), atol=1e-5)
    expected_mean = values.mean(axis=0) * (1 - strength + strength * level)
    np.testing.assert_allclose(out.mean(axis=0), expected_mean, atol=1e-5)


@given(
    strength=st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0)).map(sorted),
    level=st.tuples(st.floats(0.0, 4.0), st.floats(0.0, 4.0)).map(sorted),
    dtype=st.sampled_from([np.uint8, np.uint16]),
    channels=st.sampled_from([1, 3]),
    seed=st.integers(0, 1000),
)
@settings(max_examples=40, deadline=None)
def test_rendered_veil_keeps_dtype_lowers_linear_contrast_and_runs_alone(
    strength: list[float], level: list[float], dtype: type, channels: int, seed: int
) -> None:
    image = _image(dtype, channels, seed)
    spec = EffectsSpec(veil=VeilSpec(strength=tuple(strength), level=tuple(level)))  # type: ignore[arg-type]
    calls: list[str] = []
    out, mask = render_effects(image, spec, np.random.default_rng(seed), calls.append)
    assert calls == ["veil"]
    assert out.dtype == image.dtype and out.shape == image.shape
    # scattered light reaches every pixel; a veil of strength 0 changes none
    assert mask.all() if strength[1] > 0 else not mask.any()
    before = to_linear(to_float(image)).std()
    after = to_linear(to_float(out)).std()
    # Clipping at white is 1-Lipschitz, so it cannot raise the spread; rounding to codes can,
    # by at most about half a code step in linear light.
    rounding = 0.005 if dtype == np.uint8 else 1e-4
    assert after <= before * (1 - strength[0]) + rounding


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_zero_strength_changes_no_pixel(dtype: type) -> None:
    image = _image(dtype, 3, 0)
    spec = EffectsSpec(veil=VeilSpec(strength=(0.0, 0.0)))
    out, mask = render_effects(image, spec, np.random.default_rng(0))
    np.testing.assert_array_equal(out, image)
    assert not mask.any()  # nothing changed, nothing obstructed


def test_full_strength_is_the_veil_light_everywhere() -> None:
    image = _image(np.uint16, 3, 1)
    spec = EffectsSpec(veil=VeilSpec(strength=(1.0, 1.0), level=(1.0, 1.0)))
    out, _ = render_effects(image, spec, np.random.default_rng(0))
    linear = to_linear(to_float(out)).reshape(-1, 3)
    expected = to_linear(to_float(image)).reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(linear, np.broadcast_to(expected, linear.shape), atol=1e-4)


def test_spec_rejects_bad_ranges() -> None:
    with pytest.raises(ValueError, match="strength"):
        VeilSpec(strength=(0.5, 0.2))
    with pytest.raises(ValueError, match="level"):
        VeilSpec(level=(-1.0, 1.0))
