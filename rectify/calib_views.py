"""Board views in a calibration: board poses, reprojection errors, cam0/cam1 corner matching.

A view is one exposure of the board; :data:`Points` is its corners seen by
both cameras. :func:`board_pose` and :func:`refit_poses` place the board for a
fixed camera, :func:`view_error` and :func:`stereo_residuals` measure how well
a fit reprojects a view, and :func:`match_views` pairs each view's cam0 and
cam1 corners, choosing cam1's numbering to agree with the rig.
"""

import cv2
import numpy as np

from lenspair.rectify.boards import Board
from lenspair.rectify.corner_detection import Detection
from lenspair.rectify.projection import pixel_rays, project_rays
from lenspair.rectify.rig import CameraModel

MIN_COMMON = 6
"""Corners both cameras must share for a view to count in the stereo step."""
Points = tuple[np.ndarray, np.ndarray, np.ndarray]
"""One stereo view: object points ``(N, 3)``, cam0 and cam1 pixels ``(N, 2)``, float64."""


def rms(residuals: np.ndarray) -> float:
    """RMS of the Euclidean norms of ``(..., 2)`` residuals, pixels."""
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=-1))))


def refit_poses(
    camera: CameraModel, points: list[tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each view's board pose for a fixed camera, and its RMS error: ``rvecs, tvecs, errors``."""
    poses = [board_pose(camera, obj, img) for obj, img in points]
    rvecs = np.array([cv2.Rodrigues(pose[:3, :3])[0].ravel() for pose in poses])
    tvecs = np.array([pose[:3, 3] for pose in poses])
    errors = np.array(
        [view_error(camera, obj, img, rvecs[k], tvecs[k]) for k, (obj, img) in enumerate(points)]
    )
    return rvecs, tvecs, errors


def view_error(
    camera: CameraModel, obj: np.ndarray, img: np.ndarray, rvec: np.ndarray, tvec: np.ndarray
) -> float:
    """RMS reprojection error of one view at pose ``(rvec, tvec)``, pixels."""
    rotation = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))[0]
    projected = project_rays(camera, obj @ rotation.T + np.asarray(tvec).reshape(3))
    return rms(np.nan_to_num(projected - img, nan=1e6))


def board_pose(camera: CameraModel, obj: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """4x4 board -> camera transform from one view (PnP on undistorted rays)."""
    rays = np.ascontiguousarray(pixel_rays(camera, corners)[:, :2])
    _, rvec, tvec = cv2.solvePnP(obj, rays, np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = np.asarray(tvec).ravel()
    return pose


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between the rotation parts of ``a`` and ``b``, degrees."""
    cosine = (np.trace(a[:3, :3] @ b[:3, :3].T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def match_views(
    pairs: dict[int, tuple[Detection, Detection]],
    board: Board,
    cameras: tuple[CameraModel, CameraModel],
    tolerance_deg: float,
) -> tuple[dict[int, Points], dict[int, str]]:
    """Corner correspondences per view, with cam1's numbering chosen to agree with the rig.

    Each view gives one candidate cam0 -> cam1 transform per board symmetry
    (board pose in cam1 times the inverse pose in cam0); the true transform is
    the one most views agree on, and each view keeps its candidate closest to it.

    Args:
        pairs: view index -> (cam0, cam1) detections.
        board: the board (object points, symmetries).
        cameras: calibrated cam0 and cam1.
        tolerance_deg: a view whose best candidate rotation is further than
            this from the consensus is refused.

    Returns:
        ``(matched, refused)``: view -> matched points, and view -> reason.

    """
    objects = board.object_points()
    candidates: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for view, (d0, d1) in pairs.items():
        pose0 = board_pose(cameras[0], objects[d0.ids], d0.corners)
        candidates[view] = []
        for perm in board.symmetries():
            ids1 = perm[d1.ids]
            pose1 = board_pose(cameras[1], objects[ids1], d1.corners)
            candidates[view].append((ids1, pose1 @ np.linalg.inv(pose0)))
    everything = [relative for cands in candidates.values() for _, relative in cands]
    support = [
        sum(
            any(angle_deg(c, other) < tolerance_deg for _, other in cands)
            for cands in candidates.values()
        )
        for c in everything
    ]
    consensus = everything[int(np.argmax(support))]
    matched: dict[int, Points] = {}
    refused: dict[int, str] = {}
    for view, cands in candidates.items():
        angles = [angle_deg(relative, consensus) for _, relative in cands]
        best = int(np.argmin(angles))
        if angles[best] > tolerance_deg:
            reason = (
                f"cam0->cam1 rotation from this view's board poses is {angles[best]:.1f} deg off "
                "the other views (board moved between exposures, or a false detection)"
            )
            refused[view] = reason
            continue
        d0, d1 = pairs[view]
        common, index0, index1 = np.intersect1d(d0.ids, cands[best][0], return_indices=True)
        if len(common) < MIN_COMMON:
            refused[view] = f"only {len(common)} corners seen by both cameras (need {MIN_COMMON})"
            continue
        matched[view] = (objects[common], d0.corners[index0], d1.corners[index1])
    return matched, refused


def stereo_residuals(
    item: Points,
    cameras: tuple[CameraModel, CameraModel],
    transform: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
) -> np.ndarray:
    """Residuals ``(2N, 2)`` of one view in both cameras for the cam0 pose ``(rvec, tvec)``."""
    obj, img0, img1 = item
    in_cam0 = obj @ cv2.Rodrigues(rvec)[0].T + tvec
    in_cam1 = in_cam0 @ transform[:3, :3].T + transform[:3, 3]
    residuals = [project_rays(cameras[0], in_cam0) - img0, project_rays(cameras[1], in_cam1) - img1]
    return np.asarray(np.nan_to_num(np.concatenate(residuals), nan=1e6))
