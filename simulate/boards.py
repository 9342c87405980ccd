"""Calibration boards in a scene: textures, corner coordinates and poses seen by both cameras.

The board model (geometry, printed image) is shared with ``lenspair calibrate``:
:class:`lenspair.rectify.boards.Board`, reached through ``BoardSpec.target``.

Board frame (metres): origin at the outer top-left corner of the square
grid, x along the rows of squares (``cols`` direction), y down the columns,
z = x cross y, pointing away from a viewer who sees the board the right way
round. This is OpenCV's ChArUco convention (``CharucoBoard.getChessboardCorners``)
and the usual chessboard one.

* ``chessboard``: ``cols x rows`` *inner* corners, so ``(cols + 1) x (rows + 1)``
  squares, the top-left square black. Inner corner ``(i, j)`` (row ``i``,
  column ``j``) is at ``((j + 1) s, (i + 1) s, 0)``.
* ``charuco``: ``cols x rows`` *squares* (``cv2.aruco.CharucoBoard``); its
  ``(cols - 1) x (rows - 1)`` inner corners have OpenCV's ids, row-major.

Both are printed with a white border one square wide (the quiet zone that
detectors need). Reflectances in linear light: black 0.03, white 0.80.
"""

import numpy as np

from lenspair.rectify.rig import CameraModel
from lenspair.simulate.boardspec import BoardSpec
from lenspair.simulate.camera import project, unproject
from lenspair.simulate.errors import SimulateError
from lenspair.simulate.scene import Plane
from lenspair.simulate.textures import Texture, build_texture
from lenspair.simulate.transforms import (
    axis_angle,
    invert_transform,
    make_transform,
    transform_points,
)

BLACK = 0.03
WHITE = 0.80
_MAX_ATTEMPTS = 4000
_MAX_VIEW_ANGLE_DEG = 65.0
_SPIN_DEG = 15.0


def object_points(board: BoardSpec) -> np.ndarray:
    """Inner corners in the board frame, ``(N, 3)`` float64, row-major (ids 0..N-1)."""
    return board.target.object_points(grid_origin=True)


def board_texture(board: BoardSpec, channels: int) -> Texture:
    """Linear-light mip pyramid of the printed board (not tiled)."""
    printed = board.target.printed_image(board.pixels_per_square)
    reflectance = BLACK + (WHITE - BLACK) * (printed.astype(np.float32) / 255.0)
    if channels == 3:
        reflectance = np.repeat(reflectance[:, :, None], 3, axis=2)
    return build_texture(reflectance.astype(np.float32), tiled=False)


def board_outline(board: BoardSpec, per_edge: int = 8) -> np.ndarray:
    """Points along the outer edge of the printed board (border included), ``(M, 3)``."""
    width, height = board.target.grid_size_m
    border = board.square_m
    x0, y0, x1, y1 = -border, -border, width + border, height + border
    steps = np.linspace(0.0, 1.0, per_edge, endpoint=False)
    edges = [
        np.stack([x0 + (x1 - x0) * steps, np.full_like(steps, y0)], axis=1),
        np.stack([np.full_like(steps, x1), y0 + (y1 - y0) * steps], axis=1),
        np.stack([x1 - (x1 - x0) * steps, np.full_like(steps, y1)], axis=1),
        np.stack([np.full_like(steps, x0), y1 - (y1 - y0) * steps], axis=1),
    ]
    outline = np.concatenate(edges, axis=0)
    return np.concatenate([outline, np.zeros((outline.shape[0], 1))], axis=1)


def board_plane(board: BoardSpec, texture: Texture, T_world_board: np.ndarray) -> Plane:
    """The printed board as a finite :class:`Plane` at pose ``T_world_board``."""
    width, height = board.target.grid_size_m
    texel = board.square_m / board.pixels_per_square
    texture_width, texture_height = texture.size
    centre = transform_points(T_world_board, np.array([[width / 2, height / 2, 0.0]]))[0]
    return Plane(
        centre=centre,
        axis_u=T_world_board[:3, 0].copy(),
        axis_v=T_world_board[:3, 1].copy(),
        size_m=(texture_width * texel, texture_height * texel),
        texel_m=(texel, texel),
        texture=texture,
    )


def _fits(
    board: BoardSpec,
    T_body_board: np.ndarray,
    cameras: tuple[CameraModel, CameraModel],
    T_body_cams: tuple[np.ndarray, np.ndarray],
    outline: np.ndarray,
) -> bool:
    corners = object_points(board)
    normal_body = T_body_board[:3, 2]
    for camera, T_body_cam in zip(cameras, T_body_cams, strict=True):
        T_cam_board = invert_transform(T_body_cam) @ T_body_board
        points = transform_points(T_cam_board, np.concatenate([outline, corners], axis=0))
        if np.any(points[:, 2] <= 0.05):
            return False
        centre = points.mean(axis=0)
        normal = invert_transform(T_body_cam)[:3, :3] @ normal_body
        cosine = float(normal @ centre) / float(np.linalg.norm(centre))
        if cosine < np.cos(np.deg2rad(_MAX_VIEW_ANGLE_DEG)):
            return False
        pixels = project(camera, points)
        width, height = camera.resolution
        margin = board.margin_px
        inside = (
            np.isfinite(pixels).all(axis=1)
            & (pixels[:, 0] >= margin - 0.5)
            & (pixels[:, 0] <= width - 0.5 - margin)
            & (pixels[:, 1] >= margin - 0.5)
            & (pixels[:, 1] <= height - 0.5 - margin)
        )
        if not inside.all():
            return False
    return True


def sample_board_poses(
    board: BoardSpec,
    cameras: tuple[CameraModel, CameraModel],
    T_body_cams: tuple[np.ndarray, np.ndarray],
    count: int,
    rng: np.random.Generator,
) -> list[np.ndarray]:
    """Draw ``count`` board poses ``T_body_board`` that both cameras see whole.

    Targets cycle through the cells of a ``board.grid`` over cam0's image
    (each cycle in a random order) so that the views cover the whole image,
    corners included; within a cell the target pixel, the distance, the
    tilt (about a random in-plane axis, up to ``max_tilt_deg``) and a small
    in-plane spin are uniform. A draw is kept when the whole printed board
    is ``margin_px`` inside both images and seen at less than 65 deg.

    Raises:
        SimulateError: no pose fits for some view (board too large for the
            distances, or margins too tight).

    """
    columns, rows = board.grid
    width, height = cameras[0].resolution
    outline = board_outline(board)
    grid_width, grid_height = board.target.grid_size_m
    local_centre = np.array([grid_width / 2, grid_height / 2, 0.0])
    cam0_from_body = invert_transform(T_body_cams[0])
    poses: list[np.ndarray] = []
    order: list[int] = []
    for _ in range(count):
        if not order:
            order = [int(i) for i in rng.permutation(columns * rows)]
        cell = order.pop(0)
        cell_x, cell_y = cell % columns, cell // columns
        for _attempt in range(_MAX_ATTEMPTS):
            target = np.array(
                [
                    (cell_x + rng.uniform()) / columns * width - 0.5,
                    (cell_y + rng.uniform()) / rows * height - 0.5,
                ]
            )
            distance = rng.uniform(*board.distance_m)
            tilt_axis_angle = rng.uniform(0.0, 2 * np.pi)
            tilt = np.deg2rad(rng.uniform(0.0, board.max_tilt_deg))
            spin = np.deg2rad(rng.uniform(-_SPIN_DEG, _SPIN_DEG))
            ray = unproject(cameras[0], target[None, :])[0]
            if not np.all(np.isfinite(ray)):
                continue
            # Face the camera along the viewing ray, then tilt and spin.
            z_axis = ray
            x_axis = np.array([1.0, 0.0, 0.0]) - ray[0] * ray
            x_axis /= np.linalg.norm(x_axis)
            facing = np.stack([x_axis, np.cross(z_axis, x_axis), z_axis], axis=1)
            in_plane = facing[:, 0] * np.cos(tilt_axis_angle) + facing[:, 1] * np.sin(
                tilt_axis_angle
            )
            R_cam0_board = axis_angle(in_plane, tilt) @ facing @ axis_angle([0, 0, 1], spin)
            centre_cam0 = distance * ray
            T_cam0_board = make_transform(R_cam0_board, centre_cam0 - R_cam0_board @ local_centre)
            T_body_board = invert_transform(cam0_from_body) @ T_cam0_board
            if _fits(board, T_body_board, cameras, T_body_cams, outline):
                poses.append(T_body_board)
                break
        else:
            raise SimulateError(
                f"board: no pose of the {board.cols}x{board.rows} board fits both images "
                f"in cell {cell} of the {columns}x{rows} grid; use a smaller board, larger "
                "distance_m or smaller margin_px"
            )
    return poses
