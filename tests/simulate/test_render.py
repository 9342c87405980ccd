"""Renderer API: only listed effects run, outside-mask identity, determinism, stability."""

import dataclasses
import itertools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.core.errors import LenspairError
from lenspair.model.detection.hard_cases import HARD_KINDS
from lenspair.simulate import render
from lenspair.simulate.effects import brightness, defocus, dirt, dust, raindrops, veil
from lenspair.simulate.effects.spec import (
    SHARP_DROPS,
    BrightnessSpec,
    DefocusSpec,
    DirtSpec,
    DustSpec,
    EffectsSpec,
    RaindropsSpec,
    VeilSpec,
)
from lenspair.simulate.presets import OUR_DROPS
from lenspair.simulate.render import advance_glass, apply_glass, render_effects, sample_glass

EFFECTS = {
    "raindrops": RaindropsSpec(count=12, radius_px=(4.0, 14.0)),
    "brightness": BrightnessSpec(fraction=0.5),
    "dirt": DirtSpec(count=3, radius_px=(4.0, 12.0)),
    "defocus": DefocusSpec(shifts=6, shift_px=2.5, disk_radius_px=1.0),
    "dust": DustSpec(scale_px=20.0, coverage=0.3),
    "veil": VeilSpec(strength=(0.1, 0.3)),
}
COMBINATIONS = [
    combo
    for size in (1, 2, 5, 6)
    for combo in itertools.combinations(EFFECTS, size)
    if size != 2 or "raindrops" in combo or "dust" in combo
]
UNLISTED_FUNCTIONS = {
    "raindrops": [(raindrops, "sample_drops"), (raindrops, "rasterize"), (raindrops, "shade")],
    "brightness": [(brightness, "sample_gains"), (brightness, "brighten")],
    "dirt": [(dirt, "sample_blobs"), (dirt, "rasterize"), (dirt, "premultiplied")],
    "defocus": [(defocus, "sample_shifts"), (defocus, "blur_kernel"), (defocus, "blur_layer")],
    "dust": [(dust, "sample_dust"), (dust, "apply_dust")],
    "veil": [(veil, "sample_veil"), (veil, "veil_light"), (veil, "apply_veil")],
}


def _image(
    dtype: type, channels: int, shape: tuple[int, int] = (64, 80), seed: int = 0
) -> np.ndarray:
    rng = np.random.default_rng(seed)
    size = shape if channels == 1 else (*shape, channels)
    return rng.integers(0, np.iinfo(dtype).max, size=size, endpoint=True, dtype=dtype)


def _spec(names: tuple[str, ...]) -> EffectsSpec:
    return EffectsSpec(**{name: EFFECTS[name] for name in names})  # type: ignore[arg-type]


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 3])
def test_no_effects_is_identity_and_computes_nothing(dtype: type, channels: int) -> None:
    image = _image(dtype, channels)
    calls: list[str] = []
    out, mask = render_effects(image, EffectsSpec(), np.random.default_rng(0), calls.append)
    assert out.dtype == image.dtype and out.shape == image.shape
    np.testing.assert_array_equal(out, image)
    assert out is not image
    assert mask.dtype == np.uint8 and mask.shape == image.shape[:2] and not mask.any()
    assert calls == []


@pytest.mark.parametrize("names", COMBINATIONS, ids="+".join)
@pytest.mark.parametrize(("dtype", "channels"), [(np.uint8, 3), (np.uint16, 1)])
def test_outside_the_mask_is_bit_identical(
    names: tuple[str, ...], dtype: type, channels: int
) -> None:
    image = _image(dtype, channels)
    out, mask = render_effects(image, _spec(names), np.random.default_rng(7))
    assert out.dtype == image.dtype and out.shape == image.shape
    assert set(np.unique(mask)) <= {0, 255}
    np.testing.assert_array_equal(out[mask == 0], image[mask == 0])
    if "raindrops" in names or "dirt" in names or "dust" in names:
        changed = out != image if channels == 1 else (out != image).any(axis=-1)
        assert changed.any() and (mask[changed] == 255).all()


@pytest.mark.parametrize("names", COMBINATIONS, ids="+".join)
def test_hook_reports_exactly_the_listed_effects_in_order(names: tuple[str, ...]) -> None:
    calls: list[str] = []
    spec = _spec(names)
    render_effects(_image(np.uint8, 3), spec, np.random.default_rng(1), calls.append)
    assert calls == list(spec.listed)
    glass = sample_glass(spec, (64, 80), np.random.default_rng(1))
    calls.clear()
    for _ in range(3):  # one call per effect per frame
        apply_glass(_image(np.uint8, 1), glass, calls.append)
    assert calls == list(spec.listed) * 3


@pytest.mark.parametrize("listed", [("raindrops",), ("dust",), ("dirt", "defocus"), ()], ids=str)
def test_unlisted_effects_never_run(
    monkeypatch: pytest.MonkeyPatch, listed: tuple[str, ...]
) -> None:
    def boom(*args: object, **kwargs: object) -> None:
        raise AssertionError("an unlisted effect was computed")

    for name, functions in UNLISTED_FUNCTIONS.items():
        if name not in listed:
            for module, function in functions:
                monkeypatch.setattr(module, function, boom)
    image = _image(np.uint16, 3)
    out, mask = render_effects(image, _spec(listed), np.random.default_rng(2))
    assert mask.any() == bool(listed)
    assert (out != image).any() == bool(listed)


def test_sharp_drops_preset_is_raindrops_only_and_shares_drops_with_defocus() -> None:
    assert SHARP_DROPS.listed == ("raindrops",)
    assert SHARP_DROPS.anomaly_kinds == ("rain",)
    assert EffectsSpec(veil=VeilSpec()).anomaly_kinds == ("rain",)  # wet glass: not clean
    assert EffectsSpec(veil=VeilSpec(strength=(0.0, 0.0))).anomaly_kinds == ()  # changes nothing
    # beside dust or dirt a veil is that glass's haze, labelled as the detector's
    # veiled_dust hard case is: a recording of it must not teach "rain"
    veil = VeilSpec()
    assert EffectsSpec(dust=DustSpec(), veil=veil).anomaly_kinds == (HARD_KINDS["veiled_dust"],)
    assert EffectsSpec(dirt=DirtSpec(), veil=veil).anomaly_kinds == ("dirt",)
    wet_and_dusty = EffectsSpec(raindrops=RaindropsSpec(), dust=DustSpec(), veil=veil)
    assert wet_and_dusty.anomaly_kinds == ("rain", "dust")
    image = _image(np.uint8, 3, (120, 160))
    sharp_out, sharp_mask = render_effects(image, SHARP_DROPS, np.random.default_rng(3))
    soft = EffectsSpec(
        raindrops=SHARP_DROPS.raindrops, defocus=DefocusSpec(), brightness=BrightnessSpec()
    )
    soft_out, soft_mask = render_effects(image, soft, np.random.default_rng(3))
    assert (soft_mask >= sharp_mask).all() and soft_mask.sum() > sharp_mask.sum()
    assert (sharp_out != soft_out).any()


@pytest.mark.parametrize(
    "names", [("raindrops", "brightness", "defocus"), tuple(EFFECTS)], ids="+".join
)
def test_same_seed_same_bytes_different_seed_differs(names: tuple[str, ...]) -> None:
    image = _image(np.uint16, 3)
    spec = _spec(names)
    first = render_effects(image, spec, np.random.default_rng(11))
    again = render_effects(image.copy(), spec, np.random.default_rng(11))
    other = render_effects(image, spec, np.random.default_rng(12))
    assert first[0].tobytes() == again[0].tobytes() and first[1].tobytes() == again[1].tobytes()
    assert first[0].tobytes() != other[0].tobytes()
    if "veil" in names:  # the veil's footprint is the whole frame, whatever the seed
        assert first[1].all() and other[1].all()
    else:
        assert first[1].tobytes() != other[1].tobytes()


def test_glass_is_sampled_once_and_reused_on_every_frame() -> None:
    spec = _spec(("raindrops", "defocus"))
    glass = sample_glass(spec, (64, 80), np.random.default_rng(4))
    frames = [_image(np.uint8, 3, seed=s) for s in range(3)]
    masks = [apply_glass(frame, glass)[1] for frame in frames]
    assert all((m == masks[0]).all() for m in masks)
    # Same drops, different scenes behind them: the drops show each scene.
    outs = [apply_glass(frame, glass)[0] for frame in frames]
    assert (outs[0][masks[0] == 255] != outs[1][masks[0] == 255]).any()
    with pytest.raises(ValueError):
        glass.mask[0, 0] = 1  # the state is read-only


def test_persistence_controls_how_many_drops_stay() -> None:
    shape = (64, 80)
    stay = sample_glass(_spec(("raindrops",)), shape, np.random.default_rng(5))
    assert advance_glass(stay, np.random.default_rng(0)) is stay  # persistence 1: drops stay put
    spec = EffectsSpec(
        raindrops=RaindropsSpec(count=400, radius_px=(1.0, 2.0), persistence=0.25),
        brightness=BrightnessSpec(),
    )
    glass = sample_glass(spec, shape, np.random.default_rng(5))
    moved = advance_glass(glass, np.random.default_rng(6))
    assert glass.drops is not None and moved.drops is not None
    kept = (glass.drops.centers == moved.drops.centers).all(axis=1)
    assert kept.mean() == pytest.approx(0.25, abs=0.07)
    assert moved.gains is not None and moved.gains.shape == (400,)
    assert (moved.mask != glass.mask).any()


@pytest.mark.parametrize(
    "image",
    [np.zeros((5, 5, 4), np.uint8), np.zeros((64, 80), np.float32), np.zeros((32, 80), np.uint8)],
    ids=["four-channels", "float", "wrong-size"],
)
def test_bad_images_raise_a_lenspair_error(image: np.ndarray) -> None:
    glass = sample_glass(SHARP_DROPS, (64, 80), np.random.default_rng(0))
    with pytest.raises(LenspairError, match=r"image|dtype|shape"):
        apply_glass(image, glass)


def test_bad_shape_raises() -> None:
    with pytest.raises(LenspairError, match="shape"):
        sample_glass(SHARP_DROPS, (0, 10), np.random.default_rng(0))


def test_drop_pixels_are_bounded_by_the_worst_case_on_the_frame() -> None:
    # 55 drops of 300 px: each box is 605 px wide, clipped to a 540 px high frame
    under = EffectsSpec(raindrops=RaindropsSpec(count=55, radius_px=(300.0, 300.0)))
    under.check_memory((540, 720))  # 55 * 540 * 605 = 1.8e7 pixels
    over = EffectsSpec(raindrops=RaindropsSpec(count=62, radius_px=(300.0, 300.0)))
    with pytest.raises(LenspairError, match=r"raindrops: 62 drops .* 2.03e\+07 pixels of a 720x5"):
        sample_glass(over, (540, 720), np.random.default_rng(0))
    # the same drops on a smaller frame are clipped to it, so they fit
    sample_glass(over, (240, 320), np.random.default_rng(0))
    OUR_DROPS.check_memory((1080, 1920))  # the ours preset, even on a large frame


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_untouched_linear_values_encode_back_to_the_same_code(dtype: type) -> None:
    codes: np.ndarray = np.arange(np.iinfo(dtype).max + 1, dtype=dtype)
    linear = render._linearize(codes.reshape(1, -1))
    np.testing.assert_array_equal(render._encode(linear.reshape(-1, 1), dtype).ravel(), codes)


def _finite_spy(monkeypatch: pytest.MonkeyPatch) -> list[np.ndarray]:
    seen: list[np.ndarray] = []
    original = render._encode

    def spy(values: np.ndarray, dtype: np.dtype | type) -> np.ndarray:
        seen.append(values)
        return original(values, dtype)

    monkeypatch.setattr(render, "_encode", spy)
    return seen


@given(
    data=st.data(),
    scene=st.sampled_from(["black", "white", "noise"]),
    dtype=st.sampled_from([np.uint8, np.uint16]),
    channels=st.sampled_from([1, 3]),
    height=st.integers(1, 40),
    width=st.integers(1, 40),
    seed=st.integers(0, 2**32 - 1),
)
def test_hard_cases_never_produce_nan_or_leave_the_mask(
    data: st.DataObject,
    scene: str,
    dtype: type,
    channels: int,
    height: int,
    width: int,
    seed: int,
) -> None:
    radius = data.draw(st.floats(0.0, 30.0))
    spec = EffectsSpec(
        raindrops=RaindropsSpec(
            count=data.draw(st.integers(0, 12)),
            radius_px=(radius * data.draw(st.floats(0.0, 1.0)), radius),
            aspect=(data.draw(st.floats(0.05, 1.0)), 1.0),
            contact_angle_deg=(data.draw(st.floats(0.0, 90.0)), 90.0),
            refractive_index=data.draw(st.sampled_from([1.0, 1.0001, 1.33, 3.0])),
            focal_px=data.draw(st.sampled_from([1.0, 350.0, 1e5])),
        ),
        brightness=data.draw(
            st.none()
            | st.builds(BrightnessSpec, gain=st.sampled_from([(0.0, 0.0), (100.0, 100.0)]))
        ),
        dirt=data.draw(
            st.none() | st.builds(DirtSpec, count=st.integers(0, 4), radius_px=st.just((0.0, 15.0)))
        ),
        defocus=data.draw(
            st.none()
            | st.builds(
                DefocusSpec, shift_px=st.floats(0.0, 8.0), disk_radius_px=st.floats(0.0, 4.0)
            )
        ),
        dust=data.draw(
            st.none()
            | st.builds(DustSpec, attenuation=st.just((0.0, 1.0)), scale_px=st.floats(4.0, 50.0))
        ),
    )
    top = np.iinfo(dtype).max
    shape = (height, width) if channels == 1 else (height, width, channels)
    image = {
        "black": np.zeros(shape, dtype),
        "white": np.full(shape, top, dtype),
        "noise": np.random.default_rng(seed).integers(0, top, shape, endpoint=True, dtype=dtype),
    }[scene]
    monkeypatch = pytest.MonkeyPatch()
    try:
        seen = _finite_spy(monkeypatch)
        out, mask = render_effects(image, spec, np.random.default_rng(seed))
    finally:
        monkeypatch.undo()
    assert out.dtype == image.dtype and out.shape == image.shape
    assert mask.shape == (height, width) and mask.dtype == np.uint8
    np.testing.assert_array_equal(out[mask == 0], image[mask == 0])
    for values in seen:
        assert np.isfinite(values).all()
        assert values.min(initial=0.0) >= -1e-3 and values.max(initial=0.0) <= 100 * 1.2 + 1.5


def test_non_contiguous_views_render_like_copies() -> None:
    base = _image(np.uint8, 3, (60, 70))
    spec = _spec(tuple(EFFECTS))
    for view in (base[:, :, 0], base[:, ::-1], base[::-1, :, ::-1]):
        got = render_effects(view, spec, np.random.default_rng(8))
        expected = render_effects(np.ascontiguousarray(view), spec, np.random.default_rng(8))
        np.testing.assert_array_equal(got[0], expected[0])
        np.testing.assert_array_equal(got[1], expected[1])


def test_listing_brightness_does_not_move_the_drops_of_later_frames() -> None:
    # "simulate only the effects a scene calls for": a do-nothing brightness must
    # not change where drops fall; it drew from the drops' generator
    shape = (64, 80)
    drops = RaindropsSpec(count=60, radius_px=(1.0, 3.0), persistence=0.5)
    centres = []
    for spec in (
        EffectsSpec(raindrops=drops),
        EffectsSpec(raindrops=drops, brightness=BrightnessSpec()),
    ):
        rng = np.random.default_rng(3)
        glass = sample_glass(spec, shape, rng)
        frames = []
        for _ in range(4):
            glass = advance_glass(glass, rng)
            assert glass.drops is not None
            frames.append(glass.drops.centers.copy())
        centres.append(frames)
    for plain, bright in zip(*centres, strict=True):
        np.testing.assert_array_equal(plain, bright)


@pytest.mark.parametrize(
    "effects",
    [
        EffectsSpec(raindrops=RaindropsSpec(count=0)),
        EffectsSpec(raindrops=RaindropsSpec(refractive_index=1.0)),
        EffectsSpec(dust=DustSpec(coverage=0.0)),
        EffectsSpec(dirt=DirtSpec(count=0)),
        EffectsSpec(veil=VeilSpec(strength=(0.0, 0.0))),
        EffectsSpec(
            raindrops=RaindropsSpec(refractive_index=1.0),
            brightness=BrightnessSpec(fraction=1.0, gain=(2.0, 2.0)),
        ),
        EffectsSpec(raindrops=RaindropsSpec(radius_px=(0.0, 0.0))),
        EffectsSpec(dirt=DirtSpec(opacity=(0.0, 0.0))),
        EffectsSpec(dirt=DirtSpec(radius_px=(0.0, 0.0))),
        EffectsSpec(dust=DustSpec(attenuation=(1.0, 1.0))),
    ],
    ids=[
        "no-drops",
        "drops-of-air",
        "no-dust",
        "no-dirt",
        "no-veil",
        "brightened-drops-of-air",
        "drops-of-radius-0",
        "clear-dirt",
        "dirt-of-radius-0",
        "dust-that-blocks-nothing",
    ],
)
def test_an_effect_that_changes_no_pixel_is_no_anomaly(effects: EffectsSpec) -> None:
    # rig.yaml's anomaly labels train the detector: a label on a clean frame teaches it wrong
    image = _image(np.uint8, 1, (60, 80))
    out, _ = render_effects(image, effects, np.random.default_rng(1))
    np.testing.assert_array_equal(out, image)
    assert effects.anomaly_kinds == ()


@pytest.mark.parametrize("names", [c for c in COMBINATIONS if len(c) > 1])
def test_a_glass_without_an_effect_renders_as_the_spec_without_it(names: tuple[str, ...]) -> None:
    # what simulate's labels compare against: the frame as if the effect were not listed,
    # everything else as drawn (the effects' draws come from streams of their own)
    image = np.random.default_rng(3).integers(0, 256, (48, 64), dtype=np.uint8)
    effects = EffectsSpec(**{name: EFFECTS[name] for name in names})
    glass = sample_glass(effects, image.shape, np.random.default_rng(7))
    for name in set(names) & {"raindrops", "dirt", "dust", "veil"}:
        gone = {name: None} | ({"brightness": None} if name == "raindrops" else {})
        fewer = dataclasses.replace(effects, **gone)
        alone = sample_glass(fewer, image.shape, np.random.default_rng(7))
        without = render.without_effect(glass, name)
        np.testing.assert_array_equal(without.mask, alone.mask)
        np.testing.assert_array_equal(apply_glass(image, without), apply_glass(image, alone))
    with pytest.raises(ValueError, match="'defocus'"):
        render.without_effect(glass, "defocus")
