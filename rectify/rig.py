"""Camera and stereo-rig models, and Kalibr camchain read/write.

Conventions:

* Intrinsics ``(fx, fy, cx, cy)`` in pixels; ``resolution`` is ``(width, height)``.
* ``distortion`` follows Kalibr: ``radtan`` -> ``(k1, k2, p1, p2)`` (OpenCV's
  first four coefficients), ``equidistant`` -> ``(k1, k2, k3, k4)`` (OpenCV's
  ``cv2.fisheye`` model).
* ``T_cam1_cam0`` is Kalibr's ``T_cn_cnm1`` for cam1: the 4x4 rigid transform
  taking a point expressed in cam0's frame to cam1's frame (metres). A cam1
  mounted rotated by 180 deg about its optical axis shows up here as a
  rotation; nothing else in lenspair special-cases it.
"""

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from lenspair.core.fsutil import atomic_write_text
from lenspair.rectify.errors import RectifyError

log = logging.getLogger(__name__)

DistortionModel = Literal["radtan", "equidistant"]


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with radtan or equidistant (fisheye) distortion.

    Attributes:
        intrinsics: ``(fx, fy, cx, cy)`` in pixels.
        distortion_model: ``"radtan"`` or ``"equidistant"``.
        distortion: four coefficients, see the module docstring.
        resolution: ``(width, height)`` in pixels.

    """

    intrinsics: tuple[float, float, float, float]
    distortion_model: DistortionModel
    distortion: tuple[float, float, float, float]
    resolution: tuple[int, int]

    def __post_init__(self) -> None:
        # plain Python numbers, whatever the caller passed (numpy scalars do not go to JSON)
        object.__setattr__(self, "intrinsics", tuple(float(v) for v in self.intrinsics))
        object.__setattr__(self, "distortion", tuple(float(v) for v in self.distortion))
        if any(int(side) != side for side in self.resolution):
            raise ValueError(f"resolution must be whole pixels, got {self.resolution}")
        object.__setattr__(self, "resolution", tuple(int(side) for side in self.resolution))
        values = (*self.intrinsics, *self.distortion)
        if not all(np.isfinite(values)):
            raise ValueError(f"camera parameters must be finite, got {values}")
        if self.intrinsics[0] <= 0 or self.intrinsics[1] <= 0:
            raise ValueError(f"focal lengths must be positive, got {self.intrinsics[:2]}")
        if self.resolution[0] <= 0 or self.resolution[1] <= 0:
            raise ValueError(f"resolution must be positive, got {self.resolution}")

    @property
    def K(self) -> np.ndarray:
        """3x3 camera matrix, float64."""
        fx, fy, cx, cy = self.intrinsics
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion coefficients in OpenCV's order and shape, float64."""
        if self.distortion_model == "equidistant":
            return np.asarray(self.distortion, dtype=np.float64).reshape(4, 1)
        return np.array([*self.distortion, 0.0], dtype=np.float64).reshape(1, 5)


def is_rotation(matrix: np.ndarray, atol: float) -> bool:
    """Whether a 3x3 ``matrix`` is a proper rotation: orthonormal within ``atol``, det +1."""
    return bool(np.allclose(matrix @ matrix.T, np.eye(3), atol=atol) and np.linalg.det(matrix) > 0)


@dataclass(frozen=True)
class StereoRig:
    """Two cameras and the rigid transform between them.

    Attributes:
        cam0: first camera (Kalibr's ``cam0``).
        cam1: second camera.
        T_cam1_cam0: 4x4 transform from cam0's frame to cam1's frame.
        topics: ROS topics of the two cameras, when known.
        topics_stated: whether the calibration stated them (a camchain's
            ``rostopic`` keys, a calibration from a bag); else ``topics`` are
            the conventional defaults, an assumption.

    """

    cam0: CameraModel
    cam1: CameraModel
    T_cam1_cam0: np.ndarray = field(repr=False)
    topics: tuple[str, str] = ("/cam0/image_raw", "/cam1/image_raw")
    topics_stated: bool = field(default=False, compare=False)

    def __post_init__(self) -> None:
        T = np.asarray(self.T_cam1_cam0, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"T_cam1_cam0: expected shape (4, 4), got {T.shape}")
        if not np.all(np.isfinite(T)):
            raise ValueError("T_cam1_cam0 contains NaN or Inf")
        if not is_rotation(T[:3, :3], atol=1e-5):
            raise ValueError("T_cam1_cam0: rotation part is not a proper rotation matrix")
        object.__setattr__(self, "T_cam1_cam0", T)

    @property
    def R(self) -> np.ndarray:
        """Rotation cam0 -> cam1 (3x3)."""
        return self.T_cam1_cam0[:3, :3].copy()

    @property
    def t(self) -> np.ndarray:
        """Translation cam0 -> cam1 (3,), metres."""
        return self.T_cam1_cam0[:3, 3].copy()

    @property
    def baseline_m(self) -> float:
        """Distance between the two optical centres, metres."""
        return float(np.linalg.norm(self.t))

    def camera(self, name: str) -> CameraModel:
        """Return ``cam0`` or ``cam1`` by name."""
        if name not in ("cam0", "cam1"):
            raise ValueError(f"camera name must be 'cam0' or 'cam1', got {name!r}")
        return self.cam0 if name == "cam0" else self.cam1


def _camera_to_kalibr(cam: CameraModel, topic: str, overlap: int) -> dict[str, Any]:
    return {
        "camera_model": "pinhole",
        "intrinsics": [float(v) for v in cam.intrinsics],
        "distortion_model": cam.distortion_model,
        "distortion_coeffs": [float(v) for v in cam.distortion],
        "resolution": [int(v) for v in cam.resolution],
        "rostopic": topic,
        "cam_overlaps": [overlap],
    }


def rig_to_kalibr(rig: StereoRig) -> dict[str, Any]:
    """The camchain mapping Kalibr writes for a two-camera rig."""
    cam1 = _camera_to_kalibr(rig.cam1, rig.topics[1], 0)
    cam1 = {"T_cn_cnm1": [[float(v) for v in row] for row in rig.T_cam1_cam0], **cam1}
    return {"cam0": _camera_to_kalibr(rig.cam0, rig.topics[0], 1), "cam1": cam1}


def kalibr_text(rig: StereoRig) -> str:
    """``rig`` as the text of a Kalibr camchain YAML file."""
    return yaml.safe_dump(rig_to_kalibr(rig), sort_keys=False, default_flow_style=None)


def write_kalibr(path: Path, rig: StereoRig) -> None:
    """Write ``rig`` as a Kalibr camchain YAML file (atomically)."""
    atomic_write_text(Path(path), kalibr_text(rig))


def _numbers(value: Any, where: str, count: int) -> tuple[float, ...]:
    """``count`` numbers from a YAML list; a string, a flag or another count is refused."""
    if not isinstance(value, list) or not all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    ):
        raise RectifyError(f"{where}: expected a list of {count} numbers, got {value!r}")
    if not all(math.isfinite(v) for v in value):
        raise RectifyError(f"{where}: camera parameters must be finite, got {value!r}")
    if len(value) != count:
        raise RectifyError(f"{where}: expected {count} values, got {len(value)}")
    return tuple(float(v) for v in value)


def camera_from_kalibr(data: Any, where: str) -> CameraModel:
    """One camera of a Kalibr camchain; errors start with ``where``.

    Keys: ``camera_model``, ``distortion_model``, ``intrinsics``,
    ``distortion_coeffs``, ``resolution``.
    """
    if not isinstance(data, dict):
        raise RectifyError(f"{where}: expected a mapping")
    try:
        model = data.get("camera_model", "pinhole")
        if model != "pinhole":
            raise RectifyError(f"{where}.camera_model: only 'pinhole' is supported, got {model!r}")
        dist_model = data["distortion_model"]
        if dist_model == "equi":
            dist_model = "equidistant"
        if dist_model not in ("radtan", "equidistant"):
            raise RectifyError(
                f"{where}.distortion_model: expected radtan or equidistant, got {dist_model!r}"
            )
        intrinsics = _numbers(data["intrinsics"], f"{where}.intrinsics", 4)
        coefficients = data["distortion_coeffs"]
        if dist_model == "radtan" and isinstance(coefficients, list) and len(coefficients) == 5:
            if coefficients[4] != 0:
                raise RectifyError(
                    f"{where}.distortion_coeffs: radtan has 4 (k1 k2 p1 p2); a fifth (k3) "
                    f"must be 0, got {coefficients[4]!r}"
                )
            coefficients = coefficients[:4]  # a zero k3, as the other readers drop it
        distortion = _numbers(coefficients, f"{where}.distortion_coeffs", 4)
        pixels = _numbers(data["resolution"], f"{where}.resolution", 2)
    except KeyError as exc:
        raise RectifyError(f"{where}: missing key {exc.args[0]!r}") from None
    if any(v != int(v) for v in pixels):
        raise RectifyError(f"{where}.resolution: expected whole pixels, got {list(pixels)}")
    resolution = (int(pixels[0]), int(pixels[1]))
    try:
        camera = CameraModel(intrinsics, dist_model, distortion, resolution)  # type: ignore[arg-type]
    except ValueError as exc:
        raise RectifyError(f"{where}: {exc}") from None
    refuse_implausible(camera, where)
    return camera


PIXEL_ASPECT_LIMIT = 2.5
"""A camera with fy/fx beyond this (or below its inverse) is none that is built.

Real cameras reach 2: one field of interlaced video has fy/fx near 0.5,
2x1 binning 0.5 or 2, anamorphic lenses squeeze 1.33-2x. A calibration fit
that goes past it diverged (:func:`lenspair.rectify.fit_checks.check_fit`);
a file that states it holds a typing error."""

MIN_FOCAL_FRACTION = 0.05
"""The least focal length, as a fraction of the image's longer side. A fisheye
seeing 220 degrees has about 0.26 (equidistant: half the side over 1.9 rad), a
pinhole's 157 degrees 0.1: below 0.05 no lens maps the image, and the number
is in another unit (millimetres) or of another camera."""


def refuse_implausible(camera: CameraModel, where: str, region: bool = False) -> None:
    """Refuse intrinsics that a calibration file may hold but no camera has.

    A file's fy typed as 4 instead of 400, a focal length in millimetres, or a
    calibration of the full sensor used for a binned stream loaded and
    rectified without a word: the rectified view was made of five raw rows, of
    a fraction of a pixel, or around a principal point in the image's corner.
    A stream read from a ``region`` of the sensor (a ROS camera_info ``roi``,
    already taken to its images) may well hold no principal point: a band
    read off-centre for frame rate; its principal point is not checked.

    Raises:
        RectifyError: one line naming ``where`` and the value.
    """
    fx, fy, cx, cy = camera.intrinsics
    width, height = camera.resolution
    if not 1.0 / PIXEL_ASPECT_LIMIT <= fy / fx <= PIXEL_ASPECT_LIMIT:
        raise RectifyError(
            f"{where}: fy/fx = {fy / fx:.3g} (fx {fx:g} px, fy {fy:g} px): no camera's pixels "
            f"are that far from square (limit {PIXEL_ASPECT_LIMIT:g}); check the intrinsics"
        )
    if min(fx, fy) < MIN_FOCAL_FRACTION * max(width, height):
        raise RectifyError(
            f"{where}: focal length {min(fx, fy):g} px in a {width}x{height} image: under "
            f"{MIN_FOCAL_FRACTION:g} of its longer side, wider than any lens sees; intrinsics "
            "are in pixels (a focal length in millimetres?)"
        )
    if not region and not (0 < cx < width and 0 < cy < height):
        raise RectifyError(
            f"{where}: principal point ({cx:g}, {cy:g}) is not inside the {width}x{height} "
            "image: the calibration is of another resolution (binning, a region of interest, "
            "a resized stream)?"
        )


MAX_BASELINE_M = 10.0
"""Larger than any stereo rig: a translation this long was written in millimetres."""

WIDE_BASELINE_M = 1.0
"""Wider than the rigs lenspair records with (two cameras behind one window, a few
centimetres apart): a baseline above it is warned of, as one in centimetres reads
(a RealSense's 5 cm written as 5)."""

MIN_BASELINE_M = 1e-4
"""A tenth of a millimetre: below it the rig is a single point (OpenCV's
stereoRectify then asserts); no stereo rig is built that tight."""


ROTATION_ATOL = 1e-3
"""How far from orthonormal a stated rotation may be (``R @ R.T`` against the
identity, largest element). A rotation written with 4 decimals is about 1e-4
off and is read as the nearest rotation; one written with 3 is up to about
1e-3 off, mostly read so too (the nearest rotation is within a milliradian of
what was meant) and now and then refused; one written with 2 is refused."""


def orthonormality_error(rotation: np.ndarray) -> float:
    """Largest element of ``R @ R.T - I``: 0 for an exact rotation."""
    return float(np.abs(rotation @ rotation.T - np.eye(3)).max())


def checked_transform(matrix: np.ndarray, where: str) -> np.ndarray:
    """``T_cam1_cam0`` checked: 4x4, finite, a rotation, a rigid last row, a stereo baseline.

    Every calibration reader passes its extrinsic through here, so a zero
    (placeholder) baseline, one in millimetres, or a matrix that is no
    rotation, is one line naming the file, not an OpenCV assertion later. A
    baseline in centimetres reads as one of a few metres, which long-baseline
    rigs have: it is warned of (:data:`WIDE_BASELINE_M`), not refused. A
    rotation rounded where it was written (within :data:`ROTATION_ATOL`) is
    replaced by the nearest exact one (SVD), as rectification needs.

    Raises:
        RectifyError: naming ``where`` and what is wrong.
    """
    if matrix.shape != (4, 4):
        raise RectifyError(f"{where}: T_cam1_cam0 must be 4x4, got shape {matrix.shape}")
    baseline = float(np.linalg.norm(matrix[:3, 3]))
    if not np.isfinite(matrix).all():
        raise RectifyError(f"{where}: T_cam1_cam0 holds non-finite values")
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise RectifyError(f"{where}: T_cam1_cam0's last row is {matrix[3].tolist()}, not 0 0 0 1")
    rotation = matrix[:3, :3]
    if not is_rotation(rotation, atol=ROTATION_ATOL):
        raise RectifyError(
            f"{where}: T_cam1_cam0's rotation part is not a proper rotation matrix (R R^T "
            f"differs from the identity by up to {orthonormality_error(rotation):.2g}, "
            f"determinant {np.linalg.det(rotation):+.3g})"
        )
    if orthonormality_error(rotation) > 1e-9:  # rounded where it was written
        u, _, vt = np.linalg.svd(rotation)
        matrix = matrix.copy()
        matrix[:3, :3] = u @ vt  # det +1: checked above
    if baseline < MIN_BASELINE_M:
        raise RectifyError(
            f"{where}: baseline {baseline:g} m: the two cameras sit at one point, so the "
            "views cannot be rectified as a stereo pair; check the extrinsics (T_cn_cnm1)"
        )
    if baseline > MAX_BASELINE_M:
        raise RectifyError(
            f"{where}: baseline {baseline:g} is not plausible in metres (millimetres or "
            "centimetres?); translations must be in metres"
        )
    if baseline > WIDE_BASELINE_M:
        log.warning(
            "%s: baseline %g m, wider than two cameras behind one window; if the "
            "translation is in centimetres, write it in metres",
            where,
            baseline,
        )
    return matrix


def rig_from_kalibr(data: Any, source: str = "camchain") -> StereoRig:
    """Build a :class:`StereoRig` from a parsed Kalibr camchain mapping.

    Raises:
        RectifyError: missing cameras or keys, NaN values, bad transform; the
            message starts with ``source``.

    """
    if not isinstance(data, dict) or "cam0" not in data or "cam1" not in data:
        raise RectifyError(f"{source}: expected a Kalibr camchain with cam0 and cam1")
    cam0 = camera_from_kalibr(data["cam0"], f"{source}: cam0")
    cam1 = camera_from_kalibr(data["cam1"], f"{source}: cam1")
    try:
        T = np.asarray(data["cam1"]["T_cn_cnm1"], dtype=np.float64)
        if T.shape == (3, 4):  # [R | t], the last row implied
            T = np.vstack([T, [0.0, 0.0, 0.0, 1.0]])
        T = checked_transform(T, f"{source}: cam1.T_cn_cnm1")
        topics = (
            str(data["cam0"].get("rostopic", "/cam0/image_raw")),
            str(data["cam1"].get("rostopic", "/cam1/image_raw")),
        )
        stated = "rostopic" in data["cam0"] or "rostopic" in data["cam1"]
        return StereoRig(cam0, cam1, T, topics, stated)
    except KeyError:
        raise RectifyError(f"{source}: cam1.T_cn_cnm1 is missing") from None
    except ValueError as exc:
        raise RectifyError(f"{source}: cam1.T_cn_cnm1: {exc}") from None


def read_kalibr(path: Path) -> StereoRig:
    """Read a Kalibr camchain YAML file."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RectifyError(f"{path}: file not found") from None
    except yaml.YAMLError as exc:
        raise RectifyError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    return rig_from_kalibr(data, str(path))
