"""Stereo calibrations in a EuRoC/ASL camera ``sensor.yaml`` pair: :func:`from_euroc`.

``mav0/cam0/sensor.yaml`` and ``mav0/cam1/sensor.yaml``: ``intrinsics``
``[fu, fv, cu, cv]``, ``distortion_model``
``radial-tangential``/``equidistant``, ``distortion_coefficients``,
``resolution`` and ``T_BS``, each camera's pose in the body frame; first file
cam0. The extrinsic is ``T_cam1_cam0 = inv(T_BS1) T_BS0``. ``capture-ingest``
takes them from a EuRoC recording that has no other calibration
(:func:`is_euroc_sensor_file`).
"""

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lenspair.rectify.calib_values import finite, stereo_rig
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import (
    ROTATION_ATOL,
    CameraModel,
    StereoRig,
    camera_from_kalibr,
    checked_transform,
    is_rotation,
)

_EUROC_MODELS = {"radial-tangential": "radtan", "equidistant": "equidistant"}
_EUROC_KEYS = ("intrinsics", "T_BS", "distortion_model", "distortion_coefficients", "resolution")


def euroc_sensor(text: str) -> dict[str, Any] | None:
    """The mapping of a EuRoC camera ``sensor.yaml`` (``sensor_type: camera``), else None."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        return None
    return data if isinstance(data, dict) and data.get("sensor_type") == "camera" else None


def is_euroc_sensor_file(path: Path) -> bool:
    """Whether ``path`` is a EuRoC camera ``sensor.yaml`` holding a calibration."""
    try:
        data = euroc_sensor(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError):
        return False
    return data is not None and all(key in data for key in _EUROC_KEYS)


def _rigid(path: Path, matrix: np.ndarray) -> np.ndarray:
    """``T_BS`` checked to be a rigid transform (rotation, translation, bottom row 0 0 0 1)."""
    rigid = np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6)
    if not (rigid and is_rotation(matrix[:3, :3], atol=ROTATION_ATOL)):
        raise RectifyError(
            f"{path}: T_BS is not a rigid transform (a rotation, a translation and the bottom "
            "row 0 0 0 1)"
        )
    return matrix


def _euroc_camera(path: Path, data: dict[str, Any]) -> CameraModel:
    if missing := [key for key in _EUROC_KEYS if key not in data]:
        raise RectifyError(f"{path}: missing key {missing[0]!r} (a EuRoC camera sensor.yaml)")
    named = data["distortion_model"]
    model = _EUROC_MODELS.get(str(named))
    if model is None:  # named in EuRoC's words: the Kalibr reader's message would use its own
        raise RectifyError(
            f"{path}: distortion_model: expected {' or '.join(_EUROC_MODELS)}, got {named!r}"
        )
    coefficients = data["distortion_coefficients"]
    if model == "radtan" and isinstance(coefficients, list) and len(coefficients) > 4:
        # k1 k2 p1 p2 [k3]: a zero k3 is dropped as for the other formats, a non-zero one refused
        if any(_as_float(value) != 0.0 for value in coefficients[4:]):
            raise RectifyError(
                f"{path}: distortion_coefficients: a non-zero k3 or higher term; lenspair's "
                "radtan model has k1 k2 p1 p2"
            )
        coefficients = coefficients[:4]
    kalibr = {
        "camera_model": data.get("camera_model", "pinhole"),
        "distortion_model": model,
        "intrinsics": data["intrinsics"],
        "distortion_coeffs": coefficients,
        "resolution": data["resolution"],
    }
    return camera_from_kalibr(kalibr, str(path))


def _as_float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan  # not zero: refused as a term that is not 0


def from_euroc(paths: list[Path], sensors: list[dict[str, Any]]) -> tuple[StereoRig, str]:
    """The rig in two EuRoC ``sensor.yaml`` files (cam0, cam1), parsed by :func:`euroc_sensor`.

    Returns:
        ``(rig, description)``: the rig, and a line saying where it came from.

    Raises:
        RectifyError: missing keys, NaN/Inf, a ``T_BS`` that is not rigid; naming the file.
    """
    cameras, poses = [], []
    for path, data in zip(paths, sensors, strict=True):
        cameras.append(_euroc_camera(path, data))
        pose = finite(path, "T_BS", _matrix_node(data["T_BS"], path, "T_BS"))
        poses.append(_rigid(path, pose))
    where = f"{paths[0]} + {paths[1]}"
    matrix = checked_transform(np.linalg.inv(poses[1]) @ poses[0], where)
    return stereo_rig(cameras[0], cameras[1], matrix, where), f"EuRoC sensor.yaml {where}"


def _matrix_node(node: Any, path: Path, key: str) -> np.ndarray:
    try:
        values = np.asarray(node["data"] if isinstance(node, dict) else node, dtype=np.float64)
        return values.reshape(4, 4)
    except (TypeError, ValueError, KeyError):
        raise RectifyError(f"{path}: {key}: expected 16 numbers (a 4x4 transform)") from None
