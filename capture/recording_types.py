"""Value types of a stereo recording: frame references, problems, the recording.

These are the types every reader (:mod:`lenspair.capture.euroc`,
:mod:`lenspair.capture.folders`, :mod:`lenspair.capture.rosbag`) returns; the
dispatch that picks a reader is :mod:`lenspair.capture.recording`, which
re-exports every name here (import from there in application code).
"""

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from lenspair.capture.errors import CaptureError
from lenspair.capture.rigfile import CameraName

CAMERAS: tuple[CameraName, CameraName] = ("cam0", "cam1")
Layout = Literal["euroc", "rosbag1", "rosbag2", "folders"]


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
        """Human-readable location: the file, or ``bag topic @ t_ns (logged at ...)``.

        A bag frame names its log time too: two messages may carry one header
        stamp, and each must be told apart (and accounted for) on its own.
        """
        if self.topic is None:
            return str(self.source)
        nth = f", #{self.occurrence + 1} at that time" if self.occurrence else ""
        return f"{self.source} {self.topic} @ t_ns={self.t_ns} (logged {self.log_time_ns}{nth})"


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
            unique per camera, never empty; both cameras unless the recording
            was opened for some (``open_recording(cameras=...)``).
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
        for camera in self.frames or CAMERAS:
            if not self.frames.get(camera):
                dropped = [p for p in self.problems if p.camera in (camera, None) and p.dropped]
                detail = f"; first of {len(dropped)} problems: {dropped[0]}" if dropped else ""
                if self.topics is not None and not dropped:  # a bag: name the topic
                    topic = self.topics[CAMERAS.index(camera)]
                    detail = f": its topic {topic} holds no message"
                raise CaptureError(f"{self.path}: no {camera} frames could be listed{detail}")

    def swapped(self) -> "Recording":
        """The same recording with cam0 and cam1 exchanged (bags read with crossed topics).

        Cheaper than reading the bag again the other way round, which lists
        every message a second time.
        """
        other: dict[CameraName, CameraName] = {"cam0": "cam1", "cam1": "cam0"}
        return replace(
            self,
            frames={
                other[camera]: [replace(frame, camera=other[camera]) for frame in frames]
                for camera, frames in self.frames.items()
            },
            problems=[
                replace(problem, camera=other[problem.camera]) if problem.camera else problem
                for problem in self.problems
            ],
            topics=None if self.topics is None else (self.topics[1], self.topics[0]),
            sensor_files={other[camera]: path for camera, path in self.sensor_files.items()},
        )

    def timestamps(self, camera: CameraName) -> list[int]:
        """Sorted, unique timestamps (ns) of ``camera``'s frames."""
        return [frame.t_ns for frame in self.frames[camera]]

    def load(self, frame: FrameRef) -> np.ndarray:
        """Read the pixels of ``frame``; see :func:`lenspair.capture.recording.load_frame`."""
        # Imported here to break a circle: the dispatch module imports the
        # readers, which import these types.
        from lenspair.capture.recording import load_frame

        return load_frame(frame)


SIMULATION_INCOMPLETE = ".simulate-incomplete"
"""In a folder ``lenspair simulate`` is writing, or was killed while writing: its files
(frames, ``data.csv``, the rig and calibration files) are not all there yet."""

ACTIVE_BAG_SUFFIX = ".bag.active"
"""What ``rosbag record`` names a ROS 1 bag while it writes it: a recorder killed leaves
it so, unindexed (the index is written, and the name changed to ``.bag``, on close)."""


def is_ros1_bag(path: Path) -> bool:
    """True when ``path``'s name is a ROS 1 bag's: ``.bag``, or ``.bag.active``."""
    name = Path(path).name.lower()
    return name.endswith(".bag") or name.endswith(ACTIVE_BAG_SUFFIX)


def active_bag_stem(path: Path) -> str | None:
    """``run`` for a ``run.bag.active`` (what the bag would have been named), else None."""
    name = Path(path).name
    return name[: -len(ACTIVE_BAG_SUFFIX)] if name.lower().endswith(ACTIVE_BAG_SUFFIX) else None


def recording_id_for(path: Path) -> str:
    """Name of a recording: the folder name or the bag's stem (``mav0`` -> parent).

    ``run.bag.active`` is ``run``, as the bag it would have become.
    """
    resolved = Path(path).resolve()
    if (stem := active_bag_stem(resolved)) is not None and resolved.is_file():
        return stem
    if resolved.is_file():
        return resolved.stem
    if resolved.name == "mav0":
        return resolved.parent.name
    return resolved.name


DUPLICATE_TIMESTAMP = "duplicate timestamp"
"""How a frame dropped for its camera's repeated timestamp begins its problem's reason."""


def order_frames(
    camera: CameraName, frames: Iterable[FrameRef], problems: list[FrameProblem]
) -> list[FrameRef]:
    """Sort one camera's frames by time, dropping duplicate timestamps with a record.

    Args:
        camera: the camera the frames belong to.
        frames: the frames in recording order (``data.csv`` rows, bag log
            time, or already sorted for folders).
        problems: appended to: one dropped entry per repeated timestamp (the
            first occurrence is kept), one warning per frame whose timestamp
            goes back from the frame before it, and one warning per frame
            listed again with its timestamp (a repeated ``data.csv`` row: one
            frame, counted once), or with another one (the file counted once,
            at its first timestamp).

    Returns:
        Frames sorted by ``t_ns`` with unique timestamps.
    """
    kept: dict[int, FrameRef] = {}
    files: dict[str, FrameRef] = {}  # a file's first listing (a bag's messages are each unique)
    previous: FrameRef | None = None
    for frame in frames:
        earlier = files.get(frame.describe())
        if earlier is not None and earlier.t_ns != frame.t_ns:
            # one file under two timestamps gave one output name two frames: a fresh
            # restore counted the second as resumed, or wrote the file twice
            reason = (
                f"listed again with another timestamp (first at t_ns={earlier.t_ns}); "
                "counted once, at its first"
            )
            problems.append(
                FrameProblem(camera, frame.t_ns, frame.describe(), reason, dropped=False)
            )
            continue
        if frame.t_ns in kept:
            first = kept[frame.t_ns].describe()
            if first == frame.describe():
                reason = "listed twice with the same timestamp; counted once"
                problems.append(FrameProblem(camera, frame.t_ns, first, reason, dropped=False))
                continue
            problems.append(
                FrameProblem(
                    camera, frame.t_ns, frame.describe(), f"{DUPLICATE_TIMESTAMP} (kept {first})"
                )
            )
            continue
        if previous is not None and frame.t_ns < previous.t_ns:
            back_ms = (previous.t_ns - frame.t_ns) / 1e6
            reason = f"timestamp goes back by {back_ms:.3f} ms after t_ns={previous.t_ns}"
            problems.append(
                FrameProblem(camera, frame.t_ns, frame.describe(), reason, dropped=False)
            )
        kept[frame.t_ns] = frame
        files[frame.describe()] = frame
        # against the frame before it, not the latest time so far: one stamp far
        # in the future gave every later (good) frame this warning
        previous = frame
    return sorted(kept.values(), key=lambda f: f.t_ns)
