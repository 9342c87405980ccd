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
timestamp; a dropped frame has no file and no ``data.csv`` row.

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
import yaml

from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.core.config import to_plain
from lenspair.core.fsutil import atomic_write_json, atomic_write_text, remove_path
from lenspair.core.imageio import write_image
from lenspair.core.leftovers import process_alive
from lenspair.core.progress import progress
from lenspair.rectify.rig import CameraModel, StereoRig, write_kalibr
from lenspair.simulate import boards, truth
from lenspair.simulate.camera import project, ray_map
from lenspair.simulate.errors import SimulateError
from lenspair.simulate.euroc import camera_folder, image_name, write_data_csv, write_sensor_yaml
from lenspair.simulate.motion import body_pose, make_clock
from lenspair.simulate.render import GlassState, advance_glass, apply_glass, sample_glass
from lenspair.simulate.scene import Plane, build_planes, render_view
from lenspair.simulate.sensor import expose, expose_through_glass
from lenspair.simulate.spec import SceneSpec
from lenspair.simulate.stereo import body_from_cameras, rig_from_spec
from lenspair.simulate.textures import NAMES
from lenspair.simulate.transforms import invert_transform, transform_points

log = logging.getLogger(__name__)

CAMERAS = ("cam0", "cam1")
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


INCOMPLETE = ".simulate-incomplete"
"""In OUT while a simulation runs: a rerun of a killed one starts it over (it is deterministic)."""


def _writer(marker: Path) -> int | None:
    """The process that wrote an :data:`INCOMPLETE` marker (None for a marker without one)."""
    try:
        match = re.match(r"pid (\d+):", marker.read_text())
    except OSError:
        return None
    return int(match[1]) if match else None


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


def _streams(seed: int) -> dict[str, np.random.SeedSequence]:
    children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
    return dict(zip(_STREAMS, children, strict=True))


def _seconds(t_ns: int, start_ns: int) -> float:
    return (int(t_ns) - int(start_ns)) * 1e-9


@dataclass(frozen=True)
class _Setup:
    """What every frame of one simulation shares."""

    spec: SceneSpec
    resolved_spec: SceneSpec  # texture files as absolute paths: scene.yaml renders from anywhere
    rig: StereoRig
    T_body_cams: tuple[np.ndarray, np.ndarray]
    planes: list[Plane]
    clean: int
    obstructed: int

    @property
    def cameras(self) -> tuple[CameraModel, CameraModel]:
        return self.rig.cam0, self.rig.cam1


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
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / INCOMPLETE).write_text(
        f"pid {os.getpid()}: removed when the simulation is complete\n"
    )
    rig = rig_from_spec(spec.rig)
    channels = 3 if spec.rig.color == "rgb" else 1
    dtype = np.uint16 if spec.rig.bit_depth == 16 else np.uint8
    obstructed = CAMERAS.index(spec.obstructed.camera)
    setup = _Setup(
        spec=spec,
        resolved_spec=_absolute_textures(spec, Path(base_dir)),
        rig=rig,
        T_body_cams=body_from_cameras(rig),
        planes=build_planes(spec.planes, Path(base_dir), channels),
        clean=1 - obstructed,
        obstructed=obstructed,
    )
    board_poses: list[np.ndarray] = []
    board_texture = None
    if spec.board is not None:
        board_texture = boards.board_texture(spec.board, channels)
        board_rng = np.random.default_rng(streams["board"])
        board_poses = boards.sample_board_poses(
            spec.board, setup.cameras, setup.T_body_cams, spec.recording.frames, board_rng
        )
    ray_maps = tuple(ray_map(camera, spec.supersample) for camera in setup.cameras)
    camera_specs = (spec.rig.cam0, spec.rig.cam1)
    effects = spec.obstructed.effects
    glass: GlassState | None = None
    glass_changes = np.random.default_rng(streams["glass_changes"])
    if effects.listed:
        width, height = setup.cameras[obstructed].resolution
        glass = sample_glass(effects, (height, width), np.random.default_rng(streams["glass"]))
    noise_streams = streams["noise"].spawn(spec.recording.frames)

    written: tuple[list[int], list[int]] = ([], [])
    changed = False  # whether the glass changed a pixel of any obstructed frame
    records: list[dict[str, Any]] = []
    render_seconds = 0.0
    start_ns = spec.recording.start_ns
    for k in progress(range(spec.recording.frames), desc="simulate", unit="frame"):
        T_world_body = body_pose(spec.motion, _seconds(clock.nominal_ns[k], start_ns))
        T_world_cams = [
            body_pose(spec.motion, _seconds(clock.stamps_ns[k, c], start_ns)) @ setup.T_body_cams[c]
            for c in range(2)
        ]
        frame_planes = list(setup.planes)
        T_world_board = None
        if spec.board is not None and board_texture is not None:
            T_world_board = T_world_body @ board_poses[k]
            frame_planes.append(boards.board_plane(spec.board, board_texture, T_world_board))
        noise_seeds = noise_streams[k].spawn(2)  # a generator from one draws the same noise
        for c in range(2):
            if clock.dropped[k, c]:
                continue
            t_ns = int(clock.stamps_ns[k, c])
            started = time.perf_counter()
            linear = render_view(
                ray_maps[c], T_world_cams[c], frame_planes, spec.background, channels
            )
            noise, gain = camera_specs[c].noise_std, camera_specs[c].gain
            if c == obstructed:
                through = None if glass is None else functools.partial(apply_glass, glass=glass)
                clear, image, mask = expose_through_glass(
                    linear, gain, noise, noise_seeds[c], dtype, through
                )
                changed = changed or not np.array_equal(image, clear)
                render_seconds += time.perf_counter() - started
                write_image(out_dir / "truth" / "clear" / image_name(t_ns), clear)
                write_image(out_dir / "truth" / "mask" / image_name(t_ns), mask)
            else:
                image = expose(linear, gain, noise, np.random.default_rng(noise_seeds[c]), dtype)
                render_seconds += time.perf_counter() - started
            write_image(camera_folder(out_dir, CAMERAS[c]) / "data" / image_name(t_ns), image)
            written[c].append(t_ns)
        if glass is not None:
            glass = advance_glass(glass, glass_changes)
        stamps = (clock.nominal_ns[k], clock.stamps_ns[k], clock.dropped[k])
        records.append(_frame_record(setup, k, stamps, T_world_body, T_world_cams, T_world_board))

    anomaly = effects.anomaly_kinds
    if anomaly and not changed:
        log.warning(
            "%s: the effects (%s) changed no pixel of any frame (too small or faint at this "
            "resolution and bit depth): rig.yaml labels the recording clean",
            out_dir,
            ", ".join(anomaly),
        )
        anomaly = ()
    _write_metadata(setup, out_dir, written, records, anomaly)
    (out_dir / INCOMPLETE).unlink()
    images = (len(written[0]), len(written[1]))
    return SimulationSummary(
        out_dir=out_dir,
        frames=spec.recording.frames,
        images=images,
        seconds_per_pair=render_seconds / max(1.0, sum(images) / 2),
    )


def _absolute_textures(spec: SceneSpec, base_dir: Path) -> SceneSpec:
    """``spec`` with texture files named by absolute path (sample names stay names).

    ``scene.yaml`` is written into the recording; a texture path relative to
    the spec's own folder would not resolve from there.
    """

    def absolute(name: str) -> str:
        return name if name in NAMES else str((base_dir / name).resolve())

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


def _write_metadata(
    setup: _Setup,
    out_dir: Path,
    written: tuple[list[int], list[int]],
    records: list[dict[str, Any]],
    anomaly: tuple[str, ...],
) -> None:
    """Write data.csv, sensor.yaml, camchain.yaml, rig.yaml, scene.yaml, geometry.json.

    ``anomaly`` is rig.yaml's labels: the effects' kinds, or none when they
    changed no pixel (a frame is clean whatever its spec listed).
    """
    spec = setup.spec
    for c, name in enumerate(CAMERAS):
        folder = camera_folder(out_dir, name)
        camera = setup.cameras[c]
        write_data_csv(folder / "data.csv", written[c])
        comment = f"lenspair simulate {name} ({camera.distortion_model})"
        rate = spec.recording.rate_hz
        write_sensor_yaml(folder / "sensor.yaml", camera, setup.T_body_cams[c], rate, comment)
    write_kalibr(out_dir / "camchain.yaml", setup.rig)
    rig_file = RigFile(
        obstructed=spec.obstructed.camera,
        anomaly=anomaly,
        calibration="camchain.yaml",
    )
    write_rig_file(out_dir / "rig.yaml", rig_file)
    atomic_write_text(out_dir / "scene.yaml", scene_yaml(setup.resolved_spec))
    atomic_write_json(out_dir / "truth" / "geometry.json", _geometry(setup, records))


def scene_yaml(spec: SceneSpec) -> str:
    """The spec as ``scene.yaml``: the effects it lists, and no null for those it does not.

    Loaded back it is the same spec; a ``null`` effect reads as off, and
    :func:`lenspair.simulate.spec.load_scene` warns of each (a bare ``dust:``
    meant as "dust with its defaults" is one).
    """
    plain = to_plain(spec)
    effects = plain["obstructed"]["effects"]
    plain["obstructed"]["effects"] = {k: v for k, v in effects.items() if v is not None}
    return yaml.safe_dump(plain, sort_keys=False, default_flow_style=None)


def _frame_record(
    setup: _Setup,
    index: int,
    stamps: tuple[np.int64, np.ndarray, np.ndarray],
    T_world_body: np.ndarray,
    T_world_cams: list[np.ndarray],
    T_world_board: np.ndarray | None,
) -> dict[str, Any]:
    """The ``frames[index]`` entry of ``geometry.json``."""
    nominal_ns, stamps_ns, dropped = stamps
    spec = setup.spec
    cameras = setup.cameras
    record: dict[str, Any] = {
        "index": index,
        "t_nominal_ns": int(nominal_ns),
        "T_world_body": truth.matrix(T_world_body),
        "homography": None,
        "far_plane_clean": None,
        "T_world_board": None if T_world_board is None else truth.matrix(T_world_board),
    }
    far_index = spec.far_plane_index
    if far_index is not None:
        H, normal, distance = truth.far_plane_homography(
            setup.planes[far_index],
            cameras[setup.clean].K,
            cameras[setup.obstructed].K,
            T_world_cams[setup.clean],
            T_world_cams[setup.obstructed],
        )
        record["homography"] = truth.matrix(H)
        record["far_plane_clean"] = {"normal": truth.vector(normal), "distance_m": distance}
    for c, name in enumerate(CAMERAS):
        corners = None
        if T_world_board is not None and spec.board is not None:
            T_cam_board = invert_transform(T_world_cams[c]) @ T_world_board
            points = transform_points(T_cam_board, boards.object_points(spec.board))
            corners = truth.matrix(project(cameras[c], points))
        record[name] = {
            "t_ns": int(stamps_ns[c]),
            "dropped": bool(dropped[c]),
            "T_world_cam": truth.matrix(T_world_cams[c]),
            "board_corners_px": corners,
        }
    return record


def _geometry(setup: _Setup, frames: list[dict[str, Any]]) -> dict[str, Any]:
    """The whole ``geometry.json`` document (schema in :mod:`lenspair.simulate.truth`)."""
    spec = setup.spec
    cameras = setup.cameras
    far_index = spec.far_plane_index
    far_plane = None
    if far_index is not None:
        far = setup.planes[far_index]
        far_plane = {
            "index": far_index,
            "name": spec.planes[far_index].name,
            "depth_m": spec.planes[far_index].depth_m,
            "normal_world": truth.vector(far.normal),
            "offset_m": far.offset_m,
        }
    board = None
    if spec.board is not None:
        points = boards.object_points(spec.board)
        charuco = spec.board.kind == "charuco"
        board = {
            "kind": spec.board.kind,
            "cols": spec.board.cols,
            "rows": spec.board.rows,
            "square_m": spec.board.square_m,
            "marker_m": spec.board.marker_size_m if charuco else None,
            "dictionary": spec.board.dictionary if charuco else None,
            "object_points": truth.matrix(points),
            "ids": list(range(points.shape[0])),
        }
    return {
        "format": truth.FORMAT,
        "convention": truth.CONVENTION,
        "clean": CAMERAS[setup.clean],
        "obstructed": CAMERAS[setup.obstructed],
        "K_clean": truth.matrix(cameras[setup.clean].K),
        "K_obstructed": truth.matrix(cameras[setup.obstructed].K),
        "homography": frames[0]["homography"] if frames else None,
        "baseline_m": setup.rig.baseline_m,
        "T_cam1_cam0": truth.matrix(setup.rig.T_cam1_cam0),
        "T_body_cam0": truth.matrix(setup.T_body_cams[0]),
        "T_body_cam1": truth.matrix(setup.T_body_cams[1]),
        "far_plane": far_plane,
        "planes": [
            truth.plane_record(i, plane, s.name, list(s.textures), s.depth_m)
            for i, (plane, s) in enumerate(zip(setup.planes, spec.planes, strict=True))
        ],
        "board": board,
        "frames": frames,
    }
