"""Raindrops: refraction through spherical caps, TIR rim, hard geometric cases."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.core.pixels import from_float, from_linear
from lenspair.simulate.effects import raindrops
from lenspair.simulate.effects.raindrops import Drops, exit_refraction
from lenspair.simulate.effects.spec import (
    DefocusSpec,
    DirtSpec,
    DustSpec,
    EffectsSpec,
    RaindropsSpec,
    VeilSpec,
)
from lenspair.simulate.render import render_effects, sample_glass

WATER = 1.33
CRITICAL = math.asin(1 / WATER)


def _unit(v: np.ndarray) -> np.ndarray:
    unit: np.ndarray = (v / np.linalg.norm(v, axis=-1, keepdims=True)).astype(np.float32)
    return unit


def _ray_at(angle: float) -> np.ndarray:
    """Unit ray making ``angle`` (radians) with the +z normal."""
    return np.array([math.sin(angle), 0.0, math.cos(angle)], np.float32)


def _drops(*rows: tuple[float, float, float, float, float, float]) -> Drops:
    """Drops from rows (x, y, major, minor, angle_rad, contact_deg)."""
    data = np.array(rows, np.float64).reshape(-1, 6)
    return Drops(data[:, 0:2], data[:, 2:4], data[:, 4], np.deg2rad(data[:, 5]))


def _place(monkeypatch: pytest.MonkeyPatch, drops: Drops) -> None:
    monkeypatch.setattr(raindrops, "sample_drops", lambda spec, shape, rng: drops)


def _grey(linear: float, shape: tuple[int, ...], dtype: type = np.uint16) -> np.ndarray:
    return from_float(from_linear(np.full(shape, linear, np.float32)), dtype)


def _linear(image: np.ndarray) -> np.ndarray:
    top = np.iinfo(image.dtype).max
    encoded = image.astype(np.float64) / top
    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)


# --- exit refraction (Snell + Fresnel) -------------------------------------------------


def test_snell_law_holds_below_the_critical_angle() -> None:
    normal = np.array([0.0, 0.0, 1.0], np.float32)
    for degrees in (0.0, 10.0, 30.0, 45.0, 48.0):
        incident = _ray_at(math.radians(degrees))
        out, transmittance, tir = exit_refraction(incident, normal, WATER)
        assert not tir
        sin_out = math.hypot(out[0], out[1])
        assert sin_out == pytest.approx(WATER * math.sin(math.radians(degrees)), abs=1e-5)
        assert 0.0 < transmittance <= 1.0


def test_total_internal_reflection_starts_at_the_critical_angle() -> None:
    normal = np.array([0.0, 0.0, 1.0], np.float32)
    below = exit_refraction(_ray_at(CRITICAL - 1e-3), normal, WATER)
    above = exit_refraction(_ray_at(CRITICAL + 1e-3), normal, WATER)
    assert not below[2] and above[2]
    assert above[1] == 0.0  # no light leaves
    assert below[1] < 0.5  # Fresnel transmittance collapses towards the critical angle
    assert math.degrees(CRITICAL) == pytest.approx(48.75, abs=0.01)


def test_tangent_and_backward_rays_are_masked_without_nan() -> None:
    normal = np.array([[0.0, 0.0, 1.0]] * 3, np.float32)
    incident = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]], np.float32)
    for index in (1.0, WATER, 3.0):
        out, transmittance, tir = exit_refraction(incident, normal, index)
        assert tir.all()
        assert np.isfinite(out).all() and (transmittance == 0).all()


def test_index_one_leaves_rays_unchanged() -> None:
    rng = np.random.default_rng(0)
    incident = _unit(rng.normal(size=(100, 3)) * [1, 1, 0.3] + [0, 0, 1])
    normal = _unit(rng.normal(size=(100, 3)) * [0.3, 0.3, 0.1] + [0, 0, 1])
    out, transmittance, tir = exit_refraction(incident, normal, 1.0)
    ok = ~tir
    assert ok.sum() > 90
    np.testing.assert_allclose(out[ok], incident[ok], atol=1e-5)
    np.testing.assert_allclose(transmittance[ok], 1.0, atol=1e-5)


@given(
    incident=st.tuples(*[st.floats(-1, 1)] * 3),
    normal=st.tuples(*[st.floats(-1, 1)] * 3),
    index=st.floats(1.0, 3.0),
)
def test_exit_refraction_is_always_finite(
    incident: tuple[float, float, float], normal: tuple[float, float, float], index: float
) -> None:
    d = np.array(incident, np.float32)
    n = np.array(normal, np.float32)
    if np.linalg.norm(d) < 1e-3 or np.linalg.norm(n) < 1e-3:
        return
    out, transmittance, tir = exit_refraction(_unit(d), _unit(n), index)
    assert np.isfinite(out).all() and np.isfinite(transmittance)
    assert 0.0 <= transmittance <= 1.0
    assert np.linalg.norm(out) == pytest.approx(1.0, abs=1e-4)
    cos_i = float(np.dot(_unit(d), _unit(n)))
    if cos_i > 1e-3 and index * math.sqrt(max(0.0, 1 - cos_i**2)) > 1 + 1e-4:
        assert tir


# --- rasterised optics -------------------------------------------------------------------


@given(
    major=st.floats(0.0, 60.0),
    aspect=st.floats(0.05, 1.0),
    contact=st.floats(0.0, 90.0),
    index=st.floats(1.0, 3.0),
    x=st.floats(-5.0, 45.0),
    y=st.floats(-5.0, 35.0),
    angle=st.floats(0.0, math.pi),
)
def test_optics_are_finite_for_any_drop(
    major: float, aspect: float, contact: float, index: float, x: float, y: float, angle: float
) -> None:
    spec = RaindropsSpec(refractive_index=index)
    drops = _drops((x, y, major, major * aspect, angle, contact))
    optics = raindrops.rasterize(drops, spec, (30, 40), pad=3)
    for array in (optics.source, optics.transmittance, optics.sprites.alpha):
        assert np.isfinite(array).all()
    assert optics.sprites.alpha.min(initial=0) >= 0 and optics.sprites.alpha.max(initial=0) <= 1
    assert (optics.transmittance[optics.tir] == 0).all()
    box = optics.sprites.boxes[0]
    assert box[0] >= -3 and box[1] <= 33 and box[2] >= -3 and box[3] <= 43


def test_tir_pixels_are_exactly_past_the_critical_angle() -> None:
    # Very long focal length: viewing rays are parallel to the axis, so the
    # incidence angle is the cap normal's tilt asin(rho sin(theta_c)).
    spec = RaindropsSpec(focal_px=1e5)
    contact = 80.0
    optics = raindrops.rasterize(_drops((50, 50, 30, 30, 0, contact)), spec, (101, 101), pad=0)
    rho = np.hypot(optics.sprites.xs - 50, optics.sprites.ys - 50) / 30
    boundary = math.sin(CRITICAL) / math.sin(math.radians(contact))
    assert 0.7 < boundary < 0.8
    assert not optics.tir[rho < boundary - 0.02].any()
    assert optics.tir[(rho > boundary + 0.02) & (rho < 1)].all()
    shallow = raindrops.rasterize(_drops((50, 50, 30, 30, 0, 45.0)), spec, (101, 101), pad=0)
    assert not shallow.tir[rho < 0.99].any()  # 45° < 48.8°: no TIR anywhere inside


def test_drop_shows_a_flipped_minified_view(monkeypatch: pytest.MonkeyPatch) -> None:
    shape = (201, 201)
    _place(monkeypatch, _drops((100, 100, 40, 40, 0, 60)))
    ramp = np.linspace(0.05, 0.95, shape[1], dtype=np.float32)
    spec = EffectsSpec(raindrops=RaindropsSpec(count=1))
    for axis in (1, 0):
        field = np.broadcast_to(ramp[None, :] if axis == 1 else ramp[:, None], shape)
        image = from_float(from_linear(np.ascontiguousarray(field)), np.uint16)
        out, mask = render_effects(image, spec, np.random.default_rng(0))
        line_in = _linear(image)[100, 90:111] if axis == 1 else _linear(image)[90:111, 100]
        line_out = _linear(out)[100, 90:111] if axis == 1 else _linear(out)[90:111, 100]
        slope_in = np.polyfit(np.arange(21), line_in, 1)[0]
        slope_out = np.polyfit(np.arange(21), line_out, 1)[0]
        assert slope_in > 0
        assert slope_out < 0  # flipped
        assert abs(slope_out) > 1.2 * abs(slope_in)  # zoomed out: more scene per pixel
        assert mask[100, 100] == 255


def test_tir_rim_is_darker_than_the_drop_interior(monkeypatch: pytest.MonkeyPatch) -> None:
    shape = (161, 161)
    image = _grey(0.6, shape)
    ys, xs = np.mgrid[0 : shape[0], 0 : shape[1]]
    rho = np.hypot(xs - 80, ys - 80) / 50
    interior, rim = rho < 0.5, (rho > 0.85) & (rho < 0.97)
    means = {}
    for contact in (80.0, 40.0):
        _place(monkeypatch, _drops((80, 80, 50, 50, 0, contact)))
        spec = EffectsSpec(raindrops=RaindropsSpec(count=1, focal_px=1e5))
        out = _linear(render_effects(image, spec, np.random.default_rng(0))[0])
        means[contact] = (out[interior].mean(), out[rim].mean())
    inside, edge = means[80.0]
    assert inside == pytest.approx(0.6, rel=0.05)  # ~2% Fresnel loss at normal incidence
    assert edge < 0.2 * inside  # totally internally reflected rim
    inside, edge = means[40.0]
    assert edge > 0.7 * inside  # below the critical angle: no dark rim


def test_index_one_makes_drops_invisible() -> None:
    image = np.random.default_rng(1).integers(0, 65536, (60, 80, 3), dtype=np.uint16)
    spec = EffectsSpec(raindrops=RaindropsSpec(count=30, refractive_index=1.0))
    out, mask = render_effects(image, spec, np.random.default_rng(2))
    np.testing.assert_array_equal(out, image)
    assert not mask.any()


def test_nearly_zero_radius_drops_barely_change_the_image() -> None:
    image = np.random.default_rng(1).integers(0, 256, (60, 80), dtype=np.uint8)
    spec = EffectsSpec(raindrops=RaindropsSpec(count=40, radius_px=(0.0, 0.05)))
    out, mask = render_effects(image, spec, np.random.default_rng(3))
    assert np.count_nonzero(mask) <= 40  # at most about one pixel each
    assert np.count_nonzero(out != image) <= np.count_nonzero(mask)


@pytest.mark.parametrize("defocus", [None, DefocusSpec()])
def test_zero_radius_drops_and_a_zero_veil_mask_nothing(defocus: DefocusSpec | None) -> None:
    """What the glass does not change is not obstructed: the mask says so."""
    image = np.random.default_rng(1).integers(0, 256, (64, 96, 3), dtype=np.uint8)
    specs = [
        EffectsSpec(raindrops=RaindropsSpec(count=40, radius_px=(0.0, 0.0)), defocus=defocus),
        EffectsSpec(veil=VeilSpec(strength=(0.0, 0.0))),
    ]
    for spec in specs:
        out, mask = render_effects(image, spec, np.random.default_rng(3))
        np.testing.assert_array_equal(out, image)
        assert not mask.any(), spec


def test_border_and_overlapping_drops(monkeypatch: pytest.MonkeyPatch) -> None:
    shape = (80, 100)
    drops = _drops(
        (0.0, 0.0, 25, 20, 0.3, 70),  # cut by two borders
        (99.0, 40.0, 30, 30, 0.0, 89.9),  # cut, near-hemisphere
        (50.0, 40.0, 20, 14, 1.0, 60),  # two overlapping drops
        (58.0, 44.0, 18, 18, 0.0, 85),
    )
    _place(monkeypatch, drops)
    image = np.random.default_rng(0).integers(0, 256, (*shape, 3), dtype=np.uint8)
    out, mask = render_effects(
        image, EffectsSpec(raindrops=RaindropsSpec(count=4)), np.random.default_rng(0)
    )
    assert mask[0, 0] == 255 and mask[40, 99] == 255 and mask[42, 54] == 255
    np.testing.assert_array_equal(out[mask == 0], image[mask == 0])
    assert np.count_nonzero((out != image).any(axis=-1)) > 0.8 * np.count_nonzero(mask)


def test_same_drops_whatever_else_is_listed() -> None:
    spec = RaindropsSpec(count=10)
    alone = sample_glass(EffectsSpec(raindrops=spec), (50, 60), np.random.default_rng(4))
    listed = EffectsSpec(raindrops=spec, defocus=DefocusSpec(), dust=DustSpec(), dirt=DirtSpec())
    both = sample_glass(listed, (50, 60), np.random.default_rng(4))
    assert alone.drops is not None and both.drops is not None
    np.testing.assert_array_equal(alone.drops.centers, both.drops.centers)


def test_large_drop_layers_beyond_opencv_map_limit() -> None:
    """Over 32767 drop pixels in one pyramid level (cv2.remap's map limit) still render."""
    from lenspair.simulate.effects.spec import EffectsSpec, RaindropsSpec
    from lenspair.simulate.render import render_effects

    image = np.random.default_rng(0).integers(0, 256, (540, 720), dtype=np.uint8)
    spec = EffectsSpec(raindrops=RaindropsSpec(count=60, radius_px=(60.0, 80.0)))
    out, mask = render_effects(image, spec, np.random.default_rng(1))
    assert int((mask > 0).sum()) > 32767
    assert out.dtype == np.uint8 and not np.array_equal(out, image)


@given(
    low=st.floats(0.5, 20.0),
    span=st.floats(0.0, 80.0),
    exponent=st.floats(0.0, 4.0),
    seed=st.integers(0, 1000),
)
@settings(max_examples=50, deadline=None)
def test_power_law_radii_stay_in_range(low: float, span: float, exponent: float, seed: int) -> None:
    spec = RaindropsSpec(
        radius_px=(low, low + span), size_distribution="power-law", size_exponent=exponent
    )
    radii = raindrops.sample_radii(spec, np.random.default_rng(seed).random(200))
    assert np.isfinite(radii).all()
    assert (radii >= low - 1e-9).all() and (radii <= low + span + 1e-9).all()


def test_power_law_gives_many_small_drops_and_few_large_ones() -> None:
    uniform = np.random.default_rng(0).random(20000)
    spec = RaindropsSpec(radius_px=(3.0, 60.0), size_distribution="power-law", size_exponent=2.0)
    radii = raindrops.sample_radii(spec, uniform)
    # Density ~ r^-2 on [3, 60]: CDF(r) = (1/3 - 1/r) / (1/3 - 1/60).
    for radius in (5.0, 10.0, 30.0):
        expected = (1 / 3 - 1 / radius) / (1 / 3 - 1 / 60)
        assert float((radii <= radius).mean()) == pytest.approx(expected, abs=0.015)
    flat = raindrops.sample_radii(RaindropsSpec(radius_px=(3.0, 60.0)), uniform)
    assert np.median(radii) < 0.3 * np.median(flat)


@pytest.mark.parametrize("low", [0.0, 0.49])
def test_power_law_from_under_half_a_pixel_is_refused_naming_radius_px(low: float) -> None:
    """From 0 the law drew only sub-pixel drops: rain declared, a recording labelled rain,
    and four pixels changed."""
    with pytest.raises(ValueError, match=r"^radius_px: power-law sizes need .* at least 0.5 px"):
        RaindropsSpec(radius_px=(low, 60.0), size_distribution="power-law")
    RaindropsSpec(radius_px=(low, 60.0))  # uniform sizes from 0 stay allowed
