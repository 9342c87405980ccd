"""The files of a simulated recording beside its images: calibration, labels and truth.

:func:`write_metadata` writes them once every frame is rendered
(:func:`lenspair.simulate.recording.simulate_recording`): each camera's
``data.csv`` and ``sensor.yaml``, the true ``camchain.yaml``, ``rig.yaml``,
the resolved ``scene.yaml`` and ``truth/geometry.json`` (schema in
:mod:`lenspair.simulate.truth`), the last built from one :func:`frame_record`
per frame.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.core.config import to_plain
from lenspair.core.fsutil import atomic_write_json, atomic_write_text
from lenspair.rectify.rig import CameraModel, StereoRig, write_kalibr
from lenspair.simulate import boards, truth
from lenspair.simulate.camera import project
from lenspair.simulate.euroc import camera_folder, write_data_csv, write_sensor_yaml
from lenspair.simulate.scene import Plane
from lenspair.simulate.spec import SceneSpec
from lenspair.simulate.transforms import invert_transform, transform_points

CAMERAS = ("cam0", "cam1")
"""The recording's camera folders (``mav0/cam0``, ``mav0/cam1``), in rig order."""


@dataclass(frozen=True)
class RecordingSetup:
    """What every frame of one simulation shares, and what its metadata describes.

    Attributes:
        spec: the scene as given.
        resolved_spec: ``spec`` with texture files as absolute paths, so that
            ``scene.yaml`` renders from anywhere.
        rig: the true stereo calibration.
        T_body_cams: body-from-camera transforms of cam0 and cam1, ``(4, 4)`` each.
        planes: the scene's planes, textured.
        clean: index of the clean camera (0 or 1).
        obstructed: index of the obstructed camera (``1 - clean``).

    """

    spec: SceneSpec
    resolved_spec: SceneSpec
    rig: StereoRig
    T_body_cams: tuple[np.ndarray, np.ndarray]
    planes: list[Plane]
    clean: int
    obstructed: int

    @property
    def cameras(self) -> tuple[CameraModel, CameraModel]:
        """The rig's two cameras, ``(cam0, cam1)``."""
        return self.rig.cam0, self.rig.cam1


def write_metadata(
    setup: RecordingSetup,
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


def frame_record(
    setup: RecordingSetup,
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


def _geometry(setup: RecordingSetup, frames: list[dict[str, Any]]) -> dict[str, Any]:
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
            # texture files by absolute path, as in scene.yaml: the path as typed was relative
            # to the spec's folder, so a re-render from scene.yaml recorded another name
            for i, (plane, s) in enumerate(
                zip(setup.planes, setup.resolved_spec.planes, strict=True)
            )
        ],
        "board": board,
        "frames": frames,
    }
