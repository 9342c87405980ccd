"""Dirt: opaque and semi-transparent blobs with irregular outlines."""

import math

import numpy as np
import pytest

from lenspair.core.pixels import from_float, from_linear
from lenspair.simulate.effects import dirt
from lenspair.simulate.effects.layer import Sprites
from lenspair.simulate.effects.spec import DirtSpec, EffectsSpec
from lenspair.simulate.render import render_effects


def _blobs(radius: float, opacity: float, amplitudes: list[float]) -> dirt.Blobs:
    return dirt.Blobs(
        centers=np.array([[50.0, 50.0]]),
        radii=np.array([radius]),
        opacities=np.array([opacity]),
        amplitudes=np.array([amplitudes]),
        phases=np.zeros((1, 4)),
    )


def _patch(sprites: Sprites) -> np.ndarray:
    """Coverage of the first blob as a (101, 101) image."""
    alpha = np.zeros((101, 101), np.float32)
    alpha[sprites.ys, sprites.xs] = sprites.alpha
    return alpha


def test_round_blob_has_the_right_area_and_opacity() -> None:
    sprites = dirt.rasterize(_blobs(20.0, 0.7, [0, 0, 0, 0]), (101, 101), pad=0)
    alpha = _patch(sprites)
    assert alpha.max() == pytest.approx(0.7)
    support = np.count_nonzero(alpha)
    assert support == pytest.approx(math.pi * 20**2, rel=0.05)
    assert (alpha >= 0).all() and (alpha <= 0.7 + 1e-6).all()


def test_irregular_outline_follows_its_harmonics() -> None:
    # r(theta) = 20 (1 + 0.2 cos 2 theta + 0.1 cos 3 theta): 26 px along +x, 16 px along y.
    sprites = dirt.rasterize(_blobs(20.0, 1.0, [0.2, 0.1, 0, 0]), (101, 101), pad=0)
    support = _patch(sprites) > 0
    assert np.count_nonzero(support[50, 50:]) == pytest.approx(26, abs=1)
    assert np.count_nonzero(support[50:, 50]) == pytest.approx(16, abs=1)


def test_opaque_blob_shows_the_dirt_colour() -> None:
    spec = DirtSpec(count=3, radius_px=(15.0, 15.0), opacity=(1.0, 1.0), color=0.2)
    image = np.full((80, 100, 3), 250, np.uint8)
    out, mask = render_effects(image, EffectsSpec(dirt=spec), np.random.default_rng(0))
    expected = from_float(from_linear(np.array(0.2, np.float32)), np.uint8)
    assert np.count_nonzero((out == expected).all(axis=-1)) > 200  # opaque cores
    np.testing.assert_array_equal(out[mask == 0], image[mask == 0])


def test_semi_transparent_blob_blends_in_linear_light() -> None:
    spec = DirtSpec(
        count=1, radius_px=(30.0, 30.0), opacity=(0.5, 0.5), color=0.0, irregularity=0.0
    )
    image = from_float(from_linear(np.full((100, 100), 0.8, np.float32)), np.uint16)
    out, _ = render_effects(image, EffectsSpec(dirt=spec), np.random.default_rng(1))
    darkest = out.min().astype(np.float64) / 65535
    linear = ((darkest + 0.055) / 1.055) ** 2.4
    assert linear == pytest.approx(0.4, abs=1e-3)  # 0.5 * 0.8 + 0.5 * 0.0


def test_tiny_blobs_are_stable() -> None:
    spec = DirtSpec(count=20, radius_px=(0.0, 0.1))
    image = np.random.default_rng(0).integers(0, 256, (30, 40), dtype=np.uint8)
    out, mask = render_effects(image, EffectsSpec(dirt=spec), np.random.default_rng(1))
    assert np.count_nonzero(mask) <= 20 * 4
    np.testing.assert_array_equal(out[mask == 0], image[mask == 0])
