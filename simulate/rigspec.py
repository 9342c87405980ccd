"""The ``rig:`` section of a scene spec: two cameras and how cam1 is mounted.

Kept apart from :mod:`lenspair.simulate.spec` (which uses it) to keep modules small.
Conventions as there: metres, degrees, x right, y down, z forward.
"""

import math
from dataclasses import dataclass, field
from typing import Literal

Vector3 = tuple[float, float, float]


@dataclass(frozen=True)
class CameraSpec:
    """One camera of the rig.

    Attributes:
        intrinsics: ``(fx, fy, cx, cy)`` in pixels; pixel centres are at
            integer coordinates (OpenCV and Kalibr convention).
        distortion_model: ``radtan`` (OpenCV's ``k1, k2, p1, p2``) or
            ``equidistant`` (fisheye ``k1..k4``), as in Kalibr.
        distortion: the four coefficients.
        resolution: ``(width, height)`` in pixels.
        gain: exposure times gain relative to nominal, applied in linear
            light (``1.04`` = 4 % brighter).
        noise_std: standard deviation of additive Gaussian sensor noise in
            linear light, ``[0, 1]`` units (0 = noiseless).

    """

    intrinsics: tuple[float, float, float, float] = (350.0, 350.0, 359.5, 269.5)
    distortion_model: Literal["radtan", "equidistant"] = "equidistant"
    distortion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    resolution: tuple[int, int] = (720, 540)
    gain: float = 1.0
    noise_std: float = 0.0

    def __post_init__(self) -> None:
        fx, fy, cx, cy = self.intrinsics
        if not (1.0 <= fx <= 1e5 and 1.0 <= fy <= 1e5):
            raise ValueError(f"intrinsics: focal lengths expected 1..1e5 px, got {fx}, {fy}")
        if not (8 <= self.resolution[0] <= 8192 and 8 <= self.resolution[1] <= 8192):
            raise ValueError(f"resolution: expected 8..8192 pixels, got {self.resolution}")
        width, height = self.resolution
        # a principal point off the sensor by more than its size renders nothing a lens gives
        # (cx -1e6 rendered flat frames and a homography shifting by 1e6 px, exit 0)
        if not (-width <= cx <= 2 * width and -height <= cy <= 2 * height):
            raise ValueError(
                f"intrinsics: principal point ({cx}, {cy}) lies more than the image size off "
                f"the {width}x{height} sensor"
            )
        if not all(abs(k) <= 10.0 for k in self.distortion):  # 1e300 rendered background only
            raise ValueError(
                f"distortion: expected coefficients within -10..10, got {self.distortion}"
            )
        if not 0.0 < self.gain <= 100.0:  # 1e300 overflowed in linear light
            raise ValueError(f"gain: expected 0 < gain <= 100, got {self.gain}")
        if not 0.0 <= self.noise_std <= 0.5:
            raise ValueError(f"noise_std: expected 0..0.5, got {self.noise_std}")


@dataclass(frozen=True)
class RigSpec:
    """Two cameras and how cam1 is mounted relative to cam0.

    cam1's optical centre sits at ``baseline_m * baseline_direction`` in
    cam0's frame. Its orientation in cam0's frame is ``R_mis @ Rz(180 deg)``
    when ``cam1_rotated_180`` (as on real Alphasense units: its images are
    upside down relative to cam0's) and ``R_mis`` otherwise, where ``R_mis``
    is the small mounting error ``cam1_rotation_deg``.

    Attributes:
        baseline_m: distance between the optical centres, metres (required;
            about 0.11-0.14 m on Alphasense-like rigs).
        cam0: first camera.
        cam1: second camera.
        baseline_direction: direction of cam1's centre in cam0's frame
            (normalised; default to the right).
        cam1_rotation_deg: mounting error of cam1, ``(rx, ry, rz)`` degrees.
        cam1_rotated_180: cam1 is mounted rotated by 180 deg about its optical axis.
        color: ``mono`` images ``(H, W)`` or ``rgb`` images ``(H, W, 3)``.
        bit_depth: 8 (``uint8``) or 16 (``uint16``) bits per sample.

    """

    baseline_m: float
    cam0: CameraSpec = field(default_factory=CameraSpec)
    cam1: CameraSpec = field(default_factory=CameraSpec)
    baseline_direction: Vector3 = (1.0, 0.0, 0.0)
    cam1_rotation_deg: Vector3 = (0.0, 0.0, 0.0)
    cam1_rotated_180: bool = False
    color: Literal["mono", "rgb"] = "mono"
    bit_depth: int = 8

    def __post_init__(self) -> None:
        if not 0.0 < self.baseline_m <= 2.0:
            raise ValueError(f"baseline_m: expected 0 < baseline <= 2 m, got {self.baseline_m}")
        if not all(math.isfinite(v) for v in self.baseline_direction):
            raise ValueError(
                f"baseline_direction: expected finite values, got {self.baseline_direction}"
            )
        if max(abs(v) for v in self.baseline_direction) < 1e-9:
            raise ValueError("baseline_direction: must not be the zero vector")
        if any(abs(a) > 20.0 for a in self.cam1_rotation_deg):
            angles = self.cam1_rotation_deg
            raise ValueError(f"cam1_rotation_deg: expected small angles (|a| <= 20), got {angles}")
        if self.bit_depth not in (8, 16):
            raise ValueError(f"bit_depth: expected 8 or 16, got {self.bit_depth}")
