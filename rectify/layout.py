"""Which way a stereo rig's baseline runs, judged as ``cv2.stereoRectify`` judges it.

``cv2.stereoRectify`` splits the relative rotation of the two cameras in two
halves, turns each camera by its half, and then aligns the baseline with the
image axis (x or y) along which the *half-turned* translation is longer. So
the rectification it returns is side by side or top/bottom by that
criterion, not by where cam1's centre lies in cam0's frame: near 45 deg the
two disagree (cam1 at 43.5 deg from cam0's x axis and rolled 8 deg is
rectified top/bottom). :func:`unsupported_layout` therefore asks the same
question of the same vector, after cam1's quarter turns are undone
(:func:`quarter_turns`), exactly as :class:`~lenspair.rectify.rectification.StereoRectification`
hands the rig to OpenCV.
"""

import cv2
import numpy as np

from lenspair.rectify.rig import StereoRig


def rotation_z(quarter_turns: int) -> np.ndarray:
    """Rotation by ``quarter_turns`` x 90 deg about the optical (z) axis, ``(3, 3)`` float64."""
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][quarter_turns % 4]
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quarter_turns(rig: StereoRig) -> int:
    """cam1's roll relative to cam0, rounded to quarter turns (0..3; 2 for upside down)."""
    # the trace of Rz(-k) R is largest for the k nearest the roll
    return int(np.argmax([np.trace(rotation_z(k) @ rig.R) for k in range(4)]))


def half_turned_baseline(rig: StereoRig) -> np.ndarray:
    """The translation ``cv2.stereoRectify`` aligns with an image axis, ``(3,)`` metres.

    cam1's quarter turns undone, the translation turned by minus half the
    relative rotation: the vector whose larger of ``|x|`` and ``|y|`` decides
    whether OpenCV rectifies side by side or top/bottom.
    """
    turn = rotation_z(quarter_turns(rig))
    rotation, translation = turn @ rig.R, turn @ rig.t
    half = cv2.Rodrigues(-0.5 * cv2.Rodrigues(rotation)[0])[0]
    return np.asarray(half @ translation, dtype=np.float64)


def unsupported_layout(rig: StereoRig) -> str | None:
    """Why ``rig`` cannot be rectified side by side, or None where it can.

    Two layouts are not: a baseline more along the optical axis than across
    it (cam1 in front of or behind cam0: rows cannot agree without turning
    the cameras towards each other's optical axis, and the image edges then
    fall behind the rectified plane), and a baseline that ``cv2.stereoRectify``
    would align with the image columns (a top/bottom rig). Both are judged on
    :func:`half_turned_baseline`, the vector OpenCV itself uses.

    Returns:
        One phrase naming cam1's optical centre in cam0's frame (metres,
        rounded) and the layout, e.g. ``"the baseline [0.002, 0.11, -0.001] m
        is mostly vertical (a top/bottom rig, ...)"``; None for a side-by-side rig.

    """
    centre = np.round(-rig.R.T @ rig.t, 4).tolist()
    x, y, z = np.abs(half_turned_baseline(rig))
    if z > max(x, y):
        tilt = np.degrees(np.arctan2(z, np.hypot(x, y)))
        return (
            f"the baseline {centre} m runs mostly along the optical axis ({tilt:.0f} deg out "
            "of the image plane: cam1 in front of or behind cam0)"
        )
    if x <= y:  # OpenCV's own test: columns unless |x| > |y|
        angle = np.degrees(np.arctan2(y, x))
        return (
            f"the baseline {centre} m is mostly vertical (a top/bottom rig: {angle:.1f} deg "
            "from the rows once the cameras' relative rotation is split between them, as "
            "cv2.stereoRectify does)"
        )
    return None
