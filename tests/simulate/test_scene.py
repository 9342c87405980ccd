from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.core.errors import ConfigError
from lenspair.rectify.rig import CameraModel
from lenspair.simulate.camera import project, ray_map
from lenspair.simulate.scene import Plane, build_planes, render_view
from lenspair.simulate.spec import PlaneSpec
from lenspair.simulate.textures import NAMES, build_texture, load_texture_image, mosaic
from lenspair.simulate.transforms import invert_transform, make_transform, rotation_xyz_deg

FISHEYE = CameraModel(
    (350.2, 349.8, 361.3, 268.4), "equidistant", (-0.0095, 0.0036, -0.0049, 0.0015), (720, 540)
)
RADTAN = CameraModel((420.0, 421.0, 355.0, 272.0), "radtan", (-0.2, 0.05, 4e-4, -3e-4), (720, 540))
finite = {"allow_nan": False, "allow_infinity": False}


def _plane(texture: np.ndarray, pose: np.ndarray, size_m: tuple[float, float] | None) -> Plane:
    height, width = texture.shape[:2]
    extent = size_m if size_m is not None else (1.0, 1.0)
    return Plane(
        centre=pose[:3, 3].copy(),
        axis_u=pose[:3, 0].copy(),
        axis_v=pose[:3, 1].copy(),
        size_m=size_m,
        texel_m=(extent[0] / width, extent[1] / height),
        texture=build_texture(texture.astype(np.float32), tiled=size_m is None),
    )


@pytest.mark.parametrize("camera", [FISHEYE, RADTAN], ids=["equidistant", "radtan"])
@pytest.mark.parametrize("supersample", [1, 2])
def test_a_dot_on_a_plane_renders_where_it_projects(camera: CameraModel, supersample: int) -> None:
    texture = np.zeros((256, 256), np.float32)
    ys, xs = np.mgrid[0:256, 0:256]
    dot_x, dot_y = 100.3, 150.6  # texel coordinates of the dot's centre
    texture += np.exp(-((xs - dot_x) ** 2 + (ys - dot_y) ** 2) / (2 * 1.5**2))
    size = (0.5, 0.5)
    T_world_plane = make_transform(rotation_xyz_deg((10.0, -25.0, 5.0)), (0.3, -0.1, 2.0))
    plane = _plane(texture, T_world_plane, size)
    T_world_cam = make_transform(rotation_xyz_deg((2.0, 3.0, -1.0)), (0.05, 0.02, -0.1))
    image = render_view(ray_map(camera, supersample), T_world_cam, [plane], 0.0, 1)
    # Where the dot's centre is on the plane, in the world, then in the camera.
    u = (dot_x + 0.5) * size[0] / 256 - size[0] / 2
    v = (dot_y + 0.5) * size[1] / 256 - size[1] / 2
    point = plane.centre + u * plane.axis_u + v * plane.axis_v
    in_camera = invert_transform(T_world_cam) @ np.append(point, 1.0)
    expected = project(camera, in_camera[None, :3])[0]
    rows, cols = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
    window = (np.abs(cols - expected[0]) < 12) & (np.abs(rows - expected[1]) < 12)
    weights = np.where(window, image, 0.0)
    assert weights.sum() > 0.5
    centroid = np.array([(weights * cols).sum(), (weights * rows).sum()]) / weights.sum()
    assert np.linalg.norm(centroid - expected) < 0.1


def test_nearest_positive_hit_wins_and_misses_see_background() -> None:
    far = _plane(np.full((64, 64), 0.2), make_transform(np.eye(3), (0, 0, 50.0)), None)
    near = _plane(np.full((64, 64), 0.8), make_transform(np.eye(3), (0, 0, 2.0)), (0.4, 0.4))
    # A plane behind the camera must never show.
    behind = _plane(np.full((64, 64), 0.5), make_transform(np.eye(3), (0, 0, -1.0)), None)
    grid = ray_map(FISHEYE, 1)
    image = render_view(grid, np.eye(4), [far, behind, near], 0.05, 1)
    cx, cy = FISHEYE.intrinsics[2:]
    assert image[int(cy), int(cx)] == pytest.approx(0.8, abs=1e-5)
    assert image[20, 20] == pytest.approx(0.2, abs=1e-5)
    # Looking away from the far plane only the background is left.
    turned = make_transform(rotation_xyz_deg((0.0, 180.0, 0.0)), (0.0, 0.0, 0.0))
    assert np.all(render_view(grid, turned, [far, near], 0.05, 1) == np.float32(0.05))


@settings(max_examples=15)
@given(
    st.tuples(*[st.floats(-50.0, 50.0, **finite)] * 3),
    st.floats(0.5, 200.0, **finite),
    st.floats(0.0, 1.0, **finite),
)
def test_constant_texture_stays_constant_at_every_level(
    angles: tuple[float, float, float], depth: float, value: float
) -> None:
    # Mip levels, wrap-around and trilinear blending must not change a flat texture.
    plane = _plane(np.full((128, 128), value), make_transform(np.eye(3), (0, 0, depth)), None)
    camera = CameraModel((60.0, 60.0, 39.5, 29.5), "equidistant", (0.0,) * 4, (80, 60))
    pose = make_transform(rotation_xyz_deg(angles), (0.0, 0.0, 0.0))
    image = render_view(ray_map(camera, 1), pose, [plane], -1.0, 1)
    hit = image != np.float32(-1.0)
    assert hit.any()
    np.testing.assert_allclose(image[hit], value, atol=1e-5)


def test_tiled_pyramid_levels_are_periodic() -> None:
    rng = np.random.default_rng(0)
    tile = rng.random((128, 192)).astype(np.float32)
    tiled = build_texture(tile, tiled=True)
    big = build_texture(np.tile(tile, (3, 3)), tiled=False)
    for level in range(1, 4):
        h, w = tiled.levels[level].shape
        # The middle copy of the 3x3 tiling is unaffected by its outer border.
        middle = big.levels[level][h : 2 * h, w : 2 * w]
        np.testing.assert_allclose(tiled.levels[level], middle, atol=1e-5)


def test_rgb_render_and_mosaic(tmp_path: Path) -> None:
    specs = [PlaneSpec(texture=("astronaut", "brick", "coffee"), depth_m=40.0, tile_m=(60, 60))]
    planes = build_planes(specs, tmp_path, 3)
    assert planes[0].texture.levels[0].shape == (1024, 1024, 3)  # 2x2 grid of 512 tiles
    camera = CameraModel((100.0, 100.0, 79.5, 59.5), "radtan", (0.0,) * 4, (160, 120))
    image = render_view(ray_map(camera, 1), np.eye(4), planes, 0.0, 3)
    assert image.shape == (120, 160, 3) and image.dtype == np.float32
    assert image.min() >= 0.0 and image.max() <= 1.0 and image.std() > 0.02
    grey = mosaic([np.zeros((4, 4), np.float32)] * 3, (8, 8))
    assert grey.shape == (16, 16)


def test_textures_are_offline_and_linear(tmp_path: Path) -> None:
    for name in NAMES:
        image = load_texture_image(name, tmp_path)
        assert image.dtype == np.float32 and 0.0 <= image.min() <= image.max() <= 1.0
    with pytest.raises(ConfigError, match="unknown texture 'nope'"):
        load_texture_image("nope", tmp_path)
