"""Ground-truth geometry of a simulated recording: ``truth/geometry.json``.

Homography convention (``homography`` keys). ``H`` maps pixel coordinates of
the CLEAN camera's *undistorted pinhole image* (its own ``K``, no distortion,
pixel centres at integers) to the OBSTRUCTED camera's undistorted pinhole
image (its own ``K``), for points on the far plane::

    [u_o, v_o, 1]^T ~ H [u_c, v_c, 1]^T,
    H = K_o (R_oc + t_oc n_c^T / d_c) K_c^-1,   normalised so that H[2][2] = 1,

where ``(R_oc, t_oc)`` takes clean-camera coordinates to obstructed-camera
coordinates (at the two cameras' actual timestamps of that frame) and the
far plane is ``n_c . X = d_c`` in the clean camera's frame. To compare with
raw images, undistort both with their own models first (e.g.
``lenspair.simulate.camera.undistort_maps``). The top-level ``homography`` is frame 0;
``frames[k].homography`` is frame ``k``. When the rig translates parallel to
the far plane (``motion.velocity_mps[2] == 0``, as in the samples), the
plane's distance from the body origin (cam0) is the same in every frame and
``H`` is constant without wobble and jitter. A yaw/pitch/roll wobble turns ``n_c`` and
moves cam1 by ``B sin(angle)`` (under a millimetre) along the view
direction, so ``H`` drifts slightly from frame to frame (under 0.03 px in
the samples); the per-frame value is exact. (The f*B/Z parallax of the far
plane itself is part of ``H``.)

Schema (all lengths metres, transforms 4x4 row-major lists, ``T_a_b`` maps
frame ``b`` to frame ``a``; world = body at frame 0; body = cam0)::

    format: "lenspair-simulate-truth/1"
    convention: the paragraph above, as text
    clean, obstructed: "cam0" | "cam1"
    K_clean, K_obstructed: 3x3
    homography: 3x3 | null          # frame 0, null without planes
    baseline_m, T_cam1_cam0, T_body_cam0, T_body_cam1
    far_plane: {index, name, depth_m, normal_world, offset_m} | null
    planes: [{index, name, texture, depth_m, centre_world, normal_world,
              offset_m, size_m | null}]   # normal . X = offset in world;
                                          # texture: [sample names or absolute file paths]
    board: null | {kind, cols, rows, square_m, marker_m, dictionary,
                   object_points: [[x, y, 0], ...], ids: [...]}
    frames: [{index, t_nominal_ns, T_world_body (at t_nominal), homography,
              far_plane_clean: {normal, distance_m} | null,
              T_world_board | null,
              cam0: {t_ns, dropped, T_world_cam, board_corners_px | null},
              cam1: {...}}]

``board_corners_px`` are the true (distorted) pixel positions of the board's
inner corners in that camera, in ``object_points`` order.
"""

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from lenspair.simulate.scene import Plane
from lenspair.simulate.spec import MIN_DEPTH_M
from lenspair.simulate.transforms import invert_transform

FORMAT = "lenspair-simulate-truth/1"
CONVENTION = (
    "H maps pixel coordinates of the clean camera's undistorted pinhole image (its own K) "
    "to the obstructed camera's undistorted pinhole image (its own K) for points on the far "
    "plane: [u_o, v_o, 1] ~ H [u_c, v_c, 1], H = K_o (R_oc + t_oc n_c^T / d_c) K_c^-1, "
    "H[2][2] = 1, with (R_oc, t_oc) taking clean-camera to obstructed-camera coordinates at "
    "the frame's actual timestamps and n_c . X = d_c the far plane in the clean camera frame. "
    "Pixel centres at integer coordinates."
)


def plane_in_camera(plane: Plane, T_world_cam: np.ndarray) -> tuple[np.ndarray, float]:
    """The plane as ``n . X = d`` in a camera's frame: ``(n (3,), d metres)``."""
    normal = T_world_cam[:3, :3].T @ plane.normal
    distance = plane.offset_m - float(plane.normal @ T_world_cam[:3, 3])
    return normal, distance


def plane_reached(
    planes: Sequence[Plane], far_index: int | None, camera_poses: Iterable[tuple[int, np.ndarray]]
) -> str | None:
    """Where the rig comes nearer than the least plane depth to a plane it cannot pass, or None.

    A camera that reaches an endless plane drives through a wall; one that
    reaches the far plane makes its homography (the registration's truth)
    divide by zero or less, and the frames behind it are background. A
    finite plane other than the far one can be passed beside. The distance
    is :data:`~lenspair.simulate.spec.MIN_DEPTH_M`, ``depth_m``'s least.

    Args:
        planes: the scene's planes.
        far_index: the far plane's index (its homography is the truth).
        camera_poses: ``(frame index, 4x4 camera pose)`` of every camera at every frame.

    Returns:
        ``planes[i]: ...`` naming the first frame and the distance, or None.
    """
    watched = [i for i, p in enumerate(planes) if p.size_m is None or i == far_index]
    for frame, pose in camera_poses:
        for index in watched:
            _, distance = plane_in_camera(planes[index], pose)
            if distance < MIN_DEPTH_M - 1e-9:  # not refused for a rounding
                return (
                    f"planes[{index}]: at frame {frame} a camera is {distance:.3f} m in front "
                    f"of it, less than the {MIN_DEPTH_M} m it must stay (the rig "
                    "reaches or crosses it): shorten the motion or move the plane"
                )
    return None


def plane_homography(
    K_source: np.ndarray,
    K_target: np.ndarray,
    T_target_source: np.ndarray,
    normal_source: np.ndarray,
    distance_source: float,
) -> np.ndarray:
    """Homography induced by a plane between two pinhole images.

    Args:
        K_source: 3x3 camera matrix of the source image.
        K_target: 3x3 camera matrix of the target image.
        T_target_source: 4x4 transform from source-camera to target-camera frame.
        normal_source: ``(3,)`` plane normal in the source frame.
        distance_source: ``d`` of ``n . X = d`` in the source frame, metres.

    Returns:
        3x3 float64 ``H`` with ``H[2, 2] = 1``, source pixels -> target pixels.

    """
    R = T_target_source[:3, :3]
    t = T_target_source[:3, 3]
    H = K_target @ (R + np.outer(t, normal_source) / distance_source) @ np.linalg.inv(K_source)
    return np.asarray(H / H[2, 2])


def far_plane_homography(
    plane: Plane,
    K_clean: np.ndarray,
    K_obstructed: np.ndarray,
    T_world_clean: np.ndarray,
    T_world_obstructed: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(H, n_c, d_c)`` of the far plane for one frame (see the module docstring)."""
    normal, distance = plane_in_camera(plane, T_world_clean)
    T_obstructed_clean = invert_transform(T_world_obstructed) @ T_world_clean
    H = plane_homography(K_clean, K_obstructed, T_obstructed_clean, normal, distance)
    return H, normal, distance


def matrix(value: np.ndarray) -> list[list[float]]:
    """A matrix as nested lists of Python floats (stable JSON)."""
    return [[float(v) for v in row] for row in np.asarray(value, dtype=np.float64)]


def vector(value: np.ndarray) -> list[float]:
    """A vector as a list of Python floats."""
    return [float(v) for v in np.asarray(value, dtype=np.float64).ravel()]


def plane_record(
    index: int, plane: Plane, name: str, texture: Any, depth_m: float
) -> dict[str, Any]:
    """The ``planes[i]`` entry of ``geometry.json``."""
    return {
        "index": index,
        "name": name,
        "texture": texture,
        "depth_m": float(depth_m),
        "centre_world": vector(plane.centre),
        "normal_world": vector(plane.normal),
        "offset_m": plane.offset_m,
        "size_m": None if plane.size_m is None else [float(v) for v in plane.size_m],
    }
