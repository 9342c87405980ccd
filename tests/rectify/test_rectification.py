import dataclasses

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from lenspair.rectify.errors import RectifyError
from lenspair.rectify.projection import pixel_rays, project_rays
from lenspair.rectify.rectification import (
    StereoRectification,
    row_differences,
    row_disagreement,
)
from lenspair.rectify.rig import CameraModel, DistortionModel, StereoRig
from tests.rectify.rigs import make_rig

PINHOLE = CameraModel((350.0, 350.0, 359.5, 269.5), "radtan", (0.0, 0.0, 0.0, 0.0), (720, 540))


def mounted(
    cam0: CameraModel, cam1: CameraModel, rotation_deg: tuple[float, float, float], centre: tuple
) -> StereoRig:
    """A rig whose cam1 is turned by ``rotation_deg`` (x, y, z; z = roll) with its centre at
    ``centre`` (metres, cam0's frame)."""
    R = cv2.Rodrigues(np.radians(rotation_deg))[0]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.asarray(centre, dtype=np.float64)
    return StereoRig(cam0, cam1, T)


def visible_points(rig: StereoRig, count: int = 400) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3-D points (cam0 frame) seen by both cameras, and their raw pixels."""
    rng = np.random.default_rng(0)
    points = rng.uniform([-2.0, -1.5, 1.5], [2.0, 1.5, 8.0], (count, 3))
    p0 = project_rays(rig.cam0, points)
    p1 = project_rays(rig.cam1, points @ rig.R.T + rig.t)
    inside = np.ones(count, bool)
    for p in (p0, p1):
        inside &= np.all(np.isfinite(p), axis=1)
        inside &= (p[:, 0] > 0) & (p[:, 0] < 719) & (p[:, 1] > 0) & (p[:, 1] < 539)
    assert inside.sum() > 100
    return points[inside], p0[inside], p1[inside]


@pytest.mark.parametrize("model", ["radtan", "equidistant"])
@pytest.mark.parametrize("rotated", [False, True])
def test_rectified_rows_agree_and_disparity_is_positive(
    model: DistortionModel, rotated: bool
) -> None:
    rig = make_rig(model, rotated)
    rectification = StereoRectification.from_rig(rig)
    assert rectification.cam1_quarter_turns == (2 if rotated else 0)
    points, p0, p1 = visible_points(rig)
    assert row_disagreement(rectification, p0, p1) < 1e-6
    r0 = rectification.raw_to_rectified("cam0", p0)
    r1 = rectification.raw_to_rectified("cam1", p1)
    f, baseline = rectification.K[0, 0], rectification.baseline_m
    depth = (points @ rectification.rotation("cam0").T)[:, 2]  # Z in the rectified frame
    # upright, not mirrored: cam1 on the right sees points shifted left by f B / Z
    np.testing.assert_allclose(r0[:, 0] - r1[:, 0], f * baseline / depth, rtol=1e-6)
    assert baseline == pytest.approx(rig.baseline_m, rel=1e-3)


def test_unrectified_rows_disagree() -> None:
    """The metric is not trivially zero: identity rotations leave rows apart."""
    rig = make_rig("radtan", rotated=True)
    rectification = StereoRectification.from_rig(rig)
    _, p0, p1 = visible_points(rig)
    skewed = StereoRectification(
        rig, np.stack([np.eye(3), np.eye(3)]), rectification.K, rectification.size, 0.11, 0, 0.0
    )
    assert row_disagreement(skewed, p0, p1) > 50
    assert np.abs(row_differences(rectification, p0, p1)).max() < 1e-6


@pytest.mark.parametrize("model", ["radtan", "equidistant"])
def test_maps_match_opencv(model: DistortionModel) -> None:
    rig = make_rig(model)
    rectification = StereoRectification.from_rig(rig)
    camera = rig.cam1
    init = cv2.initUndistortRectifyMap if model == "radtan" else cv2.fisheye.initUndistortRectifyMap
    expected_x, expected_y = init(
        camera.K,
        camera.dist_coeffs,
        rectification.rotation("cam1"),
        rectification.projection("cam1"),
        rectification.size,
        cv2.CV_32FC1,
    )
    map_x, map_y = rectification.maps("cam1")
    assert map_x.dtype == np.float32 and map_x.shape == (540, 720)
    np.testing.assert_allclose(map_x, expected_x, atol=2e-3)
    np.testing.assert_allclose(map_y, expected_y, atol=2e-3)


def test_rectified_to_raw_takes_any_shape_and_inverts_raw_to_rectified() -> None:
    rectification = StereoRectification.from_rig(make_rig("equidistant", rotated=True))
    grid = np.stack(np.meshgrid(np.linspace(50, 650, 7), np.linspace(40, 500, 5)), axis=-1)
    raw = rectification.rectified_to_raw("cam1", grid.astype(np.float32))
    assert raw.shape == (5, 7, 2) and raw.dtype == np.float32
    assert rectification.raw_coordinates("cam1", grid).shape == (5, 7, 2)
    back = rectification.raw_to_rectified("cam1", raw)
    np.testing.assert_allclose(back, grid, atol=1e-3)


def test_every_per_view_accessor_refuses_an_unknown_view() -> None:
    # a typo must not quietly get cam0's geometry
    rectification = StereoRectification.from_rig(make_rig("equidistant", rotated=True))
    accessors = (
        rectification.rotation,
        rectification.projection,
        lambda view: rectification.rectified_to_raw(view, np.zeros((1, 2))),
    )
    for accessor in accessors:
        with pytest.raises(ValueError, match="'cam2'"):
            accessor("cam2")  # type: ignore[arg-type]


def test_alpha_zero_keeps_every_pixel_valid_and_alpha_one_keeps_every_raw_pixel() -> None:
    rig = make_rig("equidistant", rotated=True)
    tight = StereoRectification.from_rig(rig, alpha=0.0)
    assert tight.valid_region("cam0").all() and tight.valid_region("cam1").all()
    loose = StereoRectification.from_rig(rig, alpha=1.0)
    valid = loose.valid_region("cam1")
    assert 0.3 < valid.mean() < 1.0
    assert loose.K[0, 0] < tight.K[0, 0]
    # the raw image corners land inside the loose rectified image
    corners = np.array([[0.0, 0.0], [719.0, 0.0], [0.0, 539.0], [719.0, 539.0]])
    rectified = loose.raw_to_rectified("cam1", corners)
    assert np.all((rectified >= -1) & (rectified <= [720, 540]))


def test_rectify_resamples_a_raw_image() -> None:
    rig = make_rig("radtan")
    rectification = StereoRectification.from_rig(rig)
    image = np.full((540, 720), 200, np.uint8)
    out = rectification.rectify("cam0", image)
    assert out.shape == (540, 720) and out.dtype == np.uint8 and (out == 200).all()


def test_points_behind_the_camera_have_no_raw_source() -> None:
    camera = make_rig("equidistant").cam0
    pixels = project_rays(camera, np.array([[0.0, 0.0, -1.0], [0.1, 0.0, 1.0]]))
    assert np.isnan(pixels[0]).all() and np.isfinite(pixels[1]).all()
    rays = pixel_rays(camera, pixels[1:])
    np.testing.assert_allclose(rays, [[0.1, 0.0, 1.0]], atol=1e-9)


def test_vertical_rig_is_refused() -> None:
    rig = make_rig("radtan")
    T = np.eye(4)
    T[:3, 3] = [0.0, -0.1, 0.0]
    with pytest.raises(RectifyError, match="mostly vertical"):
        StereoRectification.from_rig(StereoRig(rig.cam0, rig.cam1, T))


def test_edges_without_rays_are_named() -> None:
    # Radial distortion 1 - 0.2 r^2 reaches its largest radius, about 300 px, before
    # the left and right edges (358 px and more from the centre) but after the top and
    # bottom ones (270 px): those two edges, and only they, have no ray; cam1 is named.
    rig = make_rig("radtan")
    cam1 = CameraModel((352.0, 352.5, 358.0, 271.0), "radtan", (-0.2, 0.0, 0.0, 0.0), (720, 540))
    with pytest.raises(RectifyError) as refused:
        StereoRectification.from_rig(StereoRig(rig.cam0, cam1, rig.T_cam1_cam0))
    message = str(refused.value)
    assert "cam1's left and right edges has" in message and "cam0" not in message
    assert "near the image edges" in message
    # the same camera as cam0 is named cam0
    with pytest.raises(RectifyError, match="cam0's left and right edges"):
        StereoRectification.from_rig(StereoRig(cam1, rig.cam1, rig.T_cam1_cam0))


def test_bad_alpha_is_refused() -> None:
    with pytest.raises(RectifyError, match="alpha"):
        StereoRectification.from_rig(make_rig("radtan"), alpha=1.5)


@settings(max_examples=25, deadline=None)
@given(
    direction_deg=st.floats(0.0, 90.0),
    roll_deg=st.floats(-20.0, 20.0),
)
@example(direction_deg=float(np.degrees(np.arctan2(0.095, 0.100))), roll_deg=8.0)
def test_a_rig_is_rectified_with_rows_that_agree_or_refused_as_top_bottom(
    direction_deg: float, roll_deg: float
) -> None:
    # near 45 deg, a rig side by side by cam1's centre was rectified top/bottom by
    # cv2.stereoRectify (which judges after half the roll): rows 50 px apart, no error
    angle = np.radians(direction_deg)
    rig = mounted(
        PINHOLE, PINHOLE, (0.0, 0.0, roll_deg), (0.138 * np.cos(angle), 0.138 * np.sin(angle), 0.0)
    )
    try:
        rectification = StereoRectification.from_rig(rig)
    except RectifyError as refused:
        assert "mostly vertical (a top/bottom rig" in str(refused)
        assert direction_deg > 45.0 - abs(roll_deg) / 2 - 1e-6
        return
    assert direction_deg < 45.0 + abs(roll_deg) / 2 + 1e-6
    _, p0, p1 = visible_points(rig)
    assert row_disagreement(rectification, p0, p1) < 1e-6
    assert abs(rectification.baseline_m) == pytest.approx(rig.baseline_m, rel=1e-9)


def test_a_baseline_along_the_optical_axis_is_named() -> None:
    # it was refused for "no pixel on cam0's right edge has a valid ray", blaming
    # the calibration's coverage of the image for a rig no calibration can rectify
    side = make_rig("radtan")
    rig = mounted(side.cam0, side.cam1, (0.0, 0.0, 0.0), (0.05, 0.0, 0.10))
    with pytest.raises(RectifyError) as refused:
        StereoRectification.from_rig(rig)
    message = str(refused.value)
    assert "the baseline [0.05, 0.0, 0.1] m runs mostly along the optical axis" in message
    assert "valid ray" not in message and "\n" not in message


def least_zoom_is_tight(rectification: StereoRectification) -> None:
    """Every rectified pixel of both views is valid, and 1 % less zoom about the same
    centre leaves some pixel without a source (alpha = 0 zooms no more than needed)."""
    for view in ("cam0", "cam1"):
        assert rectification.valid_region(view).all()
    K = rectification.K.copy()
    middle = (np.array(rectification.size) - 1) / 2
    centre = (middle - K[:2, 2]) / K[0, 0]
    K[0, 0] = K[1, 1] = 0.99 * K[0, 0]
    K[:2, 2] = middle - K[0, 0] * centre
    wider = dataclasses.replace(rectification, K=K)
    assert not all(wider.valid_region(view).all() for view in ("cam0", "cam1"))


@pytest.mark.parametrize(("roll_deg", "enough"), [(10, 426), (20, 489), (30, 537), (40, 569)])
def test_alpha_zero_zooms_no_more_than_a_roll_needs(roll_deg: float, enough: float) -> None:
    # ``enough``: a search over f and the principal point found every pixel valid at
    # this f; the bounding boxes of each raw edge zoomed to 466, 725, 1762, 3836 px
    rig = mounted(PINHOLE, PINHOLE, (0.0, 0.0, roll_deg), (0.11, 0.0, 0.0))
    rectification = StereoRectification.from_rig(rig)
    assert rectification.K[0, 0] <= enough
    least_zoom_is_tight(rectification)


@settings(max_examples=12, deadline=None)
@given(
    model=st.sampled_from(["radtan", "equidistant"]),
    rotation_deg=st.tuples(st.floats(-8.0, 8.0), st.floats(-10.0, 10.0), st.floats(-40.0, 40.0)),
)
@example(model="radtan", rotation_deg=(0.0, 10.0, 40.0))  # refused: "no common valid region"
def test_alpha_zero_keeps_every_pixel_valid_with_the_least_zoom(
    model: DistortionModel, rotation_deg: tuple[float, float, float]
) -> None:
    side = make_rig(model)
    rig = mounted(side.cam0, side.cam1, rotation_deg, (0.11, 0.0, 0.0))
    least_zoom_is_tight(StereoRectification.from_rig(rig))


def test_an_ideal_rig_is_rectified_to_its_own_pixels() -> None:
    # distortion-free, parallel cameras: alpha = 0 needs no zoom at all, every rectified
    # pixel centre lands on a raw one (a search window with no empty border around it
    # once put the centre at the image's edge and zoomed twice over)
    T = np.eye(4)
    T[0, 3] = -0.11
    rectification = StereoRectification.from_rig(StereoRig(PINHOLE, PINHOLE, T))
    np.testing.assert_allclose(rectification.K, PINHOLE.K, atol=0.05)
    least_zoom_is_tight(rectification)
