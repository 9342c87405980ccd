"""Dust: I = I0 a + b with smooth, compactly supported a and b."""

import tracemalloc

import numpy as np
import pytest

from lenspair.core.pixels import from_float, from_linear
from lenspair.simulate.effects import dust
from lenspair.simulate.effects.spec import DustSpec, EffectsSpec
from lenspair.simulate.render import apply_glass, render_effects, sample_glass


def _grey(linear: float, shape: tuple[int, ...]) -> np.ndarray:
    return from_float(from_linear(np.full(shape, linear, np.float32)), np.uint16)


def _linear(image: np.ndarray) -> np.ndarray:
    encoded = image.astype(np.float64) / 65535
    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)


def test_dust_is_an_affine_map_recoverable_from_two_images() -> None:
    shape = (120, 160)
    spec = DustSpec(attenuation=(0.3, 0.7), scatter=0.2, scale_px=30.0, coverage=0.6)
    glass = sample_glass(EffectsSpec(dust=spec), shape, np.random.default_rng(0))
    assert glass.dust is not None
    dark, bright = 0.1, 0.6
    out_dark, mask = apply_glass(_grey(dark, shape), glass)
    out_bright, _ = apply_glass(_grey(bright, shape), glass)
    a = (_linear(out_bright) - _linear(out_dark)) / (bright - dark)
    b = _linear(out_dark) - a * dark
    np.testing.assert_allclose(a, glass.dust.transmission, atol=2e-4)
    np.testing.assert_allclose(b, glass.dust.veil, atol=2e-4)
    # The support is exactly the mask, and outside it nothing happens.
    np.testing.assert_array_equal(mask == 255, glass.dust.support)
    assert (glass.dust.transmission[~glass.dust.support] == 1).all()
    assert (glass.dust.veil[~glass.dust.support] == 0).all()
    assert glass.dust.transmission.min() < 0.75 and glass.dust.veil.max() > 0.05


def test_dust_fields_are_smooth_at_the_patch_scale() -> None:
    spec = DustSpec(attenuation=(0.5, 0.5), scatter=0.1, scale_px=40.0, coverage=0.5)
    field = dust.sample_dust(spec, (200, 300), np.random.default_rng(1))
    a = field.transmission.astype(np.float64)
    slope = max(np.abs(np.diff(a, axis=0)).max(), np.abs(np.diff(a, axis=1)).max())
    # One bump changes tau by at most ln 2 * 1.72 / r_min per pixel (r_min = 20 px).
    assert 0.005 < slope < 3 * np.log(2) * 1.72 / 20
    curvature = np.abs(np.diff(a, n=2, axis=1)).max()
    assert curvature < 0.01  # no kinks: the bumps are C2 and vanish smoothly at the edge
    b = field.veil.astype(np.float64)
    np.testing.assert_allclose(b, 0.1 * (1 - a), atol=1e-6)


@pytest.mark.parametrize("coverage", [0.2, 0.5, 0.8])
def test_coverage_sets_the_covered_fraction(coverage: float) -> None:
    spec = DustSpec(scale_px=30.0, coverage=coverage)
    fractions = [
        dust.sample_dust(spec, (240, 320), np.random.default_rng(seed)).support.mean()
        for seed in range(6)
    ]
    assert np.mean(fractions) == pytest.approx(coverage, abs=0.12)


@pytest.mark.parametrize(
    ("coverage", "scale_px", "shape"),
    [(0.01, 40.0, (270, 360)), (0.5, 2000.0, (60, 80))],  # one patch: 3x; one patch: the frame
)
def test_coverage_holds_where_one_patch_covers_more_than_is_asked(
    coverage: float, scale_px: float, shape: tuple[int, int]
) -> None:
    # at least one whole patch per frame covered 3x the share asked for, and a patch larger
    # than the frame counted its whole disc as covering the frame: 100 % for 50 %
    spec = DustSpec(scale_px=scale_px, coverage=coverage)
    fractions = [
        dust.sample_dust(spec, shape, np.random.default_rng(seed)).support.mean()
        for seed in range(300)
    ]
    assert np.mean(fractions) == pytest.approx(coverage, rel=0.3)


def test_fine_dust_covers_what_is_asked_on_a_large_frame() -> None:
    # 50 % of 1280x720 under patches of 2-4 px radius takes about 22,000 of them; a cap of
    # 4,096 patches once covered 12 % without a word.
    spec = DustSpec(scale_px=4.0, coverage=0.5)
    field = dust.sample_dust(spec, (720, 1280), np.random.default_rng(0))
    assert field.support.mean() == pytest.approx(0.5, abs=0.02)


def test_a_patch_cut_by_the_frame_edge_is_the_same_bump_inside() -> None:
    # Patches are evaluated on windows around their centres; one centred on a corner keeps
    # exactly its quarter inside the frame, the bump of the formula.
    x, y = np.array([-0.5]), np.array([-0.5])
    tau = dust._optical_depth(x, y, np.array([6.0]), np.array([2.0]), (8, 9))
    rows, cols = np.mgrid[0:8, 0:9]
    inside = np.maximum(1 - ((rows + 0.5) ** 2 + (cols + 0.5) ** 2) / 36.0, 0.0)
    np.testing.assert_allclose(tau, 2.0 * inside**3, rtol=1e-6)


def test_memory_follows_the_frame_not_the_patch() -> None:
    # Patches far larger than the frame were evaluated on their whole windows: a legal
    # scale_px of 1e4 needed about 10 GB whatever the frame's size.
    spec = DustSpec(scale_px=2000.0, coverage=0.5)
    tracemalloc.start()
    try:
        field = dust.sample_dust(spec, (60, 80), np.random.default_rng(0))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 10e6 and field.support.any()


def test_zero_coverage_is_no_dust() -> None:
    image = np.full((40, 50, 3), 77, np.uint8)
    out, mask = render_effects(
        image, EffectsSpec(dust=DustSpec(coverage=0.0)), np.random.default_rng(0)
    )
    assert not mask.any()
    np.testing.assert_array_equal(out, image)


def test_opaque_dust_and_saturated_scene_stay_in_range() -> None:
    spec = DustSpec(attenuation=(0.0, 0.0), scatter=1.0, scale_px=10.0, coverage=0.9)
    for value in (0, 65535):
        image = np.full((30, 40), value, np.uint16)
        out, mask = render_effects(image, EffectsSpec(dust=spec), np.random.default_rng(2))
        assert out.dtype == np.uint16 and mask.any()
        np.testing.assert_array_equal(out[mask == 0], image[mask == 0])
        if value == 0:
            assert out.max() > 60000  # the veil lights up a black scene
