"""Stereo calibrations as a ROS camera_info pair: :func:`from_ros`.

Two YAML files as written by camera_calibration (or echoed ``CameraInfo``
messages: :func:`message_as_camera_info`): ``image_width``,
``image_height``, ``camera_matrix``, ``distortion_model``
``plumb_bob``/``rational_polynomial``/``equidistant``,
``distortion_coefficients``, ``rectification_matrix``, ``projection_matrix``;
first file cam0, the left camera (a pair whose ``camera_name`` or
``projection_matrix`` says the right camera came first is refused). The
extrinsic comes from a third file when given (plain YAML with ``T_cam1_cam0``
4x4, or ``R`` + ``T``; or a FileStorage with those keys), else from the
rectified pair: ``R = R1^T R0`` and ``T = R1^T (t1 - t0)`` with
``t_i = (Tx_i / fx', Ty_i / fy', 0)`` from each ``projection_matrix``
(``Tx = -fx' * B``).
"""

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lenspair.rectify.calib_opencv import is_filestorage, read_filestorage
from lenspair.rectify.calib_values import (
    MODEL_NAMES,
    camera_from_matrices,
    camera_side,
    finite,
    pick,
    refuse_swapped,
    square_transform,
    stereo_rig,
    transform_from_r_t,
)
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import (
    ROTATION_ATOL,
    CameraModel,
    DistortionModel,
    StereoRig,
    checked_transform,
    is_rotation,
)


def message_as_camera_info(message: Mapping[str, Any], name: str | None) -> dict[str, Any]:
    """A ``CameraInfo`` message's fields as the YAML ``camera_calibration`` writes.

    ``message`` maps the message's field names, ROS 1's (``K``, ``D``, ``R``,
    ``P``) or ROS 2's (``k``, ``d``, ``r``, ``p``), as a bag's message or a
    ``rostopic echo``/``ros2 topic echo`` of one holds them; ``name`` becomes
    ``camera_name`` (a topic, a frame id), which tells left from right.

    ``K`` and ``P`` describe the full sensor: a camera that bins pixels
    (``binning_x``/``binning_y`` above 1) or reads a region of interest
    (``roi``, in unbinned sensor pixels) streams smaller images, and its
    calibration is taken to them as ROS's ``image_geometry`` does: the
    principal point less the region's offset, then both divided by the
    binning, and the image size the region's (or the sensor's) divided by it.
    """
    fields = {str(key).lower(): value for key, value in message.items()}

    def values(key: str) -> list[float]:
        value = fields.get(key)  # a bag's message holds numpy arrays: no truth value
        return [] if value is None else [float(x) for x in value]

    bins = [max(1, int(fields.get(f"binning_{axis}") or 1)) for axis in "xy"]
    x_offset, y_offset, roi_width, roi_height = _roi(fields.get("roi"), name)
    width = (roi_width or int(fields["width"])) // bins[0]
    height = (roi_height or int(fields["height"])) // bins[1]
    k, p = values("k"), values("p")
    for matrix, columns in ((k, 3), (p, 4)):
        if len(matrix) == 3 * columns:
            for row, offset, step in ((0, x_offset, bins[0]), (1, y_offset, bins[1])):
                row_values = slice(row * columns, (row + 1) * columns)
                matrix[row_values] = [v / step for v in matrix[row_values]]
                matrix[row * columns + 2] -= offset / step
    full = (int(fields["width"]), int(fields["height"]))
    region = bool(roi_width and roi_height) and (roi_width, roi_height) != full
    return {
        **({"region_of_interest": [x_offset, y_offset, roi_width, roi_height]} if region else {}),
        "image_width": width,
        "image_height": height,
        "camera_name": name,
        "distortion_model": str(fields.get("distortion_model") or "plumb_bob"),
        "camera_matrix": {"rows": 3, "cols": 3, "data": k},
        "distortion_coefficients": {"rows": 1, "cols": len(values("d")), "data": values("d")},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": values("r")},
        "projection_matrix": {"rows": 3, "cols": 4, "data": p},
    }


def _roi(value: Any, name: str | None) -> tuple[int, int, int, int]:
    """``(x_offset, y_offset, width, height)`` of a ``RegionOfInterest``; zeros when unset.

    A bag's message holds it as an object, an echo as a mapping. As in ROS,
    all four zero is the full sensor; a region with an offset but no size
    is refused, not read as the full sensor shifted.

    Raises:
        RectifyError: a region with an offset and no width or height.
    """
    if value is None:
        return 0, 0, 0, 0
    get = value.get if isinstance(value, Mapping) else lambda key: getattr(value, key, 0)
    keys = ("x_offset", "y_offset", "width", "height")
    roi = tuple(int(get(key) or 0) for key in keys)
    if any(roi) and not (roi[2] and roi[3]):
        raise RectifyError(f"{name}: camera_info roi {roi} has an offset but no width or height")
    return roi  # type: ignore[return-value]


def _camera_info(text: str) -> dict[str, Any] | None:
    """A camera_info YAML's mapping: ``camera_calibration``'s file, or an echoed message.

    An echo (``rostopic echo -n 1``, ``ros2 topic echo --once``) holds the
    message's fields (``width``, ``height``, ``K``/``k``, ...) and ends with
    ``---``, a second YAML document: the first is read. None when ``text`` is
    neither.

    Raises:
        yaml.YAMLError: not YAML.
    """
    data = next(iter(yaml.safe_load_all(text)), None)
    if not isinstance(data, dict):
        return None
    if "camera_matrix" in data and "image_width" in data:
        return data
    keys = {str(key).lower() for key in data}
    if {"width", "height", "k"} <= keys:
        try:
            header = data.get("header")
            frame = header.get("frame_id") if isinstance(header, dict) else None
            return message_as_camera_info(data, str(frame) if frame else None)
        except (KeyError, TypeError, ValueError):
            return None
    return None


def is_ros_camera_info(text: str) -> bool:
    """Whether ``text`` is a ROS camera_info YAML: ``camera_calibration``'s or an echoed message."""
    try:
        return _camera_info(text) is not None
    except yaml.YAMLError:
        return False


def _ros_matrix(data: dict[str, Any], key: str, shape: tuple[int, int], path: Path) -> np.ndarray:
    if key not in data:
        raise RectifyError(f"{path}: missing key {key!r}")
    node = data[key]
    if isinstance(node, dict) and "data" not in node:
        raise RectifyError(f"{path}: {key}: no 'data' list")
    try:
        values = np.asarray(node["data"] if isinstance(node, dict) else node, dtype=np.float64)
    except (TypeError, ValueError):
        raise RectifyError(f"{path}: {key}: expected a list of numbers") from None
    finite(path, key, values)
    if shape[0] * shape[1] and values.size != shape[0] * shape[1]:
        raise RectifyError(
            f"{path}: {key}: expected {shape[0]}x{shape[1]} values, got {values.size}"
        )
    return values.reshape(shape) if shape[0] * shape[1] else values.ravel()


def _distortion(data: dict[str, Any], path: Path, model: DistortionModel) -> np.ndarray:
    """``distortion_coefficients``; an empty list is no distortion.

    Drivers of rectified or simulated streams publish ``D: []``, which ROS's
    ``image_geometry`` reads as no distortion.
    """
    node = data.get("distortion_coefficients")
    values = node.get("data") if isinstance(node, dict) else node
    if isinstance(values, list | tuple) and len(values) == 0:
        return np.zeros(4 if model == "equidistant" else 5)
    return _ros_matrix(data, "distortion_coefficients", (0, 0), path)


def _ros_camera(path: Path, data: dict[str, Any]) -> tuple[CameraModel, np.ndarray, np.ndarray]:
    name = str(data.get("distortion_model", "plumb_bob")).lower()
    if name not in MODEL_NAMES:
        raise RectifyError(
            f"{path}: distortion_model: unknown {name!r}; valid: {', '.join(MODEL_NAMES)}"
        )
    try:
        size = (int(data["image_width"]), int(data["image_height"]))
    except (KeyError, TypeError, ValueError):
        raise RectifyError(f"{path}: image_width and image_height must be integers") from None
    K = _ros_matrix(data, "camera_matrix", (3, 3), path)
    D = _distortion(data, path, MODEL_NAMES[name])
    # a part of the sensor need not hold the principal point (refuse_implausible)
    region = "region_of_interest" in data
    camera = camera_from_matrices(K, D, MODEL_NAMES[name], size, str(path), region)
    rectification = np.eye(3)
    if "rectification_matrix" in data:
        rectification = _ros_matrix(data, "rectification_matrix", (3, 3), path)
    projection = np.zeros((3, 4))
    if "projection_matrix" in data:
        projection = _ros_matrix(data, "projection_matrix", (3, 4), path)
    return camera, rectification, projection


def _extrinsic_file(path: Path, text: str) -> np.ndarray:
    if is_filestorage(path, text):
        values = read_filestorage(path)
    else:
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise RectifyError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
        if not isinstance(data, dict):
            raise RectifyError(f"{path}: expected a mapping with T_cam1_cam0, or R and T")
        values = {}
        for key, value in data.items():
            try:
                values[str(key)] = (np.asarray(value, dtype=np.float64), path)
            except (TypeError, ValueError):
                continue
    if (found := pick(values, ("T_cam1_cam0", "T_cn_cnm1"))) is not None:
        return checked_transform(square_transform(found[0], str(path)), str(path))
    R, T = pick(values, ("R", "rotation")), pick(values, ("T", "t", "translation"))
    if R is None or T is None:
        raise RectifyError(f"{path}: expected T_cam1_cam0 (4x4), or R and T")
    return transform_from_r_t(R[0], T[0], str(path))


def _check_order(paths: list[Path], names: list[Any], projections: tuple[np.ndarray, ...]) -> None:
    """Refuse a camera_info pair that says it was given the right camera first.

    camera_calibration names the cameras ``<rig>/left`` and ``<rig>/right``
    and gives the right camera's ``projection_matrix`` the baseline
    (``Tx = -fx' * B``), the left's ``Tx = 0``. Given right first, each camera
    was rectified with the other's calibration and the extrinsic inverted,
    without a word.

    Raises:
        RectifyError: naming both files and the order expected.
    """
    sides = [camera_side(name) if isinstance(name, str) else None for name in names]
    if sides == ["cam1", "cam0"]:
        refuse_swapped(
            paths, "their camera_name", f"{names[0]!r}", f"{names[1]!r}",
            "left, right, as camera_calibration names them",
        )  # fmt: skip
    if projections[0][0, 3] != 0 and projections[1][0, 3] == 0:
        refuse_swapped(
            paths, "their projection_matrix",
            f"the right camera's (Tx = {projections[0][0, 3]:g}, the baseline)",
            "the left's (Tx = 0)",
            "left, right: camera_calibration gives the right camera Tx = -fx' * B and the "
            "left Tx = 0",
        )  # fmt: skip


def from_ros(paths: list[Path], texts: list[str]) -> tuple[StereoRig, str]:
    """The rig in two ROS camera_info files (cam0, cam1) and an optional extrinsic file.

    Args:
        paths: cam0's and cam1's camera_info files, and optionally the extrinsic's.
        texts: the files' contents, in the same order.

    Returns:
        ``(rig, description)``: the rig, and a line saying where it came from.

    Raises:
        RectifyError: missing keys, NaN/Inf, implausible values; naming the file.
    """
    parsed, loaded = [], []
    for path, text in zip(paths[:2], texts[:2], strict=True):
        try:
            data = _camera_info(text)
        except yaml.YAMLError as exc:
            raise RectifyError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
        if data is None:
            raise RectifyError(f"{path}: not a ROS camera_info (no camera_matrix, no K)")
        parsed.append(_ros_camera(path, data))
        loaded.append(data)
    where = f"{paths[0]} + {paths[1]}"
    (cam0, rect0, proj0), (cam1, rect1, proj1) = parsed
    _check_order(paths[:2], [data.get("camera_name") for data in loaded], (proj0, proj1))
    for path, rectification in ((paths[0], rect0), (paths[1], rect1)):
        if not is_rotation(rectification, atol=ROTATION_ATOL):
            raise RectifyError(f"{path}: rectification_matrix is not a rotation matrix")
    if len(paths) == 3:
        rig = stereo_rig(cam0, cam1, _extrinsic_file(paths[2], texts[2]), where)
        return rig, f"ROS camera_info {where} (extrinsic from {paths[2]})"
    offsets = []
    for path, projection in ((paths[0], proj0), (paths[1], proj1)):
        if projection[0, 0] <= 0 or projection[1, 1] <= 0:
            raise RectifyError(
                f"{path}: projection_matrix is missing or zero; give the extrinsic as a third file"
            )
        fx, fy = projection[0, 0], projection[1, 1]
        offsets.append(np.array([projection[0, 3] / fx, projection[1, 3] / fy, 0.0]))
    if np.linalg.norm(offsets[1] - offsets[0]) == 0:
        raise RectifyError(
            f"{where}: the projection matrices hold no baseline (Tx = Ty = 0); "
            "give the extrinsic as a third file"
        )
    matrix = np.eye(4)
    matrix[:3, :3] = rect1.T @ rect0
    matrix[:3, 3] = rect1.T @ (offsets[1] - offsets[0])
    rig = stereo_rig(cam0, cam1, checked_transform(matrix, where), where)
    return rig, f"ROS camera_info {where} (extrinsic from the projection matrices)"
