import cv2
import numpy as np
import pytest

from lenspair.rectify.crop import Crop
from lenspair.rectify.rectification import StereoRectification
from lenspair.rectify.remap import (
    RemapGrid,
    apply,
    apply_homography,
    input_map,
    inside,
    pixel_grid,
    shifted,
    target_map,
    valid_region,
)
from lenspair.rectify.rig import CameraModel, StereoRig


def _barrel(points: np.ndarray) -> np.ndarray:
    """A smooth made-up rectified -> raw map (radial distortion about (80, 60))."""
    centre = np.array([80.0, 60.0])
    offset = points - centre
    r2 = (offset**2).sum(axis=1, keepdims=True) / 100.0**2
    return centre + offset * (1.0 + 0.05 * r2) + np.array([2.0, -1.5])


H = np.array([[1.01, 0.002, -3.2], [0.001, 0.998, 1.1], [1e-5, -2e-5, 1.0]])
CROP = Crop(30, 20, 90, 60)


def test_input_map_samples_the_point_map() -> None:
    grid = input_map(_barrel, CROP)
    assert grid.output_size == (90, 60) and grid.map_x.dtype == np.float32
    expected = _barrel(pixel_grid(30, 20, 90, 60))
    np.testing.assert_allclose(grid.map_x.ravel(), expected[:, 0], atol=1e-4)
    np.testing.assert_allclose(grid.map_y.ravel(), expected[:, 1], atol=1e-4)


def test_target_map_composes_homography_then_rectification() -> None:
    grid = target_map(_barrel, H, CROP, margin=4)
    assert grid.output_size == (90, 60) and grid.map_x.shape == (68, 98)
    inner = shifted(grid, 0.0, 0.0)
    expected = _barrel(apply_homography(np.linalg.inv(H), pixel_grid(30, 20, 90, 60)))
    np.testing.assert_allclose(inner.map_x.ravel(), expected[:, 0], atol=1e-4)
    np.testing.assert_allclose(inner.map_y.ravel(), expected[:, 1], atol=1e-4)


@pytest.mark.parametrize(("dx", "dy"), [(0.37, -1.62), (-2.5, 0.25), (1.0, 2.0)])
def test_shift_resamples_the_map_not_the_image(dx: float, dy: float) -> None:
    grid = shifted(target_map(_barrel, H, CROP, margin=4), dx, dy)
    points = pixel_grid(30 + dx, 20 + dy, 90, 60)
    expected = _barrel(apply_homography(np.linalg.inv(H), points))
    assert np.abs(grid.map_x.ravel() - expected[:, 0]).max() < 0.01
    assert np.abs(grid.map_y.ravel() - expected[:, 1]).max() < 0.01


def test_shift_beyond_margin_is_refused() -> None:
    with pytest.raises(ValueError, match="exceeds the map margin"):
        shifted(target_map(_barrel, H, CROP, margin=2), 1.5, 0.0)


def test_one_remap_equals_rectify_warp_crop_geometrically() -> None:
    """A point drawn in the raw image lands where the chain of three steps puts it."""
    raw = np.zeros((140, 180), dtype=np.uint16)
    rectified_point = np.array([[70.0, 45.0]])  # in rectified obstructed px
    clean_rectified = apply_homography(np.linalg.inv(H), rectified_point)
    raw_xy = _barrel(clean_rectified)[0]
    cv2.circle(raw, (round(raw_xy[0] * 16), round(raw_xy[1] * 16)), 48, 65535, -1, cv2.LINE_AA, 4)
    out = apply(raw, target_map(_barrel, H, CROP, margin=3))
    assert out.dtype == np.uint16 and out.shape == (60, 90)
    weights = out.astype(np.float64)
    ys, xs = np.mgrid[0:60, 0:90]
    centre = np.array([(xs * weights).sum(), (ys * weights).sum()]) / weights.sum()
    np.testing.assert_allclose(centre, rectified_point[0] - [30, 20], atol=0.05)


def test_apply_keeps_dtype_and_channels() -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 65535, (140, 180, 3), dtype=np.uint16)
    out = apply(image, input_map(_barrel, CROP))
    assert out.shape == (60, 90, 3) and out.dtype == np.uint16
    identity = RemapGrid(
        *np.meshgrid(np.arange(180, dtype=np.float32), np.arange(140, dtype=np.float32))
    )
    np.testing.assert_array_equal(apply(image, identity), image)


def test_inside_rejects_nan_and_border() -> None:
    points = np.array([[0.5, 5.0], [1.0, 1.0], [np.nan, 3.0], [8.0, 5.0], [9.0, 5.0]])
    assert inside(points, (10, 8)).tolist() == [False, True, False, True, False]


def test_valid_region_with_a_real_rectification() -> None:
    camera = CameraModel(
        (350.0, 350.0, 187.5, 119.5), "equidistant", (0.01, -0.003, 0.0, 0.0), (376, 240)
    )
    T = np.eye(4)
    T[0, 3] = -0.11
    rectification = StereoRectification.from_rig(StereoRig(camera, camera, T))

    def cam0(p: np.ndarray) -> np.ndarray:
        return rectification.rectified_to_raw("cam0", p).astype(np.float64)

    def cam1(p: np.ndarray) -> np.ndarray:
        return rectification.rectified_to_raw("cam1", p).astype(np.float64)

    shift = np.array([[1.0, 0.0, 150.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    valid = valid_region(cam0, cam1, shift, rectification.size, (376, 240), (376, 240))
    assert valid.shape == (240, 376)
    columns = valid.any(axis=0)
    # alpha=0: every rectified pixel is valid; the clean view moved 150 px right is not
    assert not columns[:100].any() and columns[160:].all()
    grid = input_map(cam0, Crop(0, 0, 376, 240))
    map_x, map_y = rectification.maps("cam0")
    np.testing.assert_allclose(grid.map_x, map_x, atol=1e-3)
    np.testing.assert_allclose(grid.map_y, map_y, atol=1e-3)
