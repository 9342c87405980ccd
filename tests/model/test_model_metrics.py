"""PSNR/SSIM in torch against scikit-image (and OpenCV's luma), both conventions."""

import math
import warnings

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from lenspair.model.errors import ModelError
from lenspair.model.metrics import (
    PSNR_CAP_DB,
    SCALE_SLACK,
    MetricConvention,
    gaussian_window,
    image_metrics,
    luma_uint8,
    mean_psnr,
    parse_metric_convention,
    psnr,
    quantize_uint8,
    ssim,
)

SIZES = [(11, 11), (24, 37), (63, 50), (97, 131)]


def _structured(channels: int, height: int, width: int, seed: int) -> np.ndarray:
    """Smooth gradients, a bright disc and mild noise, HWC float64 in [0, 1]."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width] / max(height, width)
    planes = []
    for c in range(channels):
        plane = 0.5 + 0.4 * np.sin(6 * xx + c) * np.cos(4 * yy - c)
        disc = (yy - 0.4) ** 2 + (xx - 0.5 - 0.1 * c) ** 2 < 0.05
        plane[disc] = 0.95
        planes.append(plane + 0.02 * rng.standard_normal((height, width)))
    return np.clip(np.stack(planes, axis=-1), 0, 1)


def _pair(
    kind: str, channels: int, size: tuple[int, int], seed: int
) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed + 100)
    if kind == "random":
        a = rng.random((*size, channels))
        b = np.clip(a + 0.2 * rng.standard_normal(a.shape), 0, 1)
    else:
        a = _structured(channels, *size, seed)
        b = np.clip(_structured(channels, *size, seed + 1) * 0.9 + 0.05, 0, 1)
    return a.astype(np.float32), b.astype(np.float32)


def _to_tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None]


def _skimage_ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """scikit-image's full SSIM map of two HWC float64 images, ``skimage-gaussian``, HWC.

    Its mean over the map cropped by the window's radius (5) is skimage's mean SSIM.
    """
    colour = a.shape[2] == 3
    _, full = structural_similarity(
        a if colour else a[..., 0],
        b if colour else b[..., 0],
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1.0,
        channel_axis=-1 if colour else None,
        full=True,
    )
    return np.asarray(full if colour else full[..., None])


@pytest.mark.parametrize("kind", ["random", "structured"])
@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("size", SIZES)
def test_skimage_gaussian_matches_skimage(kind: str, channels: int, size: tuple[int, int]) -> None:
    a, b = _pair(kind, channels, size, seed=sum(size) + channels)
    ours = image_metrics(_to_tensor(b), _to_tensor(a), MetricConvention.SKIMAGE_GAUSSIAN)
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    reference_ssim = float(_skimage_ssim_map(a64, b64)[5:-5, 5:-5].mean())
    reference_psnr = peak_signal_noise_ratio(a64, b64, data_range=1.0)
    assert abs(float(ours.ssim[0]) - reference_ssim) < 1e-4
    assert abs(float(ours.psnr[0]) - reference_psnr) < 1e-4
    assert ours.convention is MetricConvention.SKIMAGE_GAUSSIAN


def _deraindrop_reference(output: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """DeRaindrop's metrics.py on uint8 images (theirs are BGR from cv2.imread)."""
    output_u8 = np.round(np.clip(output, 0, 1) * 255).astype(np.uint8)
    target_u8 = np.round(np.clip(target, 0, 1) * 255).astype(np.uint8)
    if output.shape[-1] == 3:
        output_y = cv2.cvtColor(output_u8[..., ::-1].copy(), cv2.COLOR_BGR2YCR_CB)[:, :, 0]
        target_y = cv2.cvtColor(target_u8[..., ::-1].copy(), cv2.COLOR_BGR2YCR_CB)[:, :, 0]
    else:
        output_y, target_y = output_u8[..., 0], target_u8[..., 0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # divide by zero: identical images
        value_psnr = peak_signal_noise_ratio(output_y, target_y)
    return float(value_psnr), float(structural_similarity(output_y, target_y))


@pytest.mark.parametrize("kind", ["random", "structured"])
@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("size", SIZES[1:])
def test_deraindrop_y_matches_their_protocol(
    kind: str, channels: int, size: tuple[int, int]
) -> None:
    a, b = _pair(kind, channels, size, seed=3 * sum(size) + channels)
    ours = image_metrics(_to_tensor(b), _to_tensor(a), MetricConvention.DERAINDROP_Y)
    reference_psnr, reference_ssim = _deraindrop_reference(b, a)
    assert abs(float(ours.psnr[0]) - reference_psnr) < 1e-4
    assert abs(float(ours.ssim[0]) - reference_ssim) < 1e-4


def test_luma_is_bit_exact_with_opencv() -> None:
    rng = np.random.default_rng(7)
    rgb = rng.integers(0, 256, size=(61, 83, 3), dtype=np.uint8)
    rgb[0, :8] = [[0, 0, 0], [255, 255, 255], [255, 0, 0], [0, 255, 0], [0, 0, 255], [1, 2, 3],
                  [128, 128, 128], [254, 1, 127]]  # fmt: skip
    reference = cv2.cvtColor(rgb[..., ::-1].copy(), cv2.COLOR_BGR2YCR_CB)[:, :, 0]
    ours = luma_uint8(torch.from_numpy(rgb).permute(2, 0, 1)[None].contiguous())
    assert np.array_equal(ours[0, 0].numpy(), reference)


def test_batches_score_each_image() -> None:
    a = torch.rand(3, 3, 20, 24, generator=torch.Generator().manual_seed(1))
    b = (a + 0.05 * torch.randn(3, 3, 20, 24, generator=torch.Generator().manual_seed(2))).clamp(
        0, 1
    )
    together = image_metrics(b, a, MetricConvention.SKIMAGE_GAUSSIAN)
    for index in range(3):
        alone = image_metrics(b[index : index + 1], a[index : index + 1], "skimage-gaussian")  # type: ignore[arg-type]
        assert torch.allclose(together.psnr[index], alone.psnr[0])
        assert torch.allclose(together.ssim[index], alone.ssim[0])


@pytest.mark.parametrize("convention", list(MetricConvention))
def test_identical_constant_and_zero_images(convention: MetricConvention) -> None:
    cases = {
        "identical": torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(3)),
        "zeros": torch.zeros(1, 3, 16, 16),
        "ones": torch.ones(1, 3, 16, 16),
        "constant": torch.full((1, 3, 16, 16), 0.37),
    }
    for name, image in cases.items():
        scores = image_metrics(image, image.clone(), convention)
        assert math.isinf(float(scores.psnr[0])) and float(scores.psnr[0]) > 0, name
        assert float(scores.ssim[0]) == pytest.approx(1.0, abs=1e-12), name
    # Two different constant images: finite, no NaN, below 1.
    scores = image_metrics(torch.zeros(1, 1, 16, 16), torch.full((1, 1, 16, 16), 0.5), convention)
    assert math.isfinite(float(scores.psnr[0])) and 0 <= float(scores.ssim[0]) < 1
    reference_ssim = structural_similarity(
        np.zeros((16, 16)),
        np.full((16, 16), 0.5 if convention is MetricConvention.SKIMAGE_GAUSSIAN else 128.0),
        data_range=1.0 if convention is MetricConvention.SKIMAGE_GAUSSIAN else 255.0,
        gaussian_weights=convention is MetricConvention.SKIMAGE_GAUSSIAN,
        use_sample_covariance=convention is MetricConvention.DERAINDROP_Y,
    )
    assert abs(float(scores.ssim[0]) - reference_ssim) < 1e-6


def test_mean_psnr_caps_infinity() -> None:
    values = torch.tensor([30.0, math.inf], dtype=torch.float64)
    assert mean_psnr(values) == pytest.approx((30.0 + PSNR_CAP_DB) / 2)
    assert mean_psnr(torch.tensor([20.0, 40.0])) == pytest.approx(30.0)
    with pytest.raises(ModelError, match="no values"):
        mean_psnr(torch.tensor([]))
    with pytest.raises(ModelError, match="NaN"):
        mean_psnr(torch.tensor([math.nan]))


def test_gaussian_window_is_normalised_11_taps() -> None:
    taps = gaussian_window()
    assert taps.numel() == 11 and float(taps.sum()) == pytest.approx(1.0, abs=1e-15)
    assert torch.equal(taps, taps.flip(0)) and int(taps.argmax()) == 5


def test_quantize_rounds_and_clips() -> None:
    values = torch.tensor([-0.2, 0.0, 0.4 / 255, 1.6 / 255, 0.999, 1.0, 1.3])
    assert quantize_uint8(values).tolist() == [0, 0, 0, 2, 255, 255, 255]


def test_errors() -> None:
    with pytest.raises(ModelError, match="valid: skimage-gaussian, deraindrop-y"):
        parse_metric_convention("matlab")
    with pytest.raises(ModelError, match="shapes differ"):
        psnr(torch.rand(1, 1, 8, 8), torch.rand(1, 1, 8, 9))
    with pytest.raises(ModelError, match="smaller than the 11x11 window"):
        ssim(torch.rand(1, 1, 10, 30), torch.rand(1, 1, 10, 30))
    with pytest.raises(ModelError, match="NaN"):
        psnr(torch.full((1, 1, 8, 8), math.nan), torch.rand(1, 1, 8, 8))
    with pytest.raises(ModelError, match="odd"):
        ssim(torch.rand(1, 1, 16, 16), torch.rand(1, 1, 16, 16), gaussian_weights=False, win_size=4)
    assert str(MetricConvention.DERAINDROP_Y) == "deraindrop-y"


@pytest.mark.parametrize("convention", list(MetricConvention))
@pytest.mark.parametrize("shape", [(1, 1, 0, 32), (0, 1, 32, 32)])
def test_empty_images_are_refused_never_nan(
    convention: MetricConvention, shape: tuple[int, ...]
) -> None:
    """psnr gave NaN for an image of no rows (the module promises never NaN), and
    image_metrics a torch traceback from taking the minimum of nothing."""
    empty = torch.zeros(shape)
    with pytest.raises(ModelError, match=r"metrics: empty images \(N, C, H, W\)"):
        psnr(empty, empty)
    with pytest.raises(ModelError, match="empty images"):
        image_metrics(empty, empty, convention)


@pytest.mark.parametrize("convention", list(MetricConvention))
def test_images_on_another_scale_are_refused_not_misscored(convention: MetricConvention) -> None:
    rng = np.random.default_rng(11)
    codes = rng.integers(0, 256, (1, 1, 24, 24), dtype=np.uint8)
    noisy = np.clip(codes.astype(np.int16) + rng.integers(-2, 3, codes.shape), 0, 255)
    a, b = torch.from_numpy(codes), torch.from_numpy(noisy.astype(np.uint8))
    # 0-255 floats: PSNR at data_range 1 came out negative, deraindrop-y binarised them
    with pytest.raises(ModelError, match=r"output values span \[0, 255\]; expected \[0, 1\]"):
        image_metrics(b.double(), a.double() / 255, convention)
    with pytest.raises(ModelError, match=r"target is torch.int32; expected floats in \[0, 1\]"):
        image_metrics(b.double() / 255, a.int(), convention)
    right = image_metrics(b.double() / 255, a.double() / 255, convention)
    assert float(right.psnr[0]) > 40.0
    if convention is MetricConvention.DERAINDROP_Y:  # its uint8 input: the same numbers
        exact = image_metrics(b, a, convention)
        assert torch.equal(exact.psnr, right.psnr) and torch.equal(exact.ssim, right.ssim)
    else:
        with pytest.raises(ModelError, match=r"output is torch.uint8; expected floats in \[0, 1\]"):
            image_metrics(b, a, convention)
    # values a hair outside [0, 1] (rounding of a network's output) are scored
    image_metrics((b.double() / 255 * 1.01 - 0.005), a.double() / 255, convention)


def _valid_windows(valid: np.ndarray, size: int) -> np.ndarray:
    """Centres of the ``size`` windows lying wholly on ``valid``, cropped as skimage crops."""
    eroded = cv2.erode(valid.astype(np.uint8), np.ones((size, size), np.uint8), borderValue=0)
    pad = (size - 1) // 2
    return eroded[pad:-pad, pad:-pad].astype(bool)


@given(
    channels=st.sampled_from([1, 3]),
    size=st.tuples(st.integers(24, 60), st.integers(24, 60)),
    boxes=st.lists(
        st.tuples(st.floats(0, 0.9), st.floats(0, 0.9), st.floats(0.05, 0.5), st.floats(0.05, 0.5)),
        max_size=3,
    ),
    seed=st.integers(0, 1000),
)
@settings(max_examples=40, deadline=None)
def test_untrustworthy_pixels_are_left_out_as_skimage_scores_the_rest(
    channels: int,
    size: tuple[int, int],
    boxes: list[tuple[float, float, float, float]],
    seed: int,
) -> None:
    # PSNR over the valid pixels; SSIM: skimage's map over the windows wholly valid
    a, b = _pair("structured", channels, size, seed)
    valid = np.ones(size, bool)
    for top, left, tall, wide in boxes:  # masked rectangles (misregistered regions)
        y, x = int(top * size[0]), int(left * size[1])
        valid[y : y + max(1, int(tall * size[0])), x : x + max(1, int(wide * size[1]))] = False
    windows = _valid_windows(valid, 11)
    mask = torch.from_numpy(valid)[None, None]
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    if not windows.any():
        with pytest.raises(ModelError, match="no 11x11 window wholly on trustworthy pixels"):
            image_metrics(_to_tensor(b), _to_tensor(a), MetricConvention.SKIMAGE_GAUSSIAN, mask)
        return
    ours = image_metrics(_to_tensor(b), _to_tensor(a), MetricConvention.SKIMAGE_GAUSSIAN, mask)
    cropped = _skimage_ssim_map(a64, b64)[5:-5, 5:-5]
    assert abs(float(ours.ssim[0]) - cropped[windows].mean()) < 1e-4
    assert (
        abs(float(ours.psnr[0]) - peak_signal_noise_ratio(a64[valid], b64[valid], data_range=1.0))
        < 1e-4
    )
    # what lies under the mask does not count: changing it changes neither score
    scrambled = b.copy()
    scrambled[~valid] = 1.0 - scrambled[~valid]
    again = image_metrics(
        _to_tensor(scrambled), _to_tensor(a), MetricConvention.SKIMAGE_GAUSSIAN, mask
    )
    assert abs(float(again.psnr[0]) - float(ours.psnr[0])) < 1e-9
    assert abs(float(again.ssim[0]) - float(ours.ssim[0])) < 1e-9


@pytest.mark.parametrize("convention", list(MetricConvention))
def test_an_all_trusted_map_scores_as_none_and_an_all_masked_one_is_refused(
    convention: MetricConvention,
) -> None:
    a, b = _pair("structured", 3, (40, 50), 7)
    plain = image_metrics(_to_tensor(b), _to_tensor(a), convention)
    trusted = image_metrics(
        _to_tensor(b), _to_tensor(a), convention, torch.ones(1, 1, 40, 50, dtype=torch.bool)
    )
    assert torch.allclose(plain.psnr, trusted.psnr) and torch.allclose(plain.ssim, trusted.ssim)
    with pytest.raises(ModelError, match="no trustworthy pixel"):
        image_metrics(_to_tensor(b), _to_tensor(a), convention, torch.zeros(1, 1, 40, 50))
    with pytest.raises(ModelError, match="valid map"):
        image_metrics(_to_tensor(b), _to_tensor(a), convention, torch.ones(1, 1, 40, 49))


@pytest.mark.parametrize("top", [1.5, 1.0 + SCALE_SLACK + 0.01])
def test_values_above_the_slack_are_refused_not_scored(top: float) -> None:
    # scored with data_range 1, an image in [0, 2] gave a PSNR that meant nothing
    target = torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0))
    output = target.clone()
    output[0, 0, 0, 0] = top
    with pytest.raises(ModelError, match=r"values span \[.*\]; expected \[0, 1\]"):
        image_metrics(output, target, MetricConvention.SKIMAGE_GAUSSIAN)
    output[0, 0, 0, 0] = 1.0 + SCALE_SLACK / 2  # rounding and int8 stray this far: scored
    assert image_metrics(output, target, MetricConvention.SKIMAGE_GAUSSIAN).psnr.shape == (1,)


@pytest.mark.parametrize(
    ("dtype", "low", "high"),
    [(np.uint8, 0, 255), (np.int16, 0, 4095), (np.int16, -3000, 3000), (np.float64, -1, 1)],
)
def test_the_default_data_range_is_skimage_s(dtype: type, low: float, high: float) -> None:
    # uint8 scored as if in [0, 1] gave -9.5 dB where skimage gives 38.6 dB; skimage's psnr
    # reads the target (the dtype's maximum when it has no negative value, else the span)
    rng = np.random.default_rng(3)
    if np.issubdtype(dtype, np.integer):
        target = rng.integers(low, high, (40, 50), endpoint=True).astype(dtype)
        output = np.clip(target.astype(np.int64) + rng.integers(-3, 4, target.shape), low, high)
        output = output.astype(dtype)
    else:
        target = rng.uniform(low, high, (40, 50))
        output = np.clip(target + rng.normal(0, 0.01, target.shape), low, high)
    ours = float(
        psnr(torch.from_numpy(output)[None, None], torch.from_numpy(target)[None, None])[0]
    )
    assert ours == pytest.approx(peak_signal_noise_ratio(target, output), abs=1e-9)
    if not np.issubdtype(dtype, np.integer):
        return  # skimage's ssim refuses floats without a data_range
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "Setting data_range based on im1.dtype"
        theirs = structural_similarity(
            target, output, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
        )
    pair = (torch.from_numpy(output)[None, None], torch.from_numpy(target)[None, None])
    assert float(ssim(*pair)[0]) == pytest.approx(theirs, abs=1e-9)


def test_data_ranges_that_cannot_score_are_refused() -> None:
    image = torch.rand(1, 1, 16, 16)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ModelError, match="data_range must be a finite positive number"):
            psnr(image, image * 0.5, data_range=bad)
        with pytest.raises(ModelError, match="data_range must be a finite positive number"):
            ssim(image, image * 0.5, data_range=bad)
    with pytest.raises(ModelError, match=r"output is torch\.uint8 and target torch\.float32"):
        ssim((image * 255).to(torch.uint8), image)
    with pytest.raises(ModelError, match="sample_covariance needs a window of more than one"):
        ssim(image, image, gaussian_weights=False, win_size=1, sample_covariance=True)
