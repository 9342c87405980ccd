import cv2
import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st

from lenspair.rectify.rig import CameraModel
from lenspair.simulate.camera import project, ray_map, sample_positions, undistort_maps, unproject

finite = {"allow_nan": False, "allow_infinity": False}


@st.composite
def cameras(draw: st.DrawFn, model: str) -> CameraModel:
    fx = draw(st.floats(200.0, 600.0, **finite))
    fy = fx * draw(st.floats(0.98, 1.02, **finite))
    cx = draw(st.floats(330.0, 390.0, **finite))
    cy = draw(st.floats(240.0, 300.0, **finite))
    if model == "equidistant":
        dist = tuple(draw(st.floats(-0.02, 0.02, **finite)) for _ in range(4))
    else:
        dist = (
            draw(st.floats(-0.3, 0.1, **finite)),
            draw(st.floats(-0.05, 0.1, **finite)),
            draw(st.floats(-1e-3, 1e-3, **finite)),
            draw(st.floats(-1e-3, 1e-3, **finite)),
        )
    return CameraModel((fx, fy, cx, cy), model, dist, (720, 540))  # type: ignore[arg-type]


@st.composite
def rays(draw: st.DrawFn, max_angle_deg: float) -> np.ndarray:
    theta = np.deg2rad(draw(st.floats(0.0, max_angle_deg, **finite)))
    phi = draw(st.floats(-np.pi, np.pi, **finite))
    return np.array([[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]])


@given(cameras("equidistant"), rays(85.0), st.floats(0.1, 100.0, **finite))
def test_equidistant_round_trip(camera: CameraModel, ray: np.ndarray, depth: float) -> None:
    # Only where the lens is monotonic out to this angle does a pixel have one ray.
    k1, k2, k3, k4 = camera.distortion
    t2 = np.linspace(0.0, np.arccos(ray[0, 2]), 50) ** 2
    assume(np.all(1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4))) > 0.05))
    pixel = project(camera, ray * depth)
    assert np.all(np.isfinite(pixel))
    np.testing.assert_allclose(unproject(camera, pixel), ray, atol=1e-9)


@given(cameras("radtan"), rays(38.0), st.floats(0.1, 100.0, **finite))
def test_radtan_round_trip(camera: CameraModel, ray: np.ndarray, depth: float) -> None:
    pixel = project(camera, ray * depth)
    np.testing.assert_allclose(unproject(camera, pixel), ray, atol=1e-9)


@given(cameras("equidistant") | cameras("radtan"))
def test_pixel_round_trip_and_opencv_agree(camera: CameraModel) -> None:
    pixels = sample_positions(camera.resolution, 1)[::60, ::60].reshape(-1, 2)
    rays_ = unproject(camera, pixels)
    valid = np.all(np.isfinite(rays_), axis=1)
    # Strong radtan lenses fold inside the image: those pixels have no ray (NaN).
    assert valid[len(valid) // 2]
    np.testing.assert_allclose(project(camera, rays_[valid]), pixels[valid], atol=1e-6)
    # OpenCV's models stop at 90 degrees; ours go on for fisheye lenses.
    valid &= rays_[:, 2] > 0.05
    points = rays_[valid].reshape(-1, 1, 3)
    zero = np.zeros(3)
    if camera.distortion_model == "equidistant":
        expected, _ = cv2.fisheye.projectPoints(points, zero, zero, camera.K, camera.dist_coeffs)
    else:
        expected, _ = cv2.projectPoints(points, zero, zero, camera.K, camera.dist_coeffs)
    np.testing.assert_allclose(project(camera, rays_[valid]), expected.reshape(-1, 2), atol=1e-6)


def test_behind_the_camera_is_nan() -> None:
    radtan = CameraModel((300.0, 300.0, 360.0, 270.0), "radtan", (0.0,) * 4, (720, 540))
    assert np.all(np.isnan(project(radtan, np.array([[0.1, 0.0, -1.0]]))))
    fisheye = CameraModel((300.0, 300.0, 360.0, 270.0), "equidistant", (0.0,) * 4, (720, 540))
    # An equidistant lens images rays beyond 90 degrees; straight back has no image.
    assert np.all(np.isfinite(project(fisheye, np.array([[1.0, 0.0, -0.2]]))))
    assert np.all(np.isnan(project(fisheye, np.array([[0.0, 0.0, -1.0]]))))


def test_radtan_fold_has_no_ray() -> None:
    camera = CameraModel((200.0, 200.0, 360.0, 270.0), "radtan", (-0.5, 0.0, 0.0, 0.0), (720, 540))
    # Past r = 1/sqrt(3 * 0.5) the radial polynomial folds back; the image corner is past it.
    rays_ = unproject(camera, np.array([[360.0, 270.0], [719.0, 539.0]]))
    assert np.all(np.isfinite(rays_[0])) and np.all(np.isnan(rays_[1]))
    grid = ray_map(camera, 1)
    assert 0 < grid.valid.mean() < 1
    assert np.all(grid.rays[:, ~grid.valid] == 0)


def test_ray_map_layout() -> None:
    camera = CameraModel(
        (350.0, 351.0, 359.5, 269.5), "equidistant", (0.01, -0.003, 0.001, 0.0), (720, 540)
    )
    grid = ray_map(camera, 2)
    assert grid.rays.shape == (3, 1080 * 1440) and grid.rays.dtype == np.float32
    assert grid.grid_shape == (1080, 1440)
    np.testing.assert_allclose(np.linalg.norm(grid.rays, axis=0), 1.0, atol=1e-6)
    # Sample (row 2r+1, col 2c+1) sits a quarter pixel below-right of pixel (c, r)'s centre.
    index = (2 * 100 + 1) * 1440 + 2 * 200 + 1
    expected = unproject(camera, np.array([[200.25, 100.25]]))[0]
    np.testing.assert_allclose(grid.rays[:, index], expected, atol=1e-6)


def test_undistort_maps_identity_without_distortion() -> None:
    camera = CameraModel((300.0, 300.0, 100.0, 80.0), "radtan", (0.0,) * 4, (200, 160))
    map_x, map_y = undistort_maps(camera)
    xs, ys = np.meshgrid(np.arange(200), np.arange(160))
    np.testing.assert_allclose(map_x, xs, atol=1e-4)
    np.testing.assert_allclose(map_y, ys, atol=1e-4)
