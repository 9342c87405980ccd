"""Stereo recordings: one API over EuRoC/ASL folders, ROS bags and left/right folders.

Usage::

    from lenspair.capture.recording import open_recording, resolve_obstructed
    from lenspair.capture.pairing import pair_frames

    recording = open_recording(Path("runs/rain_01"))            # layout detected
    rig = resolve_obstructed(recording.path, override=None)     # rig.yaml / --obstructed
    result = pair_frames(recording.timestamps("cam0"), recording.timestamps("cam1"))
    for pair in result.pairs:
        left = recording.load(recording.frames["cam0"][pair.index0])   # lazy

Layouts recognised by :func:`open_recording` (``path`` may be any of these):

* **EuRoC/ASL**: ``<rec>/mav0/cam{0,1}/data.csv`` listing ``<t_ns>,<file>``
  rows, images in ``cam{0,1}/data/``, optional ``sensor.yaml``. ``path`` may
  be ``<rec>``, ``<rec>/mav0`` or any folder that directly holds ``cam0/`` and
  ``cam1/``. Without ``data.csv`` the image file names give the timestamps.
* **ROS1** ``.bag`` file, **ROS2** bag folder (``metadata.yaml`` + ``.db3`` or
  ``.mcap``) or a bare ``.db3``/``.mcap`` file, read with ``rosbags``. Two
  ``sensor_msgs/Image`` (or ``CompressedImage``) topics are chosen
  automatically (see :func:`lenspair.capture.rosbag.select_topics`) or passed as
  ``topics=(cam0_topic, cam1_topic)``. Timestamps are ``header.stamp``.
* **Folders**: ``<rec>/left/`` (cam0) and ``<rec>/right/`` (cam1) holding
  images whose file names carry the timestamp in ns (``1403636579763555584.png``,
  ``left_1403636579763555584.png``) or in seconds with a fraction
  (``1403636579.763555584.png``).

Contract of a :class:`Recording`:

* ``frames[camera]`` lists :class:`FrameRef` sorted by ``t_ns`` (ns, the
  camera's own clock), unique timestamps per camera, for ``cam0`` and ``cam1``;
  both lists are non-empty (else :class:`CaptureError` at open).
* ``problems`` records every frame that could not be listed (``dropped=True``:
  duplicate timestamp, missing file, unparsable ``data.csv`` row, undecodable
  message, bag truncated mid-way) and warnings about listed frames
  (``dropped=False``: timestamp going back in recording order). Nothing is
  dropped without a record.
* Pixels are read only by :meth:`Recording.load` / :func:`load_frame`; they
  return ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)`` RGB arrays (the
  :mod:`lenspair.core.pixels` convention) and raise :class:`ImageIOError` or
  :class:`CaptureError` naming the file (or bag, topic and timestamp) for
  corrupt or truncated data. A :class:`FrameRef` is a small picklable value
  holding all that is needed to reopen its source, so worker processes can call
  :func:`load_frame` directly (bag readers are cached per process).

The value types (:class:`FrameRef`, :class:`FrameProblem`, :class:`Recording`)
live in :mod:`lenspair.capture.recording_types` and are re-exported here; this
module is the reader dispatch.

``rig.yaml`` (which camera is obstructed) is found beside the recording by
:func:`find_rig_file`; :func:`resolve_obstructed` applies ``--obstructed``.
"""

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import get_args

import numpy as np

from lenspair.capture import euroc, folders, rosbag
from lenspair.capture.errors import CaptureError
from lenspair.capture.recording_types import (
    CAMERAS,
    SIMULATION_INCOMPLETE,
    FrameProblem,
    FrameRef,
    Layout,
    Recording,
    order_frames,
    recording_id_for,
)
from lenspair.capture.rigfile import RIG_FILE, CameraName, RigFile, read_rig_file
from lenspair.core.imageio import read_image

EXPECTED_LAYOUTS = (
    "an EuRoC/ASL folder (mav0/cam0/data.csv + mav0/cam0/data/<t_ns>.png, cam1 likewise), "
    "a ROS1 .bag file, a ROS2 bag folder (metadata.yaml + .db3/.mcap) or a .db3/.mcap file, "
    "or left/ + right/ folders of images named by timestamp (ns)"
)

__all__ = [
    "CAMERAS",
    "EXPECTED_LAYOUTS",
    "CameraName",
    "FrameProblem",
    "FrameRef",
    "Layout",
    "Recording",
    "find_rig_file",
    "load_frame",
    "open_recording",
    "order_frames",
    "present_cameras",
    "recording_id_for",
    "resolve_obstructed",
]


def load_frame(frame: FrameRef) -> np.ndarray:
    """Read the pixels of one frame (usable in worker processes).

    Returns:
        ``uint8``/``uint16`` array, ``(H, W)`` mono or ``(H, W, 3)`` RGB.

    Raises:
        ImageIOError: an image file is missing, corrupt or truncated.
        CaptureError: a bag message is missing, undecodable, truncated or has
            an unsupported encoding; the message names bag, topic and t_ns.
    """
    if frame.topic is None:
        return read_image(frame.source)
    return rosbag.load_bag_frame(frame)


def present_cameras(path: Path) -> tuple[CameraName, ...]:
    """The cameras whose folder a folder recording holds (EuRoC ``camN/``, ``left/``/``right/``).

    Both cameras for anything else (a bag, a path that is no recording):
    opening it says what is missing.
    """
    path = Path(path)
    if path.is_dir() and not rosbag.is_bag(path):
        root = euroc.find_euroc_root(path)
        if root is not None:
            return tuple(c for c in CAMERAS if (root / c).is_dir())
        if folders.is_left_right(path):
            return tuple(c for c in CAMERAS if (path / folders.FOLDER_NAMES[c]).is_dir())
    return CAMERAS


def open_recording(
    path: Path, topics: tuple[str, str] | None = None, cameras: Sequence[CameraName] = CAMERAS
) -> Recording:
    """List the frames of a stereo recording, detecting its layout.

    Args:
        path: a recording in one of the layouts of this module's docstring.
        topics: bags only: ``(cam0_topic, cam1_topic)``; None picks them.
        cameras: folder layouts only: the cameras to list, for a command that
            reads one camera of a recording that may hold only that one
            (:func:`present_cameras`); ``frames`` then has those keys alone.

    Returns:
        The :class:`Recording`; no pixels are read.

    Raises:
        CaptureError: path missing, layout unknown (the message lists the
            expected ones), a camera folder missing, a camera without frames,
            an unreadable bag, or ``topics`` given for a non-bag recording.
    """
    path = Path(path)
    if not path.exists():
        raise CaptureError(f"{path}: no such file or folder")
    if rosbag.is_bag(path):
        return rosbag.read_bag(path, topics)
    if topics is not None:
        raise CaptureError(f"{path}: topics can only be chosen for bags, this is a folder")
    _refuse_unfinished_simulation(path)
    if path.is_dir():
        root = euroc.find_euroc_root(path)
        if root is not None:
            return euroc.read_euroc(path, root, cameras)
        if folders.is_left_right(path):
            return folders.read_folders(path, cameras)
    hint = rosbag.storage_without_metadata(path) or _bags_inside(path)
    if hint is not None:
        raise CaptureError(f"{path}: unknown recording layout: {hint}")
    raise CaptureError(f"{path}: unknown recording layout; expected {EXPECTED_LAYOUTS}")


def _bags_inside(folder: Path) -> str | None:
    """What to pass instead of a folder of bags (a robot's ``bags/``), or None for no bag in it."""
    if not folder.is_dir():
        return None
    bags = sorted(entry.name for entry in folder.iterdir() if rosbag.is_bag(entry))
    if not bags:
        return None
    named = ", ".join(bags[:3]) + (f" and {len(bags) - 3} more" if len(bags) > 3 else "")
    return f"a folder of bags ({named}); pass each bag itself (one recording per run)"


def _refuse_unfinished_simulation(path: Path) -> None:
    """Refuse a recording ``lenspair simulate`` is still writing or was killed writing.

    Read anyway, a killed simulation gave a dataset of the frames it had
    written, with exit 0. ``path`` may be the simulation's folder or its ``mav0``.
    """
    for folder in (path, path.parent):
        if (folder / SIMULATION_INCOMPLETE).exists():
            raise CaptureError(
                f"{path}: an unfinished simulation ({folder / SIMULATION_INCOMPLETE} is there): "
                "wait for lenspair simulate to finish, or rerun it into that folder"
            )


def recording_places(recording_path: Path) -> list[Path]:
    """Where a recording's own files are looked for: its folder (if one), then beside it.

    "Beside" is taken on the absolute path (``os.path.abspath``, which also
    undoes ``..``): the recording given as ``.`` from inside ``mav0`` looked
    for ``./rig.yaml`` twice and missed the one beside ``mav0``.
    """
    path = Path(os.path.abspath(recording_path))
    if path.is_dir():
        return [path, path.parent]
    if rosbag.storage_suffix(path) and rosbag.storage_without_metadata(path.parent):
        # the storage file of a `ros2 bag record` killed before it wrote metadata.yaml,
        # passed as the error says: the rig's files lie beside its folder, as for the bag
        return [path.parent, path.parent.parent]
    return [path.parent]


def find_rig_file(recording_path: Path) -> Path | None:
    """``rig.yaml`` of a recording: inside its folder, else beside it (bag or folder)."""
    candidates = [place / RIG_FILE for place in recording_places(recording_path)]
    return next((c for c in candidates if c.is_file()), None)


def resolve_obstructed(recording_path: Path, override: str | None = None) -> RigFile:
    """Which camera is obstructed: ``rig.yaml`` beside the recording, or ``--obstructed``.

    Args:
        recording_path: the recording (folder, bag file or ROS2 bag folder).
        override: ``cam0``/``cam1`` from ``--obstructed``; it wins over
            ``rig.yaml`` (whose anomaly labels and calibration are kept), which
            may then leave ``obstructed`` out.

    Returns:
        The rig file contents (``calibration`` stays relative to the folder of
        the ``rig.yaml`` found, see :func:`find_rig_file`).

    Raises:
        CaptureError: ``override`` is not a camera name, or neither ``rig.yaml``
            nor ``override`` is available.
        ConfigError: ``rig.yaml`` exists but is malformed (names file and key),
            or leaves ``obstructed`` out and ``override`` is None.
    """
    if override is not None and override not in get_args(CameraName):
        raise CaptureError(f"--obstructed: expected cam0 or cam1, got {override!r}")
    camera: CameraName | None = None
    if override is not None:
        camera = "cam0" if override == "cam0" else "cam1"
    rig_path = find_rig_file(recording_path)
    if rig_path is None:
        if camera is None:
            raise CaptureError(
                f"{recording_path}: which camera is obstructed? Add {RIG_FILE} beside the "
                "recording (e.g. 'obstructed: cam1' and 'anomaly: [rain]') "
                "or pass --obstructed cam0|cam1"
            )
        return RigFile(obstructed=camera)
    rig = read_rig_file(rig_path, camera)  # with --obstructed, its obstructed may be left out
    if camera is not None and camera != rig.obstructed:
        return replace(rig, obstructed=camera)
    return rig
