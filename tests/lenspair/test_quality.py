import numpy as np
import pytest

from lenspair.core.quality import exposure_fractions, laplacian_variance, to_grey


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_exposure_counts_any_channel_saturated_and_all_channels_black(dtype: type) -> None:
    top = np.iinfo(dtype).max
    image = np.full((2, 2, 3), 7, dtype)
    image[0, 0] = (top, 0, 0)  # saturated in one channel
    image[0, 1] = (0, 0, 0)  # black
    image[1, 0] = (0, 0, 1)  # not black
    assert exposure_fractions(image) == (0.25, 0.25)
    assert exposure_fractions(image[:, :, 2]) == (0.0, 0.5)


def test_laplacian_variance_drops_with_blur_and_is_bit_depth_free() -> None:
    rng = np.random.default_rng(0)
    sharp = rng.integers(0, 256, (64, 64), dtype=np.uint8)
    blurred = np.full_like(sharp, int(sharp.mean()))
    assert laplacian_variance(to_grey(blurred)) == 0.0
    assert laplacian_variance(to_grey(sharp)) > 1000.0
    wide = sharp.astype(np.uint16) * 257
    assert laplacian_variance(to_grey(wide)) == pytest.approx(laplacian_variance(to_grey(sharp)))


def test_an_8_bit_image_and_its_16_bit_copy_have_the_same_grey() -> None:
    from lenspair.simulate.realism import realism_statistics

    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    wide = image.astype(np.uint16) * np.uint16(257)
    assert np.array_equal(to_grey(image), to_grey(wide))  # was a few ulps apart
    assert np.array_equal(to_grey(image[..., 0]), to_grey(wide[..., 0]))
    # so realism reads such a pair as identical (its input PSNR was about 152 dB)
    assert realism_statistics(wide, image).input_psnr == float("inf")


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_an_rgb_image_of_equal_channels_has_its_grey_image_s_grey(dtype: type) -> None:
    # OpenCV's float32 conversion moved 49 of 256 levels: realism read a grey copy of a frame
    # as changed (high-frequency share 0.95, 155 dB)
    levels = np.arange(np.iinfo(dtype).max + 1, dtype=dtype).reshape(1, -1)
    assert np.array_equal(to_grey(np.repeat(levels[..., None], 3, axis=2)), to_grey(levels))
    rgb = np.random.default_rng(0).integers(0, np.iinfo(dtype).max + 1, (8, 9, 3)).astype(dtype)
    expected = rgb.astype(np.float64) @ [0.299, 0.587, 0.114] / np.iinfo(dtype).max
    assert np.abs(to_grey(rgb) - expected).max() < 1e-7
