"""Rotations and rigid transforms (float64, metres, degrees at the API).

Naming follows Kalibr: ``T_a_b`` is the 4x4 transform that takes a point
expressed in frame ``b`` to frame ``a`` (``X_a = T_a_b @ X_b``).
"""

import numpy as np
from numpy.typing import ArrayLike


def rotation_x(angle_rad: float) -> np.ndarray:
    """3x3 rotation about x by ``angle_rad`` (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(angle_rad: float) -> np.ndarray:
    """3x3 rotation about y by ``angle_rad`` (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(angle_rad: float) -> np.ndarray:
    """3x3 rotation about z by ``angle_rad`` (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_xyz_deg(angles_deg: ArrayLike) -> np.ndarray:
    """``Rz @ Ry @ Rx`` for ``(rx, ry, rz)`` in degrees: about x first, then y, then z."""
    rx, ry, rz = np.deg2rad(np.asarray(angles_deg, dtype=np.float64))
    return np.asarray(rotation_z(rz) @ rotation_y(ry) @ rotation_x(rx))


def axis_angle(axis: ArrayLike, angle_rad: float) -> np.ndarray:
    """3x3 rotation by ``angle_rad`` about ``axis`` (normalised here; Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.asarray(
        np.eye(3) + np.sin(angle_rad) * cross + (1.0 - np.cos(angle_rad)) * cross @ cross
    )


def make_transform(rotation: np.ndarray, translation: ArrayLike) -> np.ndarray:
    """4x4 rigid transform from a 3x3 rotation and a 3-vector translation."""
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = np.asarray(translation, dtype=np.float64)
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform (exact, no general matrix inverse)."""
    R = T[:3, :3]
    return make_transform(R.T, -R.T @ T[:3, 3])


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``T`` (4x4) to points ``(N, 3)``; returns ``(N, 3)`` float64."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.asarray(points @ T[:3, :3].T + T[:3, 3])
