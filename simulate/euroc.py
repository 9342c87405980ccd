"""Writers for the EuRoC/ASL camera folders: ``data.csv`` and ``sensor.yaml``.

Layout: ``mav0/camN/data.csv`` with the header ``#timestamp [ns],filename``
and rows ``<t_ns>,<t_ns>.png``; images in ``mav0/camN/data/``; and
``mav0/camN/sensor.yaml`` in EuRoC's own style (``T_BS`` maps the sensor
frame to the body frame; ``distortion_model`` is ``radial-tangential`` or
``equidistant``, as in the EuRoC and Kalibr tools).
"""

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lenspair.core.fsutil import atomic_write_lines, atomic_write_text
from lenspair.rectify.rig import CameraModel

CSV_HEADER = "#timestamp [ns],filename"
EUROC_DISTORTION_NAMES = {"radtan": "radial-tangential", "equidistant": "equidistant"}


def camera_folder(root: Path, camera: str) -> Path:
    """``root/mav0/<camera>``."""
    return Path(root) / "mav0" / camera


def image_name(t_ns: int) -> str:
    """File name of the image taken at ``t_ns``."""
    return f"{int(t_ns)}.png"


def write_data_csv(path: Path, stamps_ns: Sequence[int]) -> None:
    """Write a camera's ``data.csv`` listing ``stamps_ns`` (increasing)."""
    rows = [f"{int(t)},{image_name(t)}" for t in stamps_ns]
    atomic_write_lines(Path(path), [CSV_HEADER, *rows])


def _number(value: float) -> str:
    """``value`` as a YAML 1.1 number, read back exactly by PyYAML.

    ``repr`` gives ``5e-05``, which YAML 1.1 (PyYAML's ``safe_load``) reads
    as a *string*: its float needs a dot, so the mantissa gets one
    (``5.0e-05``). Whole numbers below 1e16 are written as integers, and
    NaN and infinities as ``.nan`` and ``.inf``.
    """
    value = float(value)
    if not math.isfinite(value):
        return ".nan" if math.isnan(value) else ("-.inf" if value < 0 else ".inf")
    if value.is_integer() and abs(value) < 1e16:
        return str(int(value))
    mantissa, exponent, power = repr(value).partition("e")
    if exponent and "." not in mantissa:
        mantissa += ".0"
    return mantissa + exponent + power


def _list(values: Sequence[float] | np.ndarray) -> str:
    return "[" + ", ".join(_number(v) for v in values) + "]"


def write_sensor_yaml(
    path: Path, camera: CameraModel, T_body_sensor: np.ndarray, rate_hz: float, comment: str
) -> None:
    """Write a EuRoC-style camera ``sensor.yaml``.

    Args:
        path: destination.
        camera: intrinsics, distortion and resolution.
        T_body_sensor: 4x4 ``T_BS`` (sensor frame -> body frame), metres.
        rate_hz: nominal frame rate.
        comment: free text for the ``comment`` key.

    """
    fx, fy, cx, cy = camera.intrinsics
    text = "\n".join(
        [
            "# General sensor definitions.",
            "sensor_type: camera",
            f"comment: {comment}",
            "",
            "# Sensor extrinsics wrt. the body-frame.",
            "T_BS:",
            "  cols: 4",
            "  rows: 4",
            f"  data: {_list(np.asarray(T_body_sensor, dtype=np.float64).ravel())}",
            "",
            "# Camera specific definitions.",
            f"rate_hz: {_number(rate_hz)}",
            f"resolution: {_list(camera.resolution)}",
            "camera_model: pinhole",
            f"intrinsics: {_list((fx, fy, cx, cy))} #fu, fv, cu, cv",
            f"distortion_model: {EUROC_DISTORTION_NAMES[camera.distortion_model]}",
            f"distortion_coefficients: {_list(camera.distortion)}",
            "",
        ]
    )
    atomic_write_text(Path(path), text)
