import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.rectify.crop import Crop, choose_crop
from lenspair.rectify.errors import CropError


def test_crop_is_centred_in_the_valid_region() -> None:
    valid = np.zeros((100, 160), dtype=bool)
    valid[10:90, 30:150] = True  # centroid (89.5, 49.5)
    crop = choose_crop(valid, (60, 40))
    assert crop == Crop(60, 30, 60, 40)
    assert valid[crop.y : crop.y + crop.height, crop.x : crop.x + crop.width].all()


def test_crop_moves_inside_an_irregular_region() -> None:
    valid = np.ones((100, 160), dtype=bool)
    valid[:, :50] = False
    valid[:20, :] = False
    valid[40:45, 60:70] = False  # a hole near the centroid
    crop = choose_crop(valid, (60, 40))
    assert valid[crop.y : crop.y + crop.height, crop.x : crop.x + crop.width].all()


def test_full_region_takes_the_exact_centre() -> None:
    crop = choose_crop(np.ones((480, 752), dtype=bool), (540, 360))
    assert crop.as_tuple() == (106, 60, 540, 360)


def test_too_narrow_says_by_how_much() -> None:
    valid = np.zeros((480, 752), dtype=bool)
    valid[50:430, 100:610] = True  # 510 x 380
    with pytest.raises(
        CropError,
        match=r"^valid region too small; need 540x360: 30 px too narrow \(510x360 px fits; no "
        r"crop 540 px wide does\); the largest crop of that shape that fits is 510x340 px$",
    ):
        choose_crop(valid, (540, 360))


def test_a_region_that_is_not_a_rectangle_says_what_crop_of_the_shape_fits() -> None:
    """The tallest rectangle (328 wide) was all it said, though 720x536 was valid too."""
    valid = np.zeros((540, 720), dtype=bool)
    valid[:, 196:524] = True  # 328 x 540
    valid[2:538, :] = True  # 720 x 536
    with pytest.raises(CropError, match=r"the largest crop of that shape that fits is 536x536 px$"):
        choose_crop(valid, (2000, 2000))
    with pytest.raises(CropError, match=r"the largest crop of that shape that fits is 720x360 px$"):
        choose_crop(valid, (800, 400))


def test_every_size_the_shortfall_names_is_true_of_a_region_that_is_not_a_rectangle() -> None:
    """It said "valid region is 328x540 px; ... 392 px too narrow", then advised 714x536.

    A rectified region: a full-height band 328 px wide, and 720 px wide but
    for two rows at the top and bottom. The crops it names fit; one pixel more
    on the side it names does not.
    """
    valid = np.zeros((540, 720), dtype=bool)
    valid[:, 196:524] = True  # 328 x 540
    valid[2:538, :] = True  # 720 x 536
    with pytest.raises(CropError) as caught:
        choose_crop(valid, (720, 540))
    assert str(caught.value) == (
        "valid region too small; need 720x540: 392 px too narrow at full height (328x540 px "
        "fits) or 4 px too short at full width (720x536 px fits); the largest crop of that "
        "shape that fits is 714x536 px"
    )
    for fits, too_large in (((328, 540), (329, 540)), ((720, 536), (720, 537))):
        crop = choose_crop(valid, fits)
        assert valid[crop.y : crop.y + crop.height, crop.x : crop.x + crop.width].all()
        with pytest.raises(CropError):
            choose_crop(valid, too_large)
    choose_crop(valid, (714, 536))


@pytest.mark.parametrize(
    ("right", "message"),
    [
        (  # 600 x 300: too short at every width
            700,
            r"need 540x360: 60 px too short \(540x300 px fits; no crop 360 px tall does\); "
            r"the largest crop of that shape that fits is 450x300 px$",
        ),
        (  # 500 x 300: too short and too narrow
            600,
            r"need 540x360: 40 px too narrow and 60 px too short \(no crop wider than 500 px "
            r"or taller than 300 px fits\)",
        ),
    ],
)
def test_a_region_short_of_the_request_says_by_how_much(right: int, message: str) -> None:
    valid = np.zeros((480, 752), dtype=bool)
    valid[100:400, 100:right] = True
    with pytest.raises(CropError, match=message):
        choose_crop(valid, (540, 360))


def test_crop_larger_than_image() -> None:
    with pytest.raises(CropError, match="need 800x360: 48 px too narrow"):
        choose_crop(np.ones((480, 752), dtype=bool), (800, 360))


def test_empty_region() -> None:
    with pytest.raises(CropError, match=r"need 10x10: the valid region is empty"):
        choose_crop(np.zeros((50, 50), dtype=bool), (10, 10))


rectangles = st.tuples(
    st.integers(0, 60), st.integers(0, 40), st.integers(1, 60), st.integers(1, 40)
)


@st.composite
def regions(draw: st.DrawFn) -> np.ndarray:
    """A 60x40 valid region made of one to four rectangles (not itself a rectangle)."""
    valid = np.zeros((40, 60), dtype=bool)
    for x, y, w, h in draw(st.lists(rectangles, min_size=1, max_size=4)):
        valid[y : y + h, x : x + w] = True
    return valid


@settings(max_examples=60, deadline=None)
@given(regions(), st.integers(2, 90), st.integers(2, 60))
def test_the_crop_of_that_shape_said_to_fit_fits(
    valid: np.ndarray, width: int, height: int
) -> None:
    try:
        choose_crop(valid, (width, height))
    except CropError as error:
        said = re.search(r"that shape that fits is (\d+)x(\d+) px", str(error))
        if said:
            fits = int(said[1]), int(said[2])
            crop = choose_crop(valid, fits)
            assert valid[crop.y : crop.y + crop.height, crop.x : crop.x + crop.width].all()
            assert fits[0] <= width and fits[1] < height  # smaller, of about that shape
            assert abs(fits[0] - fits[1] * width / height) < 1
            taller = fits[1] + 1
            if taller * width // height >= 1:  # the largest: one row more of that shape won't fit
                with pytest.raises(CropError):
                    choose_crop(valid, (taller * width // height, taller))


@settings(max_examples=60, deadline=None)
@given(regions(), st.integers(2, 90), st.integers(2, 60))
def test_every_size_the_shortfall_names_is_true(valid: np.ndarray, width: int, height: int) -> None:
    try:
        choose_crop(valid, (width, height))
    except CropError as error:
        said = str(error)
        for w, h in re.findall(r"(\d+)x(\d+) px fits", said):  # each crop said to fit, fits
            choose_crop(valid, (int(w), int(h)))
        for pixels, which in re.findall(r"no crop (\d+) px (wide|tall) does", said):
            with pytest.raises(CropError):
                choose_crop(valid, (int(pixels), 1) if which == "wide" else (1, int(pixels)))
        if found := re.search(r"wider than (\d+) px or taller than (\d+) px", said):
            for size in ((int(found[1]) + 1, 1), (1, int(found[2]) + 1)):
                with pytest.raises(CropError):
                    choose_crop(valid, size)
        if found := re.search(r"(\d+) px too narrow at full height \((\d+)x", said):
            assert int(found[1]) + int(found[2]) == width  # the shortfall is of the crop named
            with pytest.raises(CropError):  # and the widest at that height
                choose_crop(valid, (int(found[2]) + 1, height))


def test_a_crop_without_area_is_refused() -> None:
    with pytest.raises(ValueError, match="crop size: expected at least 1x1 pixels, got 0x5"):
        choose_crop(np.ones((40, 60), dtype=bool), (0, 5))
