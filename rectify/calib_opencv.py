"""Stereo calibrations in OpenCV FileStorage files: :func:`from_filestorage`.

YAML with ``!!opencv-matrix`` nodes or a ``%YAML:1.0`` header, or XML; one to
three files whose keys are merged, e.g. ``intrinsics.yml`` + ``extrinsics.yml``
from OpenCV's stereo_calib sample. Accepted keys, first match wins:

* cam0 matrix / distortion: ``K1 M1 cameraMatrix1 camera_matrix_1 K_left
  camera_matrix_left`` / ``D1 distCoeffs1 dist_coeffs_1 D_left
  distortion_coefficients_left``; cam1 likewise with ``2`` / ``right``.
* Or one single-camera file per camera (OpenCV's calibration sample):
  ``camera_matrix`` (or ``cameraMatrix``, ``K``) and
  ``distortion_coefficients`` (or ``distCoeffs``, ``D``), first file cam0.
* Extrinsic cam0 -> cam1 (``x1 = R x0 + T``, as ``cv2.stereoCalibrate``):
  ``R`` (3x3 or a rotation vector) and ``T`` (3, **metres**), or ``T_cam1_cam0`` (4x4).
* Image size: ``image_size``/``imageSize`` ``[w, h]``, or
  ``image_width`` + ``image_height``; else each camera's own from the
  ``resolutions`` argument (``capture-ingest``: its first frame's size).
* Model: ``distortion_model`` (``radtan``/``plumb_bob`` or
  ``equidistant``/``fisheye``) or a non-zero ``fisheye_model``; default radtan.

:func:`read_filestorage` also serves the ROS reader's extrinsic file
(:mod:`~lenspair.rectify.calib_ros`).
"""

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lenspair.rectify.calib_values import (
    MODEL_NAMES,
    camera_from_matrices,
    check_camera_order,
    pick,
    square_transform,
    stereo_rig,
    transform_from_r_t,
)
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import DistortionModel, StereoRig, checked_transform

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


def is_filestorage(path: Path, text: str) -> bool:
    """Whether ``path`` (its contents ``text``) is an OpenCV FileStorage file."""
    # OpenCV 4 writes "%YAML:1.0", OpenCV 5 "%YAML 1.2"; both tag matrices "!!opencv-matrix".
    head = text.lstrip()[:200]
    return (
        head.startswith(("%YAML:1.", "<?xml", "<opencv_storage"))
        or "!!opencv-matrix" in text
        or path.suffix.lower() == ".xml"
    )


def read_filestorage(path: Path) -> dict[str, tuple[Any, Path]]:
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


def _model(values: dict[str, tuple[Any, Path]]) -> DistortionModel:
    if "distortion_model" in values:
        name, path = values["distortion_model"]
        if str(name).lower() not in MODEL_NAMES:
            valid = ", ".join(MODEL_NAMES)
            raise RectifyError(f"{path}: distortion_model: unknown {name!r}; valid: {valid}")
        return MODEL_NAMES[str(name).lower()]
    for key in ("fisheye_model", "fisheye"):
        if key in values and not isinstance(values[key][0], str) and float(values[key][0]) != 0:
            return "equidistant"
    return "radtan"


def _find_size(values: dict[str, tuple[Any, Path]]) -> tuple[int, int] | None:
    found = pick(values, ("image_size", "imageSize"))
    if found is not None and found[0].size == 2:
        return int(found[0].ravel()[0]), int(found[0].ravel()[1])
    width = pick(values, ("image_width", "width"))
    height = pick(values, ("image_height", "height"))
    if width is not None and height is not None:
        return int(width[0].ravel()[0]), int(height[0].ravel()[0])
    return None


def from_filestorage(
    paths: list[Path], resolutions: Sequence[tuple[int, int] | None] = (None, None)
) -> StereoRig:
    """The rig in one to three FileStorage files (see the module docstring for the keys).

    Args:
        paths: the files, their keys merged; per-camera files in the order cam0, cam1.
        resolutions: cam0's and cam1's image ``(width, height)`` (or None), for
            a camera whose files hold no image size.

    Raises:
        RectifyError: missing keys, NaN/Inf, implausible values; naming the file.
    """
    where = " + ".join(str(p) for p in paths)
    per_file = [read_filestorage(p) for p in paths]
    merged = {k: v for values in per_file for k, v in values.items()}
    # files holding one camera each (by position: their values are arrays, which `in` and
    # `==` cannot compare)
    single_files = [
        (path, values)
        for path, values in zip(paths, per_file, strict=True)
        if pick(values, _SINGLE_KEYS[0]) and pick(values, _SINGLE_KEYS[1])
    ]
    singles = [values for _, values in single_files]
    if len(singles) >= 2:  # one file a camera: in the order cam0, cam1, as for ROS files
        check_camera_order([path for path, _ in single_files][:2])
    cameras = []
    for index, name in enumerate(("cam0", "cam1")):
        source = singles[index] if len(singles) >= 2 else merged
        keys = _SINGLE_KEYS if len(singles) >= 2 else _CAMERA_KEYS[name]
        K, D = pick(source, keys[0]), pick(source, keys[1])
        if K is None or D is None:
            raise RectifyError(
                f"{where}: no {name} intrinsics (keys {'/'.join(keys[0][:3])}..., "
                f"{'/'.join(keys[1][:3])}...)"
            )
        size = _find_size(source) or _find_size(merged) or resolutions[index]
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
        cameras.append(camera_from_matrices(K[0], D[0], model, size, f"{K[1]}: {name}"))
    transform = pick(merged, ("T_cam1_cam0",))
    if transform is not None:
        matrix = checked_transform(
            square_transform(transform[0], str(transform[1])), str(transform[1])
        )
    else:
        R = pick(merged, ("R", "R_cam1_cam0", "rotation"))
        T = pick(merged, ("T", "t", "translation"))
        if R is None or T is None:
            raise RectifyError(f"{where}: no extrinsic (R and T, or T_cam1_cam0)")
        matrix = transform_from_r_t(R[0], T[0], str(R[1]))
    return stereo_rig(cameras[0], cameras[1], matrix, where)
