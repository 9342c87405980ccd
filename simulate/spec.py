"""Scene specs: the YAML that ``lenspair simulate`` renders into a stereo recording.

A scene spec is loaded with :func:`load_scene` through the strict loader of
:mod:`lenspair.core.config`, so an unknown key, a wrong type or a bad value is
reported with its dotted path (``planes[1].depth_m: expected float, got 'far'``).

Frames and units. The *world* frame is the rig *body* frame at time 0, and
the body frame is cam0's frame (x right, y down, z forward, metres). Planes
are placed in the world frame; ``depth_m`` is the distance along world z.
Angles are degrees; rotations ``(rx, ry, rz)`` apply about x, then y, then z
(``R = Rz @ Ry @ Rx``). Times are nanoseconds on the recording clock.

Example (see ``calib_samples/README.md`` for every key)::

    rig:
      baseline_m: 0.11
      cam0: {intrinsics: [350.0, 350.0, 359.5, 269.5], distortion_model: equidistant,
             distortion: [0.01, -0.003, 0.0, 0.0]}
      cam1: {intrinsics: [352.0, 351.5, 361.0, 268.0], distortion_model: equidistant,
             distortion: [0.012, -0.002, 0.0, 0.0], gain: 1.04}
    planes:
      - {texture: [astronaut, coffee, rocket, brick], depth_m: 60.0, tile_m: [80.0, 80.0]}
    motion: {velocity_mps: [0.8, 0.0, 0.0], yaw_amplitude_deg: 1.0}
    recording: {frames: 20, rate_hz: 20.0, jitter_us: 200.0, drop_probability: [0.0, 0.05]}
    obstructed:
      camera: cam1
      effects: {raindrops: {count: 40}, defocus: {}}
"""

import dataclasses
import logging
import types
import typing
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, Union, get_args, get_origin

from lenspair.core.config import MAX_SEED, load_dataclass, read_yaml
from lenspair.core.errors import ConfigError
from lenspair.simulate.boardspec import BoardSpec
from lenspair.simulate.effects.spec import EffectsSpec
from lenspair.simulate.rigspec import RigSpec
from lenspair.simulate.textures import check_texture

log = logging.getLogger(__name__)

CameraName = Literal["cam0", "cam1"]
Vector3 = tuple[float, float, float]


def _positive(name: str, value: float) -> None:
    if not value > 0:
        raise ValueError(f"{name}: expected > 0, got {value}")


MIN_DEPTH_M = 0.05
"""The nearest a plane may be: ``depth_m``'s least, and how near a camera may come to one
(:func:`lenspair.simulate.truth.plane_reached`)."""


@dataclass(frozen=True)
class PlaneSpec:
    """A textured plane of the scene.

    The plane's centre is at ``(center_xy_m[0], center_xy_m[1], depth_m)`` in
    the world frame; unrotated it faces the rig (normal along world z), its
    texture's x axis along world x and y axis along world y (down). A finite
    plane is a ``size_m`` rectangle with the texture stretched over it
    (``tile_m`` defaults to ``size_m``); an infinite plane (``size_m: null``)
    repeats the texture every ``tile_m`` metres (default ``depth_m`` square).

    Attributes:
        texture: a scikit-image sample name (see ``lenspair.simulate.textures.NAMES``)
            or an image path (relative to the spec file); a list makes a
            near-square mosaic of several images (richer for matching).
        depth_m: distance of the plane centre along world z, metres.
        center_xy_m: world ``(x, y)`` of the plane centre, metres.
        size_m: ``(width, height)`` of a finite plane, metres; ``None`` = infinite.
        tile_m: ``(width, height)`` covered by one copy of the texture, metres.
        rotation_deg: orientation of the plane, ``(rx, ry, rz)`` degrees.
        brightness: linear-light reflectance multiplier of the texture; above
            1 a bright surface (a sunlit sky, a lamp) exceeds full scale, which
            the camera clips once, after the glass: drops over it bloom to
            saturation as on a real lens.
        name: optional label, copied to ``truth/geometry.json``.

    """

    texture: str | tuple[str, ...]
    depth_m: float
    center_xy_m: tuple[float, float] = (0.0, 0.0)
    size_m: tuple[float, float] | None = None
    tile_m: tuple[float, float] | None = None
    rotation_deg: Vector3 = (0.0, 0.0, 0.0)
    brightness: float = 1.0
    name: str = ""

    def __post_init__(self) -> None:
        if not MIN_DEPTH_M <= self.depth_m <= 1e5:
            raise ValueError(f"depth_m: expected {MIN_DEPTH_M:g}..1e5 m, got {self.depth_m}")
        if isinstance(self.texture, tuple) and not self.texture:
            raise ValueError("texture: expected a name, a path or a non-empty list")
        # a plane is a physical thing in front of the rig: bounded sizes keep the
        # texture coordinates finite (1e300 m or 1e-38 m rendered black NaN frames)
        for name, value in (("size_m", self.size_m), ("tile_m", self.tile_m)):
            if value is not None and not all(1e-3 <= v <= 1e6 for v in value):
                raise ValueError(f"{name}: expected sizes in 1e-3..1e6 m, got {value}")
        if not all(abs(v) <= 1e6 for v in self.center_xy_m):
            raise ValueError(f"center_xy_m: expected |x|, |y| <= 1e6 m, got {self.center_xy_m}")
        if not 0.0 < self.brightness <= 100.0:  # 1e300 overflowed in linear light
            raise ValueError(f"brightness: expected 0 < brightness <= 100, got {self.brightness}")

    @property
    def textures(self) -> tuple[str, ...]:
        """The texture names/paths as a tuple (one element for a single texture)."""
        return (self.texture,) if isinstance(self.texture, str) else self.texture

    @property
    def texture_size_m(self) -> tuple[float, float]:
        """Metres covered by one copy of the texture, ``(width, height)``."""
        if self.tile_m is not None:
            return self.tile_m
        if self.size_m is not None:
            return self.size_m
        return (self.depth_m, self.depth_m)


@dataclass(frozen=True)
class MotionSpec:
    """Rig trajectory: constant velocity plus a small sinusoidal wobble.

    The body pose at time ``s`` seconds after the first frame is
    ``R = R_yaw(a_y sin(w s)) @ R_pitch(a_p sin(2 w s)) @ R_roll(a_r sin(3 w s))``
    (yaw about y, pitch about x, roll about z; ``w = 2 pi frequency_hz``)
    and ``c = start_m + velocity_mps * s``, so the rig starts level. With
    ``velocity_mps[2] == 0`` the rig translates parallel to a fronto-parallel
    far plane, so the plane's distance from the body origin (cam0) stays
    constant; only the wobble turns the plane in the camera frames (and moves
    cam1 by ``baseline * sin(angle)``, under a millimetre, along the view).

    Attributes:
        velocity_mps: world-frame velocity, metres per second.
        start_m: world position of the body origin at the first frame.
        yaw_amplitude_deg: yaw wobble amplitude, degrees.
        pitch_amplitude_deg: pitch wobble amplitude, degrees.
        roll_amplitude_deg: roll wobble amplitude, degrees.
        frequency_hz: wobble frequency.

    """

    velocity_mps: Vector3 = (0.0, 0.0, 0.0)
    start_m: Vector3 = (0.0, 0.0, 0.0)
    yaw_amplitude_deg: float = 0.0
    pitch_amplitude_deg: float = 0.0
    roll_amplitude_deg: float = 0.0
    frequency_hz: float = 0.5

    def __post_init__(self) -> None:
        for name in ("yaw_amplitude_deg", "pitch_amplitude_deg", "roll_amplitude_deg"):
            if not 0.0 <= getattr(self, name) <= 30.0:
                raise ValueError(f"{name}: expected 0..30 degrees, got {getattr(self, name)}")
        # a robot's sway, not a vibration: 1e308 overflowed to NaN poses and blank frames
        if not 0.0 <= self.frequency_hz <= 100.0:
            raise ValueError(f"frequency_hz: expected 0..100 Hz, got {self.frequency_hz}")
        # as the plane's centre: beyond, float32 rendering loses the texture (black frames)
        if not all(abs(v) <= 1e6 for v in self.start_m):
            raise ValueError(f"start_m: expected |x|, |y|, |z| <= 1e6 m, got {self.start_m}")
        if not all(abs(v) <= 100.0 for v in self.velocity_mps):
            raise ValueError(f"velocity_mps: expected |v| <= 100 m/s, got {self.velocity_mps}")


@dataclass(frozen=True)
class RecordingSpec:
    """Clock, length and imperfections of the recording.

    Frame ``k`` has the nominal time ``start_ns + round(k * 1e9 / rate_hz)``;
    each camera adds its own Gaussian jitter (clipped at 3 sigma) and drops
    the frame with its own probability, which leaves unpaired frames.

    Attributes:
        frames: number of nominal frames (``--frames`` overrides it).
        rate_hz: frame rate.
        start_ns: nominal time of frame 0, nanoseconds.
        jitter_us: standard deviation of the timestamp jitter, microseconds.
        drop_probability: per-camera probability ``(cam0, cam1)`` that a
            frame is missing.

    """

    frames: int = 20
    rate_hz: float = 20.0
    start_ns: int = 1_700_000_000_000_000_000
    jitter_us: float = 0.0
    drop_probability: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if not 1 <= self.frames <= 100_000:
            raise ValueError(f"frames: expected 1..100000, got {self.frames}")
        if not 0.1 <= self.rate_hz <= 1000.0:
            raise ValueError(f"rate_hz: expected 0.1..1000, got {self.rate_hz}")
        period_us = 1e6 / self.rate_hz
        # checked first: a jitter beyond it made start_ns look wrong
        if not 0.0 <= 3.0 * self.jitter_us < period_us / 4.0:
            raise ValueError(
                f"jitter_us: expected 0 <= 3 sigma < a quarter period "
                f"({period_us / 4.0:.0f} us), got {self.jitter_us}"
            )
        # jitter may move frame 0 up to 3 sigma earlier, and the last frame must
        # stay an int64 nanosecond count (timestamps are file names and data.csv)
        end_ns = self.start_ns + round(self.frames * period_us * 1e3) + round(3e3 * self.jitter_us)
        if self.start_ns < 3e3 * self.jitter_us or end_ns >= 2**63:
            raise ValueError(
                f"start_ns: expected {3e3 * self.jitter_us:.0f} (3 sigma of jitter) .. "
                f"{2**63 - 1 - (end_ns - self.start_ns)} (the last frame within int64 ns), "
                f"got {self.start_ns}"
            )
        if not all(0.0 <= p < 1.0 for p in self.drop_probability):
            raise ValueError(
                f"drop_probability: expected values in [0, 1), got {self.drop_probability}"
            )


@dataclass(frozen=True)
class ObstructionSpec:
    """Which camera looks through the dirty glass, and what is on it.

    Attributes:
        camera: the obstructed camera; the other one is the clean reference.
        effects: the effects on its glass (:class:`EffectsSpec`); none listed
            means the obstructed frames equal ``truth/clear``.

    """

    camera: CameraName = "cam1"
    effects: EffectsSpec = field(default_factory=EffectsSpec)


MAX_RENDER_SAMPLES = 8192 * 8192
"""Most ray samples a frame (pixels x supersample^2): rendering takes about 175 bytes a
sample at its peak (4096x4096 once: 2.9 GB), so this is about 12 GB."""


@dataclass(frozen=True)
class SceneSpec:
    """A complete scene: rig, planes, motion, clock, obstruction, optional board.

    Attributes:
        rig: the two cameras and their mounting.
        planes: textured planes; the one with the largest ``depth_m`` is the
            *far plane* whose homography ``truth/geometry.json`` reports.
        background: linear-light grey seen where no plane is hit, ``[0, 1]``.
        motion: rig trajectory.
        recording: clock, frame count, jitter, drops.
        obstructed: obstructed camera and its glass effects.
        board: calibration board (board scenes); ``None`` otherwise.
        supersample: samples per pixel along each axis. Textures are always
            mip-mapped (pre-filtered to the pixel footprint); 2 also smooths
            plane silhouettes and sharpens board corners, at 4x the cost.
        seed: random seed (``--seed`` overrides it).

    """

    rig: RigSpec
    planes: tuple[PlaneSpec, ...] = ()
    background: float = 0.25
    motion: MotionSpec = field(default_factory=MotionSpec)
    recording: RecordingSpec = field(default_factory=RecordingSpec)
    obstructed: ObstructionSpec = field(default_factory=ObstructionSpec)
    board: BoardSpec | None = None
    supersample: int = 1
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.background <= 1.0:
            raise ValueError(f"background: expected 0..1, got {self.background}")
        if not 1 <= self.supersample <= 4:
            raise ValueError(f"supersample: expected 1..4, got {self.supersample}")
        if not 0 <= self.seed <= MAX_SEED:  # every command's --seed takes the same range
            raise ValueError(f"seed: expected 0 .. {MAX_SEED}, got {self.seed}")
        if not self.planes and self.board is None:
            raise ValueError("planes: a scene needs at least one plane or a board")
        for name in ("cam0", "cam1"):
            columns, rows = getattr(self.rig, name).resolution
            if columns * rows * self.supersample**2 > MAX_RENDER_SAMPLES:
                raise ValueError(
                    f"supersample: {self.supersample} at rig.{name}.resolution {columns}x{rows} "
                    f"is {columns * rows * self.supersample**2:.2e} samples a frame, over "
                    f"{MAX_RENDER_SAMPLES:.2e} (8192x8192 once; about 12 GB to render)"
                )
        camera = getattr(self.rig, self.obstructed.camera)
        width, height = camera.resolution
        try:
            # the glass optics left unset follow the obstructed camera (scene.yaml says them)
            effects = self.obstructed.effects.for_camera(camera.intrinsics[0])
            effects.check_memory((height, width))
        except ValueError as exc:
            raise ValueError(f"obstructed.effects.{exc}") from None
        resolved = dataclasses.replace(self.obstructed, effects=effects)
        object.__setattr__(self, "obstructed", resolved)  # frozen: settled once, here

    @property
    def far_plane_index(self) -> int | None:
        """Index of the far plane (largest ``depth_m``), ``None`` without planes."""
        if not self.planes:
            return None
        return max(range(len(self.planes)), key=lambda i: self.planes[i].depth_m)


def _optional_dataclass(tp: Any) -> type | None:
    """``X`` for a field typed ``X`` or ``X | None`` where ``X`` is a dataclass."""
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return tp
    if get_origin(tp) in (Union, types.UnionType):
        options = [a for a in get_args(tp) if a is not type(None)]
        if len(options) == 1:
            return _optional_dataclass(options[0])
    return None


def _check_optional_sections(cls: type, data: Any, prefix: str) -> None:
    """Load every nested dataclass section of ``data`` alone, deepest first.

    Raises:
        ConfigError: the first problem found, with its full dotted path.

    """
    if not isinstance(data, dict):
        return
    hints = typing.get_type_hints(cls)
    for item in dataclasses.fields(cls):
        if item.name not in data:
            continue
        value, path, tp = data[item.name], f"{prefix}{item.name}", hints[item.name]
        inner = _optional_dataclass(tp)
        if inner is not None and isinstance(value, dict):
            _check_optional_sections(inner, value, f"{path}.")
            load_dataclass(inner, value, path)
        elif get_origin(tp) is tuple and isinstance(value, list):
            element = _optional_dataclass(get_args(tp)[0])
            if element is None:
                continue
            for index, entry in enumerate(value):
                _check_optional_sections(element, entry, f"{path}[{index}].")


def load_scene(path: Path) -> SceneSpec:
    """Load and validate a scene spec YAML file.

    Texture names are checked here too (names of scikit-image samples, or
    image files relative to the spec's folder), so that a typo fails before
    any rendering.

    Raises:
        ConfigError: with the file name and the dotted key, e.g.
            ``scene.yaml: planes[0].texture: unknown texture 'bricks'; ...``.

    """
    path = Path(path)
    data = read_yaml(path)  # parse once: a syntax error is reported here, alone
    try:
        spec = load_dataclass(SceneSpec, data)
    except ConfigError as error:
        # The loader reports a bad optional section (``board:``, an effect) only as
        # "expected BoardSpec or NoneType"; look inside for the precise key first.
        try:
            _check_optional_sections(SceneSpec, data, "")
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
        raise ConfigError(f"{path}: {error}") from None
    for index, plane in enumerate(spec.planes):
        for name in plane.textures:
            problem = check_texture(name, path.parent)
            if problem is not None:
                raise ConfigError(f"{path}: planes[{index}].texture: {problem}")
    obstructed = data.get("obstructed") if isinstance(data, dict) else None
    effects = obstructed.get("effects") if isinstance(obstructed, dict) else None
    for name, value in (effects or {}).items() if isinstance(effects, dict) else ():
        if value is None:  # YAML reads a bare "dust:" as null: the effect stays off
            log.warning(
                "%s: obstructed.effects.%s is empty (null), which leaves %s off; write "
                "'%s: {}' for its defaults, or remove the key",
                path, name, name, name,
            )  # fmt: skip
    return spec


def with_overrides(
    spec: SceneSpec, frames: int | None = None, seed: int | None = None
) -> SceneSpec:
    """``spec`` with the command line's ``--frames`` / ``--seed`` applied (validated).

    Raises:
        ConfigError: ``--frames`` or ``--seed`` out of range, named as the
            option the user typed (the spec's own key means nothing there).

    """
    if frames is not None:
        try:
            recording = replace(spec.recording, frames=frames)
        except ValueError as exc:
            raise ConfigError(f"--frames {str(exc).removeprefix('frames: ')}") from None
        spec = replace(spec, recording=recording)
    if seed is not None:
        try:
            spec = replace(spec, seed=seed)
        except ValueError as exc:
            raise ConfigError(f"--seed {str(exc).removeprefix('seed: ')}") from None
    return spec
