"""Reading stereo calibrations in other tools' formats: :func:`load_calibration`.

The format is recognised from the files' contents; the paths' order matters
only where it says which camera is which (first = cam0, second = cam1).

**Kalibr camchain** (one YAML file with ``cam0`` and ``cam1``): read by
:func:`lenspair.rectify.rig.read_kalibr`.

**OpenCV FileStorage** (YAML with ``!!opencv-matrix`` nodes or a ``%YAML:1.0``
header, or XML; one to
three files whose keys are merged, e.g. ``intrinsics.yml`` + ``extrinsics.yml``
from OpenCV's stereo_calib sample). Accepted keys, first match wins:

* cam0 matrix / distortion: ``K1 M1 cameraMatrix1 camera_matrix_1 K_left
  camera_matrix_left`` / ``D1 distCoeffs1 dist_coeffs_1 D_left
  distortion_coefficients_left``; cam1 likewise with ``2`` / ``right``.
* Or one single-camera file per camera (OpenCV's calibration sample):
  ``camera_matrix`` (or ``cameraMatrix``, ``K``) and
  ``distortion_coefficients`` (or ``distCoeffs``, ``D``), first file cam0.
* Extrinsic cam0 -> cam1 (``x1 = R x0 + T``, as ``cv2.stereoCalibrate``):
  ``R`` (3x3 or a rotation vector) and ``T`` (3, **metres**), or ``T_cam1_cam0`` (4x4).
* Image size: ``image_size``/``imageSize`` ``[w, h]``, or
  ``image_width`` + ``image_height``; else the ``resolution`` argument.
* Model: ``distortion_model`` (``radtan``/``plumb_bob`` or
  ``equidistant``/``fisheye``) or a non-zero ``fisheye_model``; default radtan.

**ROS camera_info pair** (two YAML files as written by camera_calibration:
``image_width``, ``image_height``, ``camera_matrix``, ``distortion_model``
``plumb_bob``/``rational_polynomial``/``equidistant``,
``distortion_coefficients``, ``rectification_matrix``, ``projection_matrix``;
first file cam0). The extrinsic comes from a third file when given (plain YAML
with ``T_cam1_cam0`` 4x4, or ``R`` + ``T``; or a FileStorage with those keys),
else from the rectified pair: ``R = R1^T R0`` and ``T = R1^T (t1 - t0)`` with
``t_i = (Tx_i / fx', Ty_i / fy', 0)`` from each ``projection_matrix``
(``Tx = -fx' * B``).

**EuRoC/ASL camera ``sensor.yaml`` pair** (``mav0/cam0/sensor.yaml`` and
``mav0/cam1/sensor.yaml``: ``intrinsics`` ``[fu, fv, cu, cv]``,
``distortion_model`` ``radial-tangential``/``equidistant``,
``distortion_coefficients``, ``resolution`` and ``T_BS``, each camera's pose in
the body frame; first file cam0). The extrinsic is
``T_cam1_cam0 = inv(T_BS1) T_BS0``. ``capture-ingest`` takes them from a
EuRoC recording that has no other calibration.

Radtan models keep four coefficients (Kalibr's ``k1 k2 p1 p2``); a non-zero
``k3`` or higher term is refused rather than silently dropped. Every value is
checked: NaN or Inf is a one-line :class:`RectifyError` naming the file.
"""

import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import (
    ROTATION_ATOL,
    CameraModel,
    DistortionModel,
    StereoRig,
    camera_from_kalibr,
    checked_transform,
    is_rotation,
    read_kalibr,
)

log = logging.getLogger(__name__)

_CAMERA_KEYS = {
    "cam0": (("K1", "M1", "cameraMatrix1", "camera_matrix_1", "K_left", "camera_matrix_left"),
             ("D1", "distCoeffs1", "dist_coeffs_1", "D_left", "distortion_coefficients_left")),
    "cam1": (("K2", "M2", "cameraMatrix2", "camera_matrix_2", "K_right", "camera_matrix_right"),
             ("D2", "distCoeffs2", "dist_coeffs_2", "D_right", "distortion_coefficients_right")),
}  # fmt: skip
_SINGLE_KEYS = (
    ("camera_matrix", "cameraMatrix", "K"),
    ("distortion_coefficients", "distCoeffs", "D"),
)
_MODEL_NAMES: dict[str, DistortionModel] = {
    "radtan": "radtan", "plumb_bob": "radtan", "rational_polynomial": "radtan",
    "equidistant": "equidistant", "equi": "equidistant", "fisheye": "equidistant",
}  # fmt: skip


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise RectifyError(f"{path}: file not found") from None
    except OSError as exc:
        raise RectifyError(f"{path}: cannot read ({exc.strerror})") from None


def _is_filestorage(path: Path, text: str) -> bool:
    # OpenCV 4 writes "%YAML:1.0", OpenCV 5 "%YAML 1.2"; both tag matrices "!!opencv-matrix".
    head = text.lstrip()[:200]
    return (
        head.startswith(("%YAML:1.", "<?xml", "<opencv_storage"))
        or "!!opencv-matrix" in text
        or path.suffix.lower() == ".xml"
    )


def _finite(path: Path, key: str, value: np.ndarray) -> np.ndarray:
    if value.size == 0 or not np.all(np.isfinite(value)):
        raise RectifyError(f"{path}: {key} is empty or contains NaN or Inf")
    return value


def _read_filestorage(path: Path) -> dict[str, tuple[Any, Path]]:
    """Top-level FileStorage nodes as numpy arrays, floats or strings (with their file)."""
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV 5 raises on a parse error
        raise RectifyError(
            f"{path}: not a readable OpenCV FileStorage file ({_cv_reason(exc)})"
        ) from None
    if not storage.isOpened():
        raise RectifyError(f"{path}: not a readable OpenCV FileStorage file")
    values: dict[str, tuple[Any, Path]] = {}
    try:
        if not storage.root().isMap():  # empty (a writer stopped after the header), or a list
            raise RectifyError(f"{path}: holds no named values (empty, or not a mapping)")
        for key in storage.root().keys():  # noqa: SIM118 (a cv2.FileNode, not a dict)
            node = storage.getNode(key)
            if node.isString():
                values[key] = (node.string(), path)
            elif node.isSeq():
                values[key] = (np.array([node.at(i).real() for i in range(node.size())]), path)
            elif node.isInt() or node.isReal():
                values[key] = (np.array(node.real()), path)
            elif node.isMap():
                try:
                    matrix = node.mat()
                except (cv2.error, SystemError) as exc:  # a map that is not a matrix: not ours
                    if node.getNode("dt").isString():  # an !!opencv-matrix, broken: say so
                        raise RectifyError(
                            f"{path}: {key}: not a readable matrix ({_cv_reason(exc)})"
                        ) from None
                    continue
                if matrix is not None:
                    values[key] = (np.asarray(matrix, dtype=np.float64), path)
    finally:
        storage.release()
    return values


def _cv_reason(exc: BaseException) -> str:
    """OpenCV's own words for a failure, one line (a SystemError carries them as its cause)."""
    cause = exc.__cause__ or exc.__context__ or exc
    lines = [line.strip() for line in str(cause).splitlines() if line.strip()]
    return lines[-1] if lines else type(cause).__name__


def _square_transform(values: np.ndarray, where: str) -> np.ndarray:
    """A 4x4 transform from 16 values, or from 12 (``[R | t]``, the last row implied)."""
    flat = np.asarray(values, dtype=np.float64).ravel()
    if flat.size == 12:
        flat = np.concatenate([flat, [0.0, 0.0, 0.0, 1.0]])
    if flat.size != 16:
        raise RectifyError(
            f"{where}: T_cam1_cam0 must be 4x4 (or 3x4 [R|t]), got {flat.size} values"
        )
    return flat.reshape(4, 4)


def _pick(
    values: dict[str, tuple[Any, Path]], keys: tuple[str, ...]
) -> tuple[np.ndarray, Path, str] | None:
    for key in keys:
        if key in values and not isinstance(values[key][0], str):
            array, path = values[key]
            return _finite(path, key, np.asarray(array, dtype=np.float64)), path, key
    return None


def _camera(
    K: np.ndarray, D: np.ndarray, model: DistortionModel, size: tuple[int, int], where: str
) -> CameraModel:
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
        return CameraModel(
            (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])),
            model, tuple(float(v) for v in d[:4]), size,  # type: ignore[arg-type]
        )  # fmt: skip
    except ValueError as exc:
        raise RectifyError(f"{where}: {exc}") from None


def _transform(R: np.ndarray, T: np.ndarray, where: str) -> np.ndarray:
    if R.size == 3:
        R = cv2.Rodrigues(R.reshape(3))[0]
    if R.size != 9 or T.size != 3:
        raise RectifyError(f"{where}: R must be 3x3 (or a rotation vector) and T 3 values")
    matrix = np.eye(4)
    matrix[:3, :3] = R.reshape(3, 3)
    matrix[:3, 3] = T.ravel()
    return checked_transform(matrix, where)


def _model(values: dict[str, tuple[Any, Path]]) -> DistortionModel:
    if "distortion_model" in values:
        name, path = values["distortion_model"]
        if str(name).lower() not in _MODEL_NAMES:
            valid = ", ".join(_MODEL_NAMES)
            raise RectifyError(f"{path}: distortion_model: unknown {name!r}; valid: {valid}")
        return _MODEL_NAMES[str(name).lower()]
    for key in ("fisheye_model", "fisheye"):
        if key in values and not isinstance(values[key][0], str) and float(values[key][0]) != 0:
            return "equidistant"
    return "radtan"


def _find_size(values: dict[str, tuple[Any, Path]]) -> tuple[int, int] | None:
    found = _pick(values, ("image_size", "imageSize"))
    if found is not None and found[0].size == 2:
        return int(found[0].ravel()[0]), int(found[0].ravel()[1])
    width = _pick(values, ("image_width", "width"))
    height = _pick(values, ("image_height", "height"))
    if width is not None and height is not None:
        return int(width[0].ravel()[0]), int(height[0].ravel()[0])
    return None


def _from_filestorage(paths: list[Path], resolution: tuple[int, int] | None) -> StereoRig:
    where = " + ".join(str(p) for p in paths)
    per_file = [_read_filestorage(p) for p in paths]
    merged = {k: v for values in per_file for k, v in values.items()}
    # files holding one camera each (by position: their values are arrays, which `in` and
    # `==` cannot compare)
    single_files = [
        (path, values)
        for path, values in zip(paths, per_file, strict=True)
        if _pick(values, _SINGLE_KEYS[0]) and _pick(values, _SINGLE_KEYS[1])
    ]
    singles = [values for _, values in single_files]
    if len(singles) >= 2:  # one file a camera: in the order cam0, cam1, as for ROS files
        _check_camera_order([path for path, _ in single_files][:2])
    cameras = []
    for index, name in enumerate(("cam0", "cam1")):
        source = singles[index] if len(singles) >= 2 else merged
        keys = _SINGLE_KEYS if len(singles) >= 2 else _CAMERA_KEYS[name]
        K, D = _pick(source, keys[0]), _pick(source, keys[1])
        if K is None or D is None:
            raise RectifyError(
                f"{where}: no {name} intrinsics (keys {'/'.join(keys[0][:3])}..., "
                f"{'/'.join(keys[1][:3])}...)"
            )
        size = _find_size(source) or _find_size(merged) or resolution
        if size is None:
            raise RectifyError(f"{K[1]}: no image size (image_size, or image_width/image_height)")
        model = _model(source)
        stated = "distortion_model" in source or any(
            k in source for k in ("fisheye_model", "fisheye")
        )
        if not stated and D[0].size == 4:  # cv2.calibrate writes 5 or more; cv2.fisheye 4
            log.warning(
                "%s: %s: 4 distortion coefficients and no distortion_model: read as radtan "
                "(k1 k2 p1 p2); if cv2.fisheye wrote them, add 'distortion_model: equidistant'",
                D[1],
                D[2],
            )
        cameras.append(_camera(K[0], D[0], model, size, f"{K[1]}: {name}"))
    transform = _pick(merged, ("T_cam1_cam0",))
    if transform is not None:
        matrix = checked_transform(
            _square_transform(transform[0], str(transform[1])), str(transform[1])
        )
    else:
        R = _pick(merged, ("R", "R_cam1_cam0", "rotation"))
        T = _pick(merged, ("T", "t", "translation"))
        if R is None or T is None:
            raise RectifyError(f"{where}: no extrinsic (R and T, or T_cam1_cam0)")
        matrix = _transform(R[0], T[0], str(R[1]))
    return _rig(cameras[0], cameras[1], matrix, where)


def _rig(cam0: CameraModel, cam1: CameraModel, matrix: np.ndarray, where: str) -> StereoRig:
    try:
        return StereoRig(cam0, cam1, matrix)
    except ValueError as exc:
        raise RectifyError(f"{where}: {exc}") from None


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
    _finite(path, key, values)
    if shape[0] * shape[1] and values.size != shape[0] * shape[1]:
        raise RectifyError(
            f"{path}: {key}: expected {shape[0]}x{shape[1]} values, got {values.size}"
        )
    return values.reshape(shape) if shape[0] * shape[1] else values.ravel()


def _ros_camera(path: Path, data: dict[str, Any]) -> tuple[CameraModel, np.ndarray, np.ndarray]:
    name = str(data.get("distortion_model", "plumb_bob")).lower()
    if name not in _MODEL_NAMES:
        raise RectifyError(
            f"{path}: distortion_model: unknown {name!r}; valid: {', '.join(_MODEL_NAMES)}"
        )
    try:
        size = (int(data["image_width"]), int(data["image_height"]))
    except (KeyError, TypeError, ValueError):
        raise RectifyError(f"{path}: image_width and image_height must be integers") from None
    K = _ros_matrix(data, "camera_matrix", (3, 3), path)
    D = _ros_matrix(data, "distortion_coefficients", (0, 0), path)
    camera = _camera(K, D, _MODEL_NAMES[name], size, str(path))
    rectification = np.eye(3)
    if "rectification_matrix" in data:
        rectification = _ros_matrix(data, "rectification_matrix", (3, 3), path)
    projection = np.zeros((3, 4))
    if "projection_matrix" in data:
        projection = _ros_matrix(data, "projection_matrix", (3, 4), path)
    return camera, rectification, projection


def _extrinsic_file(path: Path, text: str) -> np.ndarray:
    if _is_filestorage(path, text):
        values = _read_filestorage(path)
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
    if (found := _pick(values, ("T_cam1_cam0", "T_cn_cnm1"))) is not None:
        return checked_transform(_square_transform(found[0], str(path)), str(path))
    R, T = _pick(values, ("R", "rotation")), _pick(values, ("T", "t", "translation"))
    if R is None or T is None:
        raise RectifyError(f"{path}: expected T_cam1_cam0 (4x4), or R and T")
    return _transform(R[0], T[0], str(path))


def _from_ros(paths: list[Path], texts: list[str]) -> tuple[StereoRig, str]:
    parsed = []
    for path, text in zip(paths[:2], texts[:2], strict=True):
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise RectifyError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
        parsed.append(_ros_camera(path, data))
    where = f"{paths[0]} + {paths[1]}"
    (cam0, rect0, proj0), (cam1, rect1, proj1) = parsed
    for path, rectification in ((paths[0], rect0), (paths[1], rect1)):
        if not is_rotation(rectification, atol=ROTATION_ATOL):
            raise RectifyError(f"{path}: rectification_matrix is not a rotation matrix")
    if len(paths) == 3:
        rig = _rig(cam0, cam1, _extrinsic_file(paths[2], texts[2]), where)
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
    rig = _rig(cam0, cam1, checked_transform(matrix, where), where)
    return rig, f"ROS camera_info {where} (extrinsic from the projection matrices)"


_EUROC_MODELS = {"radial-tangential": "radtan", "equidistant": "equidistant"}
_EUROC_KEYS = ("intrinsics", "T_BS", "distortion_coefficients", "resolution")


def _euroc_sensor(text: str) -> dict[str, Any] | None:
    """The mapping of a EuRoC camera ``sensor.yaml`` (``sensor_type: camera``), else None."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        return None
    return data if isinstance(data, dict) and data.get("sensor_type") == "camera" else None


def is_euroc_sensor_file(path: Path) -> bool:
    """Whether ``path`` is a EuRoC camera ``sensor.yaml`` holding a calibration."""
    try:
        data = _euroc_sensor(Path(path).read_text(encoding="utf-8"))
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
    model = _EUROC_MODELS.get(str(data.get("distortion_model")), data.get("distortion_model"))
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


def _from_euroc(paths: list[Path], sensors: list[dict[str, Any]]) -> tuple[StereoRig, str]:
    cameras, poses = [], []
    for path, data in zip(paths, sensors, strict=True):
        cameras.append(_euroc_camera(path, data))
        pose = _finite(path, "T_BS", _matrix_node(data["T_BS"], path, "T_BS"))
        poses.append(_rigid(path, pose))
    where = f"{paths[0]} + {paths[1]}"
    matrix = checked_transform(np.linalg.inv(poses[1]) @ poses[0], where)
    return _rig(cameras[0], cameras[1], matrix, where), f"EuRoC sensor.yaml {where}"


def _matrix_node(node: Any, path: Path, key: str) -> np.ndarray:
    try:
        values = np.asarray(node["data"] if isinstance(node, dict) else node, dtype=np.float64)
        return values.reshape(4, 4)
    except (TypeError, ValueError, KeyError):
        raise RectifyError(f"{path}: {key}: expected 16 numbers (a 4x4 transform)") from None


def _camera_named(path: Path) -> str | None:
    """``cam0``/``cam1`` when the path names one (``mav0/cam1/sensor.yaml``, ``cam0.yaml``)."""
    for part in reversed(Path(path).with_suffix("").parts):
        if part in ("cam0", "cam1"):
            return part
    return None


def _check_camera_order(files: Sequence[Path]) -> None:
    """Refuse per-camera files whose paths say they were given cam1 first.

    Each camera would be rectified with the other's intrinsics and the
    extrinsic inverted, and the ingest ran on without a word.
    """
    named = [_camera_named(path) for path in files]
    if named == ["cam1", "cam0"]:
        raise RectifyError(
            f"{files[0]} + {files[1]}: by their paths the first is cam1's and the second "
            "cam0's; give the per-camera files in the order cam0, cam1 (or rename them, if "
            "the file named cam1 really is the first camera's)"
        )


def _is_ros(text: str) -> bool:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        return False
    return isinstance(data, dict) and "camera_matrix" in data and "image_width" in data


def load_calibration(
    paths: Sequence[Path], resolution: tuple[int, int] | None = None
) -> tuple[StereoRig, str]:
    """Read a stereo calibration in any supported format (see the module docstring).

    Args:
        paths: one Kalibr camchain; one to three OpenCV FileStorage files; or
            two ROS camera_info files (cam0, cam1) plus an optional extrinsic file.
        resolution: image ``(width, height)`` to use when a FileStorage file
            holds no image size (OpenCV's stereo_calib sample writes none).

    Returns:
        ``(rig, description)``: the rig, and a line saying where it came from.

    Raises:
        RectifyError: unknown format, missing keys, NaN/Inf, implausible values;
            one line, naming the file.

    """
    files = [Path(p) for p in paths]
    if not files:
        raise RectifyError("calibration: no file given")
    texts = [_read_text(p) for p in files]
    if all(_is_filestorage(p, t) for p, t in zip(files, texts, strict=True)) and len(files) <= 3:
        rig = _from_filestorage(files, resolution)
        return rig, f"OpenCV FileStorage {' + '.join(str(p) for p in files)}"
    if len(files) in (2, 3) and _is_ros(texts[0]) and _is_ros(texts[1]):
        _check_camera_order(files[:2])
        return _from_ros(files, texts)
    sensors = [_euroc_sensor(text) for text in texts]
    if len(files) == 2 and all(sensors):
        _check_camera_order(files)
        return _from_euroc(files, sensors)  # type: ignore[arg-type]
    if len(files) == 1:
        try:
            data = yaml.safe_load(texts[0])
        except yaml.YAMLError as exc:
            raise RectifyError(f"{files[0]}: not valid YAML ({str(exc).splitlines()[0]})") from None
        if isinstance(data, dict) and "cam0" in data:
            return read_kalibr(files[0]), f"Kalibr camchain {files[0]}"
    raise RectifyError(
        f"{' + '.join(str(p) for p in files)}: not a recognised calibration; expected one Kalibr "
        "camchain, 1-3 OpenCV FileStorage files, two ROS camera_info files (cam0, cam1), or "
        "two EuRoC sensor.yaml files (cam0, cam1)"
    )
