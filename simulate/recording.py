"""Render a scene spec into a EuRoC/ASL stereo recording with ground truth.

Output layout of ``simulate_recording(spec, DIR)``::

    DIR/mav0/cam0/data.csv            "#timestamp [ns],filename", rows "<t_ns>,<t_ns>.png"
    DIR/mav0/cam0/data/<t_ns>.png     cam0 images (the obstructed camera's with its effects)
    DIR/mav0/cam0/sensor.yaml         EuRoC sensor file (intrinsics, distortion, T_BS)
    DIR/mav0/cam1/...                 likewise
    DIR/rig.yaml                      obstructed camera, anomaly kinds, calibration: camchain.yaml
    DIR/camchain.yaml                 the TRUE calibration (Kalibr format)
    DIR/scene.yaml                    the resolved scene spec (after --frames/--seed)
    DIR/truth/clear/<t_ns>.png        obstructed camera through clean glass
    DIR/truth/mask/<t_ns>.png         effects footprint (uint8, 255 inside; zeros without effects)
    DIR/truth/geometry.json           homography, planes, poses, board corners (simulate.truth)

Images are ``uint8``/``uint16`` sRGB, ``(H, W)`` mono or ``(H, W, 3)`` RGB;
each is rendered in linear ``float32``, multiplied by the camera's gain,
encoded and quantised once. Each camera is rendered at its own (jittered)
timestamp; a dropped frame has no file and no ``data.csv`` row. The files
beside the images (calibration, labels, truth) are written by
:mod:`lenspair.simulate.recording_metadata`.

Randomness comes from ``np.random.SeedSequence(spec.seed)`` with one child
stream per purpose (clock, board poses, glass, glass changes, per-frame
noise), so the same spec and seed give byte-identical files.
"""

import functools
import logging
import os
import re
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from lenspair.capture.recording_types import SIMULATION_INCOMPLETE
from lenspair.core.fsutil import remove_path
from lenspair.core.imagewrite import write_image
from lenspair.core.leftovers import process_alive
from lenspair.core.progress import progress
from lenspair.simulate import boards
from lenspair.simulate.camera import ray_map
from lenspair.simulate.errors import SimulateError
from lenspair.simulate.euroc import camera_folder, image_name
from lenspair.simulate.labels import Seen, labels
from lenspair.simulate.motion import Clock, body_pose, make_clock
from lenspair.simulate.recording_metadata import (
    CAMERAS,
    RecordingSetup,
    frame_record,
    write_metadata,
)
from lenspair.simulate.render import GlassState, advance_glass, apply_glass_linear, sample_glass
from lenspair.simulate.scene import Plane, build_planes, render_view
from lenspair.simulate.sensor import expose, expose_through_glass
from lenspair.simulate.spec import SceneSpec
from lenspair.simulate.stereo import body_from_cameras, rig_from_spec
from lenspair.simulate.textures import NAMES, Texture, texture_file
from lenspair.simulate.truth import plane_reached

log = logging.getLogger(__name__)

_STREAMS = ("clock", "board", "glass", "glass_changes", "noise")


@dataclass(frozen=True)
class SimulationSummary:
    """What a simulation wrote.

    Attributes:
        out_dir: the recording folder.
        frames: nominal frames.
        images: images written per camera ``(cam0, cam1)``.
        seconds_per_pair: mean wall time to render, expose and obstruct one frame
            pair (file writes excluded).

    """

    out_dir: Path
    frames: int
    images: tuple[int, int]
    seconds_per_pair: float


INCOMPLETE = SIMULATION_INCOMPLETE
"""In OUT while a simulation runs: a rerun of a killed one starts it over (it is deterministic),
and the capture readers refuse the folder until it is gone."""


def _writer(marker: Path) -> int | None:
    """The process that wrote an :data:`INCOMPLETE` marker (None for a marker without one)."""
    try:
        match = re.match(r"pid (\d+):", marker.read_text())
    except OSError:
        return None
    return int(match[1]) if match else None


def _claiming(marker: Path) -> bool:
    """Whether ``marker`` is empty: made by a run that has yet to write its pid in it.

    A killed run's marker holds its pid (written with the marker, :func:`_claim`),
    so an empty one is a live run's between the two, not a killed run's to remove.
    """
    try:
        return marker.stat().st_size == 0
    except OSError:
        return False


def check_output_folder(out_dir: Path) -> None:
    """Refuse an output folder that exists with content (or is a file).

    A folder holding a killed simulation (its :data:`INCOMPLETE` marker is
    still there) is emptied instead: the same spec and seed give the same
    files, so the rerun simply starts again.

    Raises:
        SimulateError: one line naming the folder.

    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise SimulateError(f"{out_dir}: is a file, not a folder; choose a new or empty folder")
    if (out_dir / INCOMPLETE).is_file():
        if _claiming(out_dir / INCOMPLETE):
            raise SimulateError(
                f"{out_dir}: another simulate is claiming it this instant; choose another --out"
            )
        writer = _writer(out_dir / INCOMPLETE)
        # not killed but still writing (this process's own marker is of a failed attempt)
        if writer is not None and writer != os.getpid() and process_alive(writer):
            raise SimulateError(
                f"{out_dir}: another simulate (process {writer}) is writing it; wait for it or "
                f"choose another --out (if none runs, remove {out_dir / INCOMPLETE})"
            )
        log.warning("%s: a killed simulation; starting it again", out_dir)
        for child in out_dir.iterdir():
            remove_path(child)
        return
    if out_dir.exists() and any(out_dir.iterdir()):
        raise SimulateError(f"{out_dir}: output folder is not empty; choose a new or empty folder")


def _claim(out_dir: Path) -> None:
    """Write the :data:`INCOMPLETE` marker, refusing a folder claimed since it was checked.

    The folder was found empty before the spec was set up (a second or more):
    a second simulate started meanwhile wrote its marker over the first's, and
    both wrote their frames into one folder. The marker is created only where
    none is (``O_EXCL``), and the folder must still hold nothing else.

    Raises:
        SimulateError: another simulate is writing the folder, or one has filled it.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    text = f"pid {os.getpid()}: removed when the simulation is complete\n"
    for attempt in range(2):
        try:
            # made and written in two calls, not through a buffer written at close: another
            # run that reads it between the two finds it empty (_claiming), not a pid
            descriptor = os.open(out_dir / INCOMPLETE, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            try:
                os.write(descriptor, text.encode())
            finally:
                os.close(descriptor)
            break
        except FileExistsError:
            if attempt:
                message = f"{out_dir}: another simulate claimed it; choose another --out"
                raise SimulateError(message) from None
            check_output_folder(out_dir)  # a live writer is refused, a killed one's removed
    if any(child.name != INCOMPLETE for child in out_dir.iterdir()):
        (out_dir / INCOMPLETE).unlink()
        raise SimulateError(
            f"{out_dir}: another simulate filled it meanwhile; choose a new or empty folder"
        )


def _streams(seed: int) -> dict[str, np.random.SeedSequence]:
    children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
    return dict(zip(_STREAMS, children, strict=True))


def _seconds(t_ns: int, start_ns: int) -> float:
    return (int(t_ns) - int(start_ns)) * 1e-9


def simulate_recording(
    spec: SceneSpec, out_dir: Path, base_dir: Path = Path(".")
) -> SimulationSummary:
    """Render ``spec`` into ``out_dir`` (see the module docstring for the layout).

    Args:
        spec: the scene.
        out_dir: new or empty folder.
        base_dir: folder that relative texture paths are resolved against
            (the spec file's folder).

    Returns:
        A summary of what was written.

    Raises:
        SimulateError: non-empty output folder, every frame of a camera dropped,
            or no board pose fits.
        ConfigError: unknown texture.
        ImageIOError: unreadable texture file.

    """
    out_dir = Path(out_dir)
    check_output_folder(out_dir)
    streams = _streams(spec.seed)
    clock = make_clock(spec.recording, np.random.default_rng(streams["clock"]))
    for camera, dropped in zip(CAMERAS, clock.dropped.T, strict=True):
        if dropped.all():  # before anything is written: an empty camera is no recording
            raise SimulateError(
                f"{out_dir}: recording.drop_probability drops every one of the "
                f"{spec.recording.frames} frame(s) of {camera} with seed {spec.seed}: "
                "raise recording.frames or lower drop_probability"
            )
    # all that can refuse the spec (textures, board poses, planes) before anything is written
    setup = _setup(spec, Path(base_dir))
    poses = (
        (k, pose) for k in range(spec.recording.frames) for pose in _camera_poses(setup, clock, k)
    )
    if (reached := plane_reached(setup.planes, spec.far_plane_index, poses)) is not None:
        raise SimulateError(reached)
    renderer = _FrameRenderer(setup, clock, streams, out_dir)
    _claim(out_dir)
    for k in progress(range(spec.recording.frames), desc="simulate", unit="frame"):
        renderer.render(k)

    anomaly = labels(spec.obstructed.effects, renderer.seen, out_dir)
    write_metadata(setup, out_dir, renderer.written, renderer.records, anomaly)
    (out_dir / INCOMPLETE).unlink()
    images = (len(renderer.written[0]), len(renderer.written[1]))
    return SimulationSummary(
        out_dir=out_dir,
        frames=spec.recording.frames,
        images=images,
        seconds_per_pair=renderer.render_seconds / max(1.0, sum(images) / 2),
    )


def _channels(spec: SceneSpec) -> int:
    """Channels of the rig's images: 3 for RGB, 1 for mono."""
    return 3 if spec.rig.color == "rgb" else 1


def _setup(spec: SceneSpec, base_dir: Path) -> RecordingSetup:
    """The rig, the textured planes and the camera roles of ``spec``."""
    rig = rig_from_spec(spec.rig)
    obstructed = CAMERAS.index(spec.obstructed.camera)
    return RecordingSetup(
        spec=spec,
        resolved_spec=_absolute_textures(spec, base_dir),
        rig=rig,
        T_body_cams=body_from_cameras(rig),
        planes=build_planes(spec.planes, base_dir, _channels(spec)),
        clean=1 - obstructed,
        obstructed=obstructed,
    )


def _camera_poses(setup: RecordingSetup, clock: Clock, k: int) -> list[np.ndarray]:
    """Each camera's 4x4 world pose at its own timestamp of frame ``k``."""
    motion, start_ns = setup.spec.motion, setup.spec.recording.start_ns
    return [
        body_pose(motion, _seconds(clock.stamps_ns[k, c], start_ns)) @ setup.T_body_cams[c]
        for c in range(2)
    ]


def _absolute_textures(spec: SceneSpec, base_dir: Path) -> SceneSpec:
    """``spec`` with texture files named by absolute path (sample names stay names).

    ``scene.yaml`` is written into the recording; a texture path relative to
    the spec's own folder would not resolve from there.
    """

    def absolute(name: str) -> str:
        return name if name in NAMES else str(texture_file(name, base_dir).resolve())

    planes = tuple(
        replace(
            plane,
            texture=absolute(plane.texture)
            if isinstance(plane.texture, str)
            else tuple(absolute(name) for name in plane.texture),
        )
        for plane in spec.planes
    )
    return replace(spec, planes=planes)


class _FrameRenderer:
    """Renders, exposes and writes the frames of one simulation, and keeps what they gave.

    Attributes:
        written: timestamps of the images written, per camera ``(cam0, cam1)``, ns.
        records: the ``geometry.json`` entry of each frame rendered so far.
        seen: what the obstructed frames showed of each effect (its labels).
        render_seconds: wall time spent rendering and exposing, file writes excluded.

    """

    def __init__(
        self,
        setup: RecordingSetup,
        clock: Clock,
        streams: dict[str, np.random.SeedSequence],
        out_dir: Path,
    ) -> None:
        spec = setup.spec
        self.setup, self.clock, self.out_dir = setup, clock, out_dir
        self.channels = _channels(spec)
        self.dtype = np.uint16 if spec.rig.bit_depth == 16 else np.uint8
        self.board_poses: list[np.ndarray] = []
        self.board_texture: Texture | None = None
        if spec.board is not None:
            self.board_texture = boards.board_texture(spec.board, self.channels)
            board_rng = np.random.default_rng(streams["board"])
            self.board_poses = boards.sample_board_poses(
                spec.board, setup.cameras, setup.T_body_cams, spec.recording.frames, board_rng
            )
        self.ray_maps = tuple(ray_map(camera, spec.supersample) for camera in setup.cameras)
        effects = spec.obstructed.effects
        self.glass: GlassState | None = None
        self.glass_changes = np.random.default_rng(streams["glass_changes"])
        if effects.listed:
            width, height = setup.cameras[setup.obstructed].resolution
            rng = np.random.default_rng(streams["glass"])
            self.glass = sample_glass(effects, (height, width), rng)
        self.noise_streams = streams["noise"].spawn(spec.recording.frames)
        self.written: tuple[list[int], list[int]] = ([], [])
        self.records: list[dict[str, Any]] = []
        self.seen = Seen()
        self.render_seconds = 0.0

    def render(self, k: int) -> None:
        """Render and write frame ``k`` of each camera that did not drop it, and record it."""
        setup, clock = self.setup, self.clock
        spec = setup.spec
        start_ns = spec.recording.start_ns
        T_world_body = body_pose(spec.motion, _seconds(clock.nominal_ns[k], start_ns))
        T_world_cams = _camera_poses(setup, clock, k)
        frame_planes = list(setup.planes)
        T_world_board = None
        if spec.board is not None and self.board_texture is not None:
            T_world_board = T_world_body @ self.board_poses[k]
            frame_planes.append(boards.board_plane(spec.board, self.board_texture, T_world_board))
        noise_seeds = self.noise_streams[k].spawn(2)  # a generator from one draws the same noise
        for c in range(2):
            if not clock.dropped[k, c]:
                t_ns = int(clock.stamps_ns[k, c])
                self._view(c, t_ns, T_world_cams[c], frame_planes, noise_seeds[c])
        if self.glass is not None:
            self.glass = advance_glass(self.glass, self.glass_changes)
        stamps = (clock.nominal_ns[k], clock.stamps_ns[k], clock.dropped[k])
        self.records.append(
            frame_record(setup, k, stamps, T_world_body, T_world_cams, T_world_board)
        )

    def _view(
        self,
        c: int,
        t_ns: int,
        T_world_cam: np.ndarray,
        planes: list[Plane],
        noise_seed: np.random.SeedSequence,
    ) -> None:
        """Render camera ``c``'s view at ``t_ns``, expose it and write it.

        The obstructed camera's view is seen through the glass, and its clear
        view and the glass's footprint are written under ``truth/``.
        """
        spec = self.setup.spec
        started = time.perf_counter()
        linear = render_view(self.ray_maps[c], T_world_cam, planes, spec.background, self.channels)
        camera_spec = (spec.rig.cam0, spec.rig.cam1)[c]
        noise, gain = camera_spec.noise_std, camera_spec.gain
        if c == self.setup.obstructed:
            glass = self.glass

            def through(glass: GlassState | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                applied = (
                    None if glass is None else functools.partial(apply_glass_linear, glass=glass)
                )
                return expose_through_glass(linear, gain, noise, noise_seed, self.dtype, applied)

            clear, image, mask = through(glass)
            if glass is not None:
                self.seen.note(glass, clear, image, lambda other: through(other)[1])
            self.render_seconds += time.perf_counter() - started
            write_image(self.out_dir / "truth" / "clear" / image_name(t_ns), clear)
            write_image(self.out_dir / "truth" / "mask" / image_name(t_ns), mask)
        else:
            image = expose(linear, gain, noise, np.random.default_rng(noise_seed), self.dtype)
            self.render_seconds += time.perf_counter() - started
        write_image(camera_folder(self.out_dir, CAMERAS[c]) / "data" / image_name(t_ns), image)
        self.written[c].append(t_ns)
