import numpy as np
import pytest

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
        CropError, match=r"valid region is 510x380 px; need 540x360: 30 px too narrow$"
    ):
        choose_crop(valid, (540, 360))


def test_too_short_and_too_narrow() -> None:
    valid = np.zeros((480, 752), dtype=bool)
    valid[100:400, 100:600] = True  # 500 x 300
    with pytest.raises(
        CropError, match="500x300 px; need 540x360: 40 px too narrow and 60 px too short"
    ):
        choose_crop(valid, (540, 360))


def test_crop_larger_than_image() -> None:
    with pytest.raises(CropError, match="need 800x360: 48 px too narrow"):
        choose_crop(np.ones((480, 752), dtype=bool), (800, 360))


def test_empty_region() -> None:
    with pytest.raises(CropError, match="valid region is 0x0 px"):
        choose_crop(np.zeros((50, 50), dtype=bool), (10, 10))
