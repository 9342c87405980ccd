"""Checks that a calibration's board views and fits are those of a camera.

Small reprojection errors do not make a calibration: a board held still, or
seen at too few poses, fits a camera whose focal length and baseline the
views leave unconstrained (three poses held for ten frames each gave a rig
18 times too wide with fy four times fx). The calibration runs these checks on
each camera's fit (:mod:`~lenspair.rectify.calib_camera`) and on the stereo
step's views (:mod:`~lenspair.rectify.calibration`).

Each check is a plain function of the fitted poses or cameras: it raises
``RectifyError`` for what no camera gives, and returns what it warns of
(the calibration logs it, and its result keeps it).
"""

from collections.abc import Sequence

import cv2
import numpy as np

from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import PIXEL_ASPECT_LIMIT, CameraModel

STILL_BOARD_DEG = 2.0
"""A board turned less than this from the first view in every view, and moved less than
:data:`STILL_BOARD_SHIFT` of its distance, stood still: no calibration."""
STILL_BOARD_SHIFT = 0.02
FEW_TILTS_DEG = 10.0
"""Below this largest turn from the first view the focal length is poorly determined (warning)."""


def _rotations(rvecs: np.ndarray) -> list[np.ndarray]:
    """``(3, 3)`` rotation matrices of ``(V, 3)`` rotation vectors."""
    return [cv2.Rodrigues(np.asarray(r, np.float64).reshape(3))[0] for r in rvecs]


def _turn_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between rotation matrices ``a`` and ``b``, degrees."""
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(a.T @ b)[0])))


def check_pose_spread(rvecs: np.ndarray, tvecs: np.ndarray, stage: str) -> str | None:
    """Refuse views of a board that stood still; warn when it was never tilted much.

    A recording of a static board (or of the same frame many times) fits a
    calibration whose errors look small and whose focal length and baseline
    are unconstrained: it ended in a misleading "baseline mostly vertical" or
    a camchain a few per cent off, without a word.

    Args:
        rvecs: ``(V, 3)`` board -> camera rotation vectors.
        tvecs: ``(V, 3)`` board -> camera translations, metres.
        stage: the camera's name for the messages (``cam0``, ``cam1``).

    Returns:
        The warning for a board never turned more than :data:`FEW_TILTS_DEG`,
        else None.

    Raises:
        RectifyError: the board barely turned or moved across the views.
    """
    # from the first view: linear in the views (the largest turn between any two
    # lies between this and twice this)
    rotations = _rotations(rvecs)
    turned = max(_turn_deg(rotations[0], r) for r in rotations)
    centres = np.asarray(tvecs, np.float64).reshape(-1, 3)
    moved = float(np.max(np.linalg.norm(centres - centres[0], axis=1)))
    depth = float(np.mean(np.linalg.norm(centres, axis=1)))
    if turned < STILL_BOARD_DEG and moved < STILL_BOARD_SHIFT * depth:
        raise RectifyError(
            f"{stage}: the board barely moved in the {len(centres)} views (turned "
            f"{turned:.1f} deg and moved {100 * moved:.1f} cm at most from the first): a "
            "calibration needs it tilted in several directions and moved across the image"
        )
    if turned < FEW_TILTS_DEG:
        return (
            f"{stage}: the board turned at most {turned:.1f} deg from the first view; tilt it "
            "by 20-40 deg in several directions, or the focal length is poorly determined"
        )
    return None


def distinct_poses(rvecs: np.ndarray, tvecs: np.ndarray) -> int:
    """How many board poses differ from every other counted one (a board not held still).

    Two poses are one where the board turned less than :data:`STILL_BOARD_DEG`
    and moved less than :data:`STILL_BOARD_SHIFT` of its distance between
    them, the measure of :func:`check_pose_spread`. Counted greedily in view
    order: each pose joins the first counted one it repeats.

    Args:
        rvecs: ``(V, 3)`` board -> camera rotation vectors.
        tvecs: ``(V, 3)`` board -> camera translations, metres.
    """
    rotations = _rotations(rvecs)
    centres = np.asarray(tvecs, np.float64).reshape(-1, 3)
    counted: list[int] = []
    for k, (rotation, centre) in enumerate(zip(rotations, centres, strict=True)):
        depth = float(np.linalg.norm(centre))
        if all(
            _turn_deg(rotations[j], rotation) >= STILL_BOARD_DEG
            or np.linalg.norm(centre - centres[j]) >= STILL_BOARD_SHIFT * depth
            for j in counted
        ):
            counted.append(k)
    return len(counted)


def check_distinct_poses(
    rvecs: np.ndarray, tvecs: np.ndarray, stage: str, min_views: int, seen: str = "seen"
) -> None:
    """Refuse views that hold fewer than ``min_views`` distinct board poses.

    Frames of a board held still repeat one pose: ten of them weigh like one
    view ten times over, with its noise averaged away, and counted as ten
    they let three poses pass ``min_views``; the fit then diverged (a rig
    18 times too wide, fy four times fx) with small errors.

    Raises:
        RectifyError: too few distinct poses (:func:`distinct_poses`), naming
            them and the views.
    """
    distinct = distinct_poses(rvecs, tvecs)
    if distinct < min_views:
        raise RectifyError(
            f"{stage}: the board was {seen} at only {distinct} distinct poses in {len(rvecs)} "
            f"views, need at least {min_views}: frames of a board held still count once; move "
            f"or tilt it between views (by more than {STILL_BOARD_DEG:g} deg, or "
            f"{100 * STILL_BOARD_SHIFT:g} % of its distance)"
        )


def check_fit(camera: CameraModel, stage: str) -> None:
    """Refuse a fit whose focal lengths are not those of a camera (:data:`PIXEL_ASPECT_LIMIT`).

    The fits this catches go well past the limit: three board poses held still
    gave fy/fx = 4.1. The poses themselves are checked first
    (:func:`check_distinct_poses`), so this is the last guard against a fit the
    views left unconstrained.

    Raises:
        RectifyError: ``fy / fx`` outside ``[1 / PIXEL_ASPECT_LIMIT, PIXEL_ASPECT_LIMIT]``.
    """
    fx, fy = camera.intrinsics[:2]
    if not 1.0 / PIXEL_ASPECT_LIMIT <= fy / fx <= PIXEL_ASPECT_LIMIT:
        raise RectifyError(
            f"{stage}: the calibration diverged: fy/fx = {fy / fx:.2f} (fx {fx:.1f} px, fy "
            f"{fy:.1f} px), outside the {1 / PIXEL_ASPECT_LIMIT:g}-{PIXEL_ASPECT_LIMIT:g} of "
            "real cameras; show the board at more poses, tilted in several directions and "
            "across the whole image, and check --model"
        )


RMS_RATIO_LIMIT = 5.0
"""A camera whose median view error, as an angle, exceeds this multiple of the other's
(and whose error in pixels exceeds the floor) is warned about.

The errors are compared as angles (pixels over the camera's ``fx``): in
pixels they grow with the resolution, so a VGA camera and a 12 MP one
fitting equally well differed 6.3 times. Even as angles a camera may fit
worse for good reasons (a thermal camera's blurred corners), so this is a
warning, not a refusal: the diverged fits it was meant to catch are refused
by :func:`check_distinct_poses` and :func:`check_fit`. The floor (the
calibration's ``outlier_floor_px``, below which no view is rejected) keeps
quiet about pairs whose views all fit to a few tenths of a pixel."""


def rms_balance_warnings(
    view_errors_px: Sequence[Sequence[float]], cameras: Sequence[CameraModel], floor_px: float
) -> list[str]:
    """Warn of a camera that fits its views far worse than the other (:data:`RMS_RATIO_LIMIT`).

    Compared by the median view error: a few noisy views (kept where rejecting
    them would leave too few) raise a camera's RMS, not its median.

    Args:
        view_errors_px: per camera (cam0, cam1), the RMS error of each used view, pixels.
        cameras: the two fitted cameras (their ``fx`` turns pixels into angles).
        floor_px: no warning for a camera whose median view error is at most this, pixels.

    Returns:
        One warning per camera that fits far worse; empty for most rigs.
    """
    medians = [float(np.median(errors)) for errors in view_errors_px]
    angles = [
        median / camera.intrinsics[0] for median, camera in zip(medians, cameras, strict=True)
    ]
    warnings = []
    for index in (0, 1):
        own, other = angles[index], angles[1 - index]
        if medians[index] <= floor_px or own <= RMS_RATIO_LIMIT * other:
            continue
        name = f"cam{1 - index}'s"
        against = f"{own / other:.1f} times {name}" if other > 0 else f"while {name} is"
        warnings.append(
            f"cam{index}: its views fit with a median error of {medians[index]:.3f} px "
            f"({1e3 * own:.3g} mrad at fx {cameras[index].intrinsics[0]:.0f} px), {against} "
            f"{medians[1 - index]:.3f} px ({1e3 * other:.3g} mrad) on the same board: its "
            "fit may have diverged or its lens model be wrong (check --model, and show the "
            "board at more poses); a camera with blurrier corners (thermal, defocused) fits "
            "worse all the same"
        )
    return warnings
