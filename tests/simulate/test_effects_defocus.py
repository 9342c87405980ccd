"""Defocus: averaging random shifts of the glass layer, disk blur, footprint growth."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.simulate.effects import defocus, raindrops
from lenspair.simulate.effects.spec import DefocusSpec, EffectsSpec, RaindropsSpec
from lenspair.simulate.render import render_effects, sample_glass


def _shifted(layer: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """``layer(p - (dx, dy))`` with zeros shifted in."""
    out = np.zeros_like(layer)
    h, w = layer.shape[:2]
    out[max(dy, 0) : h + min(dy, 0), max(dx, 0) : w + min(dx, 0)] = layer[
        max(-dy, 0) : h + min(-dy, 0), max(-dx, 0) : w + min(-dx, 0)
    ]
    return out


@given(
    shifts=st.lists(st.tuples(st.floats(-6, 6), st.floats(-6, 6)), min_size=1, max_size=12),
    disk=st.floats(0.0, 5.0),
)
def test_kernel_is_a_normalised_non_negative_filter(
    shifts: list[tuple[float, float]], disk: float
) -> None:
    kernel = defocus.blur_kernel(np.array(shifts), disk)
    assert kernel.dtype == np.float32 and kernel.shape[0] == kernel.shape[1]
    assert kernel.shape[0] % 2 == 1
    assert (kernel >= 0).all()
    assert float(kernel.sum()) == pytest.approx(1.0, abs=1e-5)
    largest = max(math.hypot(dx, dy) for dx, dy in shifts)
    assert defocus.kernel_reach(kernel) <= largest + math.sqrt(2) + disk + 1.5


def test_kernel_equals_averaging_integer_shifts_of_the_layer() -> None:
    rng = np.random.default_rng(0)
    layer = np.zeros((40, 50, 4), np.float32)
    layer[10:30, 15:35] = rng.random((20, 20, 4), dtype=np.float32)
    shifts = np.array([[2, 0], [-1, 3], [0, 0], [3, -2]], np.float64)
    kernel = defocus.blur_kernel(shifts, 0.0)
    got = cv2.filter2D(layer, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    expected = np.mean([_shifted(layer, int(dx), int(dy)) for dx, dy in shifts], axis=0)
    np.testing.assert_allclose(got, expected, atol=1e-6)


def test_subpixel_shift_is_bilinear() -> None:
    kernel = defocus.blur_kernel(np.array([[0.25, 0.0]]), 0.0)
    half = kernel.shape[0] // 2
    # layer(p - 0.25) = 0.75 layer(p) + 0.25 layer(p - 1)
    assert kernel[half, half] == pytest.approx(0.75)
    assert kernel[half, half - 1] == pytest.approx(0.25)
    assert defocus.kernel_reach(kernel) == 1.0


def test_disk_kernel_is_round_and_normalised() -> None:
    disk = defocus.disk_kernel(4.0)
    assert float(disk.sum()) == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(disk, disk.T)
    np.testing.assert_allclose(disk, disk[::-1, ::-1])
    half = disk.shape[0] // 2
    assert disk[half, half] > 0 and disk[0, 0] == 0  # corners are outside the disk
    assert defocus.disk_kernel(0.0).tolist() == [[1.0]]


def test_shifts_stay_inside_the_disk() -> None:
    shifts = defocus.sample_shifts(DefocusSpec(shifts=256, shift_px=3.0), np.random.default_rng(1))
    assert shifts.shape == (256, 2)
    radius = np.hypot(shifts[:, 0], shifts[:, 1])
    assert radius.max() <= 3.0 and radius.max() > 2.8


def test_blur_in_boxes_matches_blurring_the_whole_frame() -> None:
    rng = np.random.default_rng(2)
    kernel = defocus.blur_kernel(defocus.sample_shifts(DefocusSpec(), rng), 2.0)
    half = kernel.shape[0] // 2
    margin = 2 * half
    height, width = 60, 80
    canvas = np.zeros((height + 2 * margin, width + 2 * margin, 2), np.float32)
    boxes = np.array([[-half, 10, -half, 12], [30, 45, 60, 80 + half], [20, 26, 20, 30]])
    for y0, y1, x0, x1 in boxes:
        canvas[y0 + margin : y1 + margin, x0 + margin : x1 + margin] = rng.random(
            (y1 - y0, x1 - x0, 2), dtype=np.float32
        )
    got = defocus.blur_layer(canvas, margin, boxes, kernel)
    full = cv2.filter2D(canvas, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    expected = full[margin : margin + height, margin : margin + width]
    np.testing.assert_allclose(got, expected, atol=1e-5)


def test_defocus_grows_the_footprint_by_the_kernel_reach() -> None:
    shape = (90, 120)
    drops = RaindropsSpec(count=12)
    sharp = sample_glass(EffectsSpec(raindrops=drops), shape, np.random.default_rng(3))
    spec = DefocusSpec(shifts=6, shift_px=4.0, disk_radius_px=1.5)
    blurred = sample_glass(
        EffectsSpec(raindrops=drops, defocus=spec), shape, np.random.default_rng(3)
    )
    assert blurred.kernel is not None
    reach = defocus.kernel_reach(blurred.kernel)
    assert 1.5 < reach <= 4.0 + 1.5 + 1.5 + math.sqrt(2)
    inner, outer = sharp.mask > 0, blurred.mask > 0
    assert (outer >= inner).all() and outer.sum() > inner.sum()
    # Every footprint pixel is within the reach of a sharp drop pixel.
    distance = cv2.distanceTransform((~inner).astype(np.uint8), cv2.DIST_L2, 5)
    assert distance[outer].max() <= math.ceil(reach) + 0.5


def test_defocused_drop_outside_the_frame_bleeds_in(monkeypatch: pytest.MonkeyPatch) -> None:
    # A drop just left of the image: only its defocus blur reaches the frame.
    drops = raindrops.Drops(
        np.array([[-6.0, 25.0]]), np.array([[4.0, 4.0]]), np.zeros(1), np.radians([70.0])
    )
    monkeypatch.setattr(raindrops, "sample_drops", lambda spec, shape, rng: drops)
    image = np.full((50, 50), 200, np.uint8)
    sharp = EffectsSpec(raindrops=RaindropsSpec(count=1))
    out, mask = render_effects(image, sharp, np.random.default_rng(0))
    assert not mask.any()
    np.testing.assert_array_equal(out, image)
    spec = EffectsSpec(
        raindrops=RaindropsSpec(count=1),
        defocus=DefocusSpec(shifts=1, shift_px=0.0, disk_radius_px=4.0),
    )
    out, mask = render_effects(image, spec, np.random.default_rng(0))
    assert mask[25, 0] == 255 and mask[25, 6] == 0
    assert out[25, 0] < image[25, 0]  # the blurred dark rim shows at the border
    np.testing.assert_array_equal(out[mask == 0], image[mask == 0])


def test_default_blur_follows_the_thin_lens_of_an_alphasense_like_camera() -> None:
    spec = DefocusSpec()
    # f_px = 2.4 mm / 6.9 um = 348 px; A = 2.4 / 2.0 = 1.2 mm; d = 30 mm.
    assert spec.focal_px == pytest.approx(2400 / 6.9)
    assert spec.blur_diameter_px == pytest.approx(2400 / 6.9 * 1.2 / 30)
    assert spec.shift_radius_px == pytest.approx(spec.blur_diameter_px / 2) and spec.disk_px == 0
    farther = DefocusSpec(glass_distance_m=0.06)
    assert farther.blur_diameter_px == pytest.approx(spec.blur_diameter_px / 2)
    wider = DefocusSpec(f_number=1.0)
    assert wider.blur_diameter_px == pytest.approx(2 * spec.blur_diameter_px)
    disk = DefocusSpec(kernel="disk")
    assert disk.shift_radius_px == 0 and disk.disk_px == pytest.approx(spec.blur_diameter_px / 2)
    by_hand = DefocusSpec(shift_px=2.0, disk_radius_px=1.0)
    assert (by_hand.shift_radius_px, by_hand.disk_px) == (2.0, 1.0)


@pytest.mark.parametrize("kernel", ["shifts", "disk"])
def test_kernel_reach_is_the_blur_radius(kernel: str) -> None:
    spec = DefocusSpec(kernel=kernel, shifts=64)  # type: ignore[arg-type]
    glass = sample_glass(EffectsSpec(defocus=spec), (32, 32), np.random.default_rng(0))
    assert glass.kernel is not None
    reach = defocus.kernel_reach(glass.kernel)
    radius = spec.blur_diameter_px / 2
    assert radius - 1.5 <= reach <= radius + 2.0


def test_glass_too_close_for_the_kernel_is_refused() -> None:
    with pytest.raises(ValueError, match="glass_distance_m"):
        DefocusSpec(glass_distance_m=0.002, pixel_pitch_um=6.9)
    close = EffectsSpec(defocus=DefocusSpec(glass_distance_m=0.002))  # the camera decides
    with pytest.raises(ValueError, match="glass_distance_m"):
        close.for_photograph()
    with pytest.raises(ValueError, match="glass_distance_m"):
        close.for_camera(350.0)
    assert close.for_camera(30.0).defocus is not None  # a 30 px camera blurs it 18 px
    DefocusSpec(glass_distance_m=0.002, shift_px=3.0, pixel_pitch_um=6.9)  # pixels by hand


@pytest.mark.parametrize("fx", [20.0, 5e4])
@pytest.mark.parametrize("by_hand", [{"shift_px": 2.0}, {"kernel": "disk", "disk_radius_px": 2.0}])
def test_a_blur_sized_by_hand_does_not_need_the_camera_s_pixel(
    fx: float, by_hand: dict[str, object]
) -> None:
    # fx 20 px is a 120 um pixel at the default focal length: refused, though the blur
    # was given in pixels and the pixel size is not used
    effects = EffectsSpec(defocus=DefocusSpec(**by_hand)).for_camera(fx)  # type: ignore[arg-type]
    assert effects.defocus is not None and effects.defocus.pixel_pitch_um is None
    with pytest.raises(ValueError, match=r"defocus\.pixel_pitch_um: .* outside 0\.1\.\.100"):
        EffectsSpec(defocus=DefocusSpec()).for_camera(fx)  # sized by the optics


@given(seed=st.integers(0, 2**31 - 1))
def test_a_declared_defocus_of_no_blur_renders_as_no_defocus(seed: int) -> None:
    # a zero shift kept a 3x3 kernel whose pad changed the rim colour of drops on the
    # frame border: declared zero strength must equal no effect, to the code
    image = np.random.default_rng(0).integers(0, 256, (72, 96), dtype=np.uint8)
    drops = RaindropsSpec(count=8, radius_px=(4.0, 12.0))
    plain = render_effects(image, EffectsSpec(raindrops=drops), np.random.default_rng(seed))
    zero = EffectsSpec(raindrops=drops, defocus=DefocusSpec(shift_px=0.0))
    blurred = render_effects(image, zero, np.random.default_rng(seed))
    assert np.array_equal(plain[0], blurred[0]) and np.array_equal(plain[1], blurred[1])
    assert defocus.blur_kernel(np.zeros((16, 2)), 0.0).tolist() == [[1.0]]


@pytest.mark.parametrize(
    "spec",
    [{"shifts": 1}, {"shifts": 3, "shift_px": 2.0}, {"shifts": 2, "kernel": "shifts"}],
)
def test_too_few_shifts_to_blur_are_refused(spec: dict[str, object]) -> None:
    # one shift translated the whole glass layer (sharp drops, moved), two doubled it
    with pytest.raises(ValueError, match="shifts: expected at least 4 where the layer is shifted"):
        DefocusSpec(**spec)  # type: ignore[arg-type]


def test_one_shift_is_fine_where_nothing_is_shifted() -> None:
    assert DefocusSpec(shifts=1, shift_px=0.0, disk_radius_px=4.0).shifts == 1
    assert DefocusSpec(shifts=1, kernel="disk").shifts == 1
