"""Checked values for the calibration file readers: numbers, cameras, transforms, rigs.

Every reader of :mod:`~lenspair.rectify.calib_io` turns what a file holds
into a :class:`~lenspair.rectify.rig.StereoRig` through these checks, so a
NaN, a wrong count or an implausible value is the same one-line
:class:`RectifyError` naming the file, whatever the format; and per-camera
files whose paths say they came in the order cam1, cam0 (or right, left)
are refused (:func:`check_camera_order`).
"""

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import cv2
import numpy as np

from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import (
    CameraModel,
    DistortionModel,
    StereoRig,
    checked_transform,
    refuse_implausible,
)

MODEL_NAMES: dict[str, DistortionModel] = {
    "radtan": "radtan", "plumb_bob": "radtan", "rational_polynomial": "radtan",
    "equidistant": "equidistant", "equi": "equidistant", "fisheye": "equidistant",
}  # fmt: skip
"""Distortion model names the files use -> lenspair's model."""


def finite(path: Path, key: str, value: np.ndarray) -> np.ndarray:
    """``value``, refused when empty or holding NaN or Inf."""
    if value.size == 0 or not np.all(np.isfinite(value)):
        raise RectifyError(f"{path}: {key} is empty or contains NaN or Inf")
    return value


def pick(
    values: dict[str, tuple[Any, Path]], keys: tuple[str, ...]
) -> tuple[np.ndarray, Path, str] | None:
    """The first of ``keys`` that holds numbers: ``(array, its file, the key)``, else None."""
    for key in keys:
        if key in values and not isinstance(values[key][0], str):
            array, path = values[key]
            return finite(path, key, np.asarray(array, dtype=np.float64)), path, key
    return None


def square_transform(values: np.ndarray, where: str) -> np.ndarray:
    """A 4x4 transform from 16 values, or from 12 (``[R | t]``, the last row implied)."""
    flat = np.asarray(values, dtype=np.float64).ravel()
    if flat.size == 12:
        flat = np.concatenate([flat, [0.0, 0.0, 0.0, 1.0]])
    if flat.size != 16:
        raise RectifyError(
            f"{where}: T_cam1_cam0 must be 4x4 (or 3x4 [R|t]), got {flat.size} values"
        )
    return flat.reshape(4, 4)


def camera_from_matrices(
    K: np.ndarray,
    D: np.ndarray,
    model: DistortionModel,
    size: tuple[int, int],
    where: str,
    region: bool = False,
) -> CameraModel:
    """A camera from its 3x3 matrix ``K`` and distortion ``D``; radtan keeps k1 k2 p1 p2.

    Raises:
        RectifyError: a wrong count, a non-zero ``k3`` or higher term, or
            values :class:`CameraModel` refuses; naming ``where``.
    """
    if K.size != 9:
        raise RectifyError(f"{where}: camera matrix must be 3x3, got {K.size} values")
    K = K.reshape(3, 3)
    d = D.ravel()
    if model == "equidistant":
        if d.size != 4:
            raise RectifyError(
                f"{where}: equidistant distortion needs 4 coefficients, got {d.size}"
            )
    else:
        if d.size < 4:
            raise RectifyError(
                f"{where}: radtan distortion needs at least 4 coefficients, got {d.size}"
            )
        if np.any(np.abs(d[4:]) > 1e-12):
            raise RectifyError(
                f"{where}: distortion has k3 or higher-order terms {d[4:].tolist()}; lenspair's "
                "radtan model (as Kalibr's) has k1 k2 p1 p2 only: recalibrate with k3 fixed to 0"
            )
    try:
        camera = CameraModel(
            (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])),
            model, tuple(float(v) for v in d[:4]), size,  # type: ignore[arg-type]
        )  # fmt: skip
    except ValueError as exc:
        raise RectifyError(f"{where}: {exc}") from None
    refuse_implausible(camera, where, region)
    return camera


def transform_from_r_t(R: np.ndarray, T: np.ndarray, where: str) -> np.ndarray:
    """The checked 4x4 cam0 -> cam1 transform from ``R`` (3x3 or a rotation vector) and ``T``."""
    if R.size == 3:
        R = cv2.Rodrigues(R.reshape(3))[0]
    if R.size != 9 or T.size != 3:
        raise RectifyError(f"{where}: R must be 3x3 (or a rotation vector) and T 3 values")
    matrix = np.eye(4)
    matrix[:3, :3] = R.reshape(3, 3)
    matrix[:3, 3] = T.ravel()
    return checked_transform(matrix, where)


def stereo_rig(cam0: CameraModel, cam1: CameraModel, matrix: np.ndarray, where: str) -> StereoRig:
    """The rig, with what :class:`StereoRig` refuses as a :class:`RectifyError` naming ``where``."""
    try:
        return StereoRig(cam0, cam1, matrix)
    except ValueError as exc:
        raise RectifyError(f"{where}: {exc}") from None


_SIDES = {"cam0": "cam0", "cam1": "cam1", "left": "cam0", "right": "cam1"}
"""Words that say which camera a file is: cam0 is the left (reference) camera, as in ROS."""


def _path_word(path: Path) -> str | None:
    """The last path part that names a camera (``mav0/cam1/sensor.yaml``, ``left.yaml``)."""
    for part in reversed(Path(path).with_suffix("").parts):
        if part.lower() in _SIDES:
            return part
    return None


def camera_side(name: str) -> str | None:
    """``cam0``/``cam1`` for a camera name that says it (``narrow_stereo/right`` is cam1).

    The last word among ``left``, ``right``, ``cam0``, ``cam1`` decides; None
    when the name holds none of them.
    """
    words = [word for word in re.split(r"[^a-z0-9]+", name.lower()) if word in _SIDES]
    return _SIDES[words[-1]] if words else None


def refuse_swapped(files: Sequence[Path], by: str, first: str, second: str, note: str) -> NoReturn:
    """Raise the refusal of two per-camera files given cam1's first.

    Args:
        files: the two files, in the order given.
        by: what tells, e.g. ``"their paths"``.
        first: what the first file is by it, e.g. ``"cam1's"``.
        second: what the second file is by it, e.g. ``"cam0's"``.
        note: what to do if ``by`` misleads, e.g. ``"or rename them, ..."``.

    Raises:
        RectifyError: always; naming the files and the order expected.
    """
    raise RectifyError(
        f"{files[0]} + {files[1]}: by {by} the first is {first} and the second {second}; "
        f"give the per-camera files in the order cam0, cam1 ({note})"
    )


def check_camera_order(files: Sequence[Path]) -> None:
    """Refuse per-camera files whose paths say they were given cam1 first.

    A path part ``cam0`` or ``left`` names the first camera, ``cam1`` or
    ``right`` the second. Each camera would be rectified with the other's
    intrinsics and the extrinsic inverted, and the ingest ran on without a word.
    """
    first, second = (_path_word(path) or "" for path in files[:2])
    if _SIDES.get(first.lower()) == "cam1" and _SIDES.get(second.lower()) == "cam0":
        said = [
            f"{w}'s" if w.lower().startswith("cam") else f"the {w} camera's"
            for w in (first, second)
        ]
        refuse_swapped(
            files, "their paths", said[0], said[1],
            f"left, right; or rename them, if the file named {first} really is the first "
            "camera's",
        )  # fmt: skip
