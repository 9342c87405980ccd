"""Reading stereo calibrations in other tools' formats: :func:`load_calibration`.

The format is recognised from the files' contents; the paths' order matters
only where it says which camera is which (first = cam0, second = cam1).
Each format's keys are listed in its reader's module:

* **Kalibr camchain** (one YAML file with ``cam0`` and ``cam1``): read by
  :func:`lenspair.rectify.rig.read_kalibr`.
* **OpenCV FileStorage** (YAML with ``!!opencv-matrix`` nodes or a
  ``%YAML:1.0`` header, or XML; one to three files whose keys are merged, or
  one single-camera file per camera): :mod:`~lenspair.rectify.calib_opencv`.
* **ROS camera_info pair** (two YAML files as written by camera_calibration,
  first file cam0; the extrinsic from a third file, else from the rectified
  pair's projection matrices): :mod:`~lenspair.rectify.calib_ros`.
* **EuRoC/ASL camera ``sensor.yaml`` pair** (``mav0/cam0/sensor.yaml`` and
  ``mav0/cam1/sensor.yaml``, the extrinsic from each camera's ``T_BS``):
  :mod:`~lenspair.rectify.calib_euroc`. ``capture-ingest`` takes them from a
  EuRoC recording that has no other calibration.

Radtan models keep four coefficients (Kalibr's ``k1 k2 p1 p2``); a non-zero
``k3`` or higher term is refused rather than silently dropped. Every value is
checked (:mod:`~lenspair.rectify.calib_values`): NaN or Inf is a one-line
:class:`RectifyError` naming the file.
"""

from collections.abc import Sequence
from pathlib import Path

import yaml

from lenspair.rectify.calib_euroc import euroc_sensor, from_euroc
from lenspair.rectify.calib_opencv import from_filestorage, is_filestorage
from lenspair.rectify.calib_ros import from_ros, is_ros_camera_info
from lenspair.rectify.calib_values import check_camera_order
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import StereoRig, read_kalibr


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise RectifyError(f"{path}: file not found") from None
    except OSError as exc:
        raise RectifyError(f"{path}: cannot read ({exc.strerror})") from None


def load_calibration(
    paths: Sequence[Path], resolutions: Sequence[tuple[int, int] | None] = (None, None)
) -> tuple[StereoRig, str]:
    """Read a stereo calibration in any supported format (see the module docstring).

    Args:
        paths: one Kalibr camchain; one to three OpenCV FileStorage files; or
            two ROS camera_info files (cam0, cam1) plus an optional extrinsic file;
            or two EuRoC ``sensor.yaml`` files (cam0, cam1).
        resolutions: cam0's and cam1's image ``(width, height)`` (or None) to
            use when a FileStorage file holds no image size (OpenCV's
            stereo_calib sample writes none); each camera its own, as a rig's
            two cameras need not have one size.

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
    if all(is_filestorage(p, t) for p, t in zip(files, texts, strict=True)) and len(files) <= 3:
        rig = from_filestorage(files, resolutions)
        return rig, f"OpenCV FileStorage {' + '.join(str(p) for p in files)}"
    if len(files) in (2, 3) and is_ros_camera_info(texts[0]) and is_ros_camera_info(texts[1]):
        check_camera_order(files[:2])
        return from_ros(files, texts)
    sensors = [euroc_sensor(text) for text in texts]
    if len(files) == 2 and all(sensors):
        check_camera_order(files)
        return from_euroc(files, sensors)  # type: ignore[arg-type]
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
