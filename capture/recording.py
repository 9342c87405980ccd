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
  automatically (see :func:`capture.rosbag.select_topics`) or passed as
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
  :mod:`lenspair.core.imageio` convention) and raise :class:`ImageIOError` or
  :class:`CaptureError` naming the file (or bag, topic and timestamp) for
  corrupt or truncated data. A :class:`FrameRef` is a small picklable value
  holding all that is needed to reopen its source, so worker processes can call
  :func:`load_frame` directly (bag readers are cached per process).

``rig.yaml`` (which camera is obstructed) is found beside the recording by
:func:`find_rig_file`; :func:`resolve_obstructed` applies ``--obstructed``.
"""

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, get_args

import numpy as np

from lenspair.capture.errors import CaptureError
from lenspair.capture.rigfile import RIG_FILE, CameraName, RigFile, read_rig_file
from lenspair.core.imageio import read_image

CAMERAS: tuple[CameraName, CameraName] = ("cam0", "cam1")
Layout = Literal["euroc", "rosbag1", "rosbag2", "folders"]

EXPECTED_LAYOUTS = (
    "an EuRoC/ASL folder (mav0/cam0/data.csv + mav0/cam0/data/<t_ns>.png, cam1 likewise), "
    "a ROS1 .bag file, a ROS2 bag folder (metadata.yaml + .db3/.mcap) or a .db3/.mcap file, "
    "or left/ + right/ folders of images named by timestamp (ns)"
)


@dataclass(frozen=True)
class FrameRef:
    """A reference to one image of a recording, cheap to keep and to pickle.

    Attributes:
        camera: ``cam0`` or ``cam1``.
        t_ns: capture timestamp in nanoseconds (file name, ``data.csv`` or
            ``header.stamp``).
        source: the image file, or the bag (``.bag`` file, ROS2 folder or
            ``.db3``/``.mcap`` file) holding the message.
        topic: bag frames only: the image topic.
        log_time_ns: bag frames only: the bag's receive time of the message
            (ns), used to seek to it.
        occurrence: bag frames only: index among the topic's messages that
            share ``log_time_ns`` (almost always 0).
    """

    camera: CameraName
    t_ns: int
    source: Path
    topic: str | None = None
    log_time_ns: int | None = None
    occurrence: int = 0

    @property
    def in_bag(self) -> bool:
        """True when the image is a message in a bag, False for an image file."""
        return self.topic is not None

    def describe(self) -> str:
        """Human-readable location: the file, or ``bag topic @ t_ns``."""
        if self.topic is None:
            return str(self.source)
        return f"{self.source} {self.topic} @ t_ns={self.t_ns}"


@dataclass(frozen=True)
class FrameProblem:
    """A frame that could not be listed, or a warning about a listed one.

    Attributes:
        camera: ``cam0``/``cam1``, or None when the problem concerns the whole
            source (e.g. a bag truncated mid-way).
        t_ns: timestamp (ns) of the frame when known.
        source: where: a file, ``data.csv:<line>``, or ``bag topic``.
        reason: one line saying what is wrong.
        dropped: True when the frame is NOT in ``Recording.frames``.
    """

    camera: CameraName | None
    t_ns: int | None
    source: str
    reason: str
    dropped: bool = True

    def __str__(self) -> str:
        return f"{self.source}: {self.reason}"


@dataclass(frozen=True)
class Recording:
    """The frames of both cameras of one recording, listed but not loaded.

    Attributes:
        path: the path given to :func:`open_recording`.
        recording_id: folder name or bag stem (``MH_01`` for ``MH_01/mav0``).
        layout: ``euroc``, ``rosbag1``, ``rosbag2`` or ``folders``.
        frames: ``cam0``/``cam1`` -> frames sorted by ``t_ns``, timestamps
            unique per camera, never empty.
        problems: frames not listed (``dropped``) and warnings, in the order met.
        topics: bags only: the ``(cam0, cam1)`` topics read.
        sensor_files: EuRoC only: ``sensor.yaml`` of each camera that has one.

    Raises:
        CaptureError: at construction, when a camera has no frames.
    """

    path: Path
    recording_id: str
    layout: Layout
    frames: dict[CameraName, list[FrameRef]]
    problems: list[FrameProblem] = field(default_factory=list)
    topics: tuple[str, str] | None = None
    sensor_files: dict[CameraName, Path] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for camera in CAMERAS:
            if not self.frames.get(camera):
                dropped = [p for p in self.problems if p.camera in (camera, None) and p.dropped]
                detail = f"; first of {len(dropped)} problems: {dropped[0]}" if dropped else ""
                raise CaptureError(f"{self.path}: no {camera} frames could be listed{detail}")

    def timestamps(self, camera: CameraName) -> list[int]:
        """Sorted, unique timestamps (ns) of ``camera``'s frames."""
        return [frame.t_ns for frame in self.frames[camera]]

    def load(self, frame: FrameRef) -> np.ndarray:
        """Read the pixels of ``frame``; see :func:`load_frame`."""
        return load_frame(frame)


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
    from lenspair.capture.rosbag import load_bag_frame  # imports rosbags only when needed

    return load_bag_frame(frame)


def open_recording(path: Path, topics: tuple[str, str] | None = None) -> Recording:
    """List the frames of a stereo recording, detecting its layout.

    Args:
        path: a recording in one of the layouts of this module's docstring.
        topics: bags only: ``(cam0_topic, cam1_topic)``; None picks them.

    Returns:
        The :class:`Recording`; no pixels are read.

    Raises:
        CaptureError: path missing, layout unknown (the message lists the
            expected ones), a camera folder missing, a camera without frames,
            an unreadable bag, or ``topics`` given for a non-bag recording.
    """
    # Readers are imported here, not at module level: they import this module's
    # types, and opening folders should not pay for importing rosbags.
    from lenspair.capture import euroc, folders, rosbag

    path = Path(path)
    if not path.exists():
        raise CaptureError(f"{path}: no such file or folder")
    if rosbag.is_bag(path):
        return rosbag.read_bag(path, topics)
    if topics is not None:
        raise CaptureError(f"{path}: topics can only be chosen for bags, this is a folder")
    if path.is_dir():
        root = euroc.find_euroc_root(path)
        if root is not None:
            return euroc.read_euroc(path, root)
        if folders.is_left_right(path):
            return folders.read_folders(path)
    raise CaptureError(f"{path}: unknown recording layout; expected {EXPECTED_LAYOUTS}")


def recording_id_for(path: Path) -> str:
    """Name of a recording: the folder name or the bag's stem (``mav0`` -> parent)."""
    resolved = Path(path).resolve()
    if resolved.is_file():
        return resolved.stem
    if resolved.name == "mav0":
        return resolved.parent.name
    return resolved.name


def order_frames(
    camera: CameraName, frames: Iterable[FrameRef], problems: list[FrameProblem]
) -> list[FrameRef]:
    """Sort one camera's frames by time, dropping duplicate timestamps with a record.

    Args:
        camera: the camera the frames belong to.
        frames: the frames in recording order (``data.csv`` rows, bag log
            time, or already sorted for folders).
        problems: appended to: one dropped entry per repeated timestamp (the
            first occurrence is kept) and one warning per frame whose timestamp
            goes back relative to an earlier one.

    Returns:
        Frames sorted by ``t_ns`` with unique timestamps.
    """
    kept: dict[int, FrameRef] = {}
    latest: FrameRef | None = None
    for frame in frames:
        if frame.t_ns in kept:
            first = kept[frame.t_ns].describe()
            problems.append(
                FrameProblem(
                    camera, frame.t_ns, frame.describe(), f"duplicate timestamp (kept {first})"
                )
            )
            continue
        if latest is not None and frame.t_ns < latest.t_ns:
            back_ms = (latest.t_ns - frame.t_ns) / 1e6
            reason = f"timestamp goes back by {back_ms:.3f} ms after t_ns={latest.t_ns}"
            problems.append(
                FrameProblem(camera, frame.t_ns, frame.describe(), reason, dropped=False)
            )
        kept[frame.t_ns] = frame
        if latest is None or frame.t_ns > latest.t_ns:
            latest = frame
    return sorted(kept.values(), key=lambda f: f.t_ns)


def find_rig_file(recording_path: Path) -> Path | None:
    """``rig.yaml`` of a recording: inside its folder, else beside it (bag or folder)."""
    path = Path(recording_path)
    candidates = [path / RIG_FILE] if path.is_dir() else []
    candidates.append(path.parent / RIG_FILE)
    return next((c for c in candidates if c.is_file()), None)


def resolve_obstructed(recording_path: Path, override: str | None = None) -> RigFile:
    """Which camera is obstructed: ``rig.yaml`` beside the recording, or ``--obstructed``.

    Args:
        recording_path: the recording (folder, bag file or ROS2 bag folder).
        override: ``cam0``/``cam1`` from ``--obstructed``; it wins over
            ``rig.yaml`` (whose anomaly labels and calibration are kept).

    Returns:
        The rig file contents (``calibration`` stays relative to the folder of
        the ``rig.yaml`` found, see :func:`find_rig_file`).

    Raises:
        CaptureError: ``override`` is not a camera name, or neither ``rig.yaml``
            nor ``override`` is available.
        ConfigError: ``rig.yaml`` exists but is malformed (names file and key).
    """
    if override is not None and override not in get_args(CameraName):
        raise CaptureError(f"--obstructed: expected cam0 or cam1, got {override!r}")
    rig_path = find_rig_file(recording_path)
    if rig_path is None:
        if override is None:
            raise CaptureError(
                f"{recording_path}: which camera is obstructed? Add {RIG_FILE} beside the "
                "recording (e.g. 'obstructed: cam1' and 'anomaly: [rain]') "
                "or pass --obstructed cam0|cam1"
            )
        camera: CameraName = "cam0" if override == "cam0" else "cam1"
        return RigFile(obstructed=camera)
    rig = read_rig_file(rig_path)
    if override is not None and override != rig.obstructed:
        return replace(rig, obstructed="cam0" if override == "cam0" else "cam1")
    return rig
