"""Frames of any input, in order: an image, a folder of images, an EuRoC/ASL recording, a bag.

The one place that answers "give me every frame of this input", shared by
``lenspair restore`` and the anomaly detector (``detect``)::

    from lenspair.capture.frames import detect_input, iter_frames

    kind = detect_input(Path("run.bag"))                # "rosbag1"
    for frame in iter_frames(Path("run.bag"), cameras=("cam1",)):
        if frame.image is None:
            print(frame.name, "failed:", frame.error)   # recorded, not fatal
        else:
            use(frame.image)                            # uint8/uint16 (H, W) or (H, W, 3) RGB

Inputs (:func:`detect_input`):

* ``image``: one image file (``.png``, ``.tif``, ``.jpg``, ...).
* ``folder``: a folder of images, searched recursively; ``name`` is the path
  relative to the folder (so an output can keep the tree).
* ``folders``: a left/right folder recording (``left/`` and ``right/`` of
  images named by timestamp, :mod:`lenspair.capture.folders`); frames of the
  chosen cameras in time order, ``name`` relative to the recording folder.
  Left and right folders whose names carry no timestamps are a ``folder``.
* ``euroc``: an EuRoC/ASL recording (``mav0/cam{0,1}/data.csv``); frames of
  the chosen cameras in time order, ``name`` relative to the recording folder
  (``mav0/cam1/data/<t_ns>.png``).
* ``rosbag1`` / ``rosbag2``: a ``.bag`` file, a ROS 2 bag folder or a bare
  ``.db3``/``.mcap`` file, read once from start to end (no seeking); the
  chosen cameras' image topics are decoded (picked as in
  :func:`bag_camera_topics`, or passed as ``topics=(cam0, cam1)``).
  :func:`iter_bag_messages` gives every message (for copying a bag),
  :func:`iter_frames` only the images.

Anything else (another kind of file, a folder without images) is a one-line
:class:`~lenspair.capture.errors.CaptureError`. Frames are decoded one at a
time: a caller that needs the count up front (a progress bar) takes it from
:func:`frame_files` (files) rather than holding the frames.

A frame that cannot be read (corrupt file, undecodable message) is yielded
with ``image=None`` and ``error`` set, so the caller records it and goes on.
A bag cut short yields its complete messages (see
:mod:`lenspair.capture.salvage`); that, or a bag that stops part-way, is
appended once to the ``problems`` list passed in.
"""

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from lenspair.capture import euroc, folders, rosbag
from lenspair.capture.errors import CaptureError
from lenspair.capture.image_messages import IMAGE_TYPES, decode_message, one_line
from lenspair.capture.recording import CAMERAS, open_recording
from lenspair.capture.recording_types import DUPLICATE_TIMESTAMP, FrameProblem, is_ros1_bag
from lenspair.capture.rigfile import CameraName
from lenspair.core.errors import LenspairError
from lenspair.core.imageio import read_image

InputKind = Literal["image", "folder", "euroc", "folders", "rosbag1", "rosbag2"]
IMAGE_SUFFIXES = folders.IMAGE_SUFFIXES


@dataclass(frozen=True)
class InputFrame:
    """One frame of an input, decoded (or not, with the reason).

    Attributes:
        index: position among the frames yielded (0-based, input order).
        name: stable identifier; for files the path relative to the input
            folder (POSIX), for bags ``<topic>@<log_time_ns>#<occurrence>``.
        camera: ``cam0``/``cam1`` for recordings and bags, None otherwise.
        t_ns: timestamp (ns) when the input has one, else None.
        source: where it came from, for messages (file, or ``bag topic @ t``).
        image: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)`` RGB, or None
            when it could not be read.
        error: one line saying why ``image`` is None.
        log_time_ns: a bag message's receive time (ns), else None.
    """

    index: int
    name: str
    camera: CameraName | None
    t_ns: int | None
    source: str
    image: np.ndarray | None
    error: str | None = None
    log_time_ns: int | None = None


@dataclass(frozen=True)
class BagMessage:
    """One message of a bag, in log-time order, with its image decoded when chosen.

    Attributes:
        connection: the ``rosbags`` connection it was recorded on.
        log_time_ns: the bag's receive time (ns).
        raw: serialised bytes as stored (ROS1 or CDR).
        frame: the decoded frame when the message is an image of a chosen
            camera topic, else None.
        message: the deserialised message when ``frame`` is set (to re-encode).
    """

    connection: Any
    log_time_ns: int
    raw: bytes
    frame: InputFrame | None = None
    message: Any = None


MODEL_SUFFIXES = (".pt", ".onnx")
"""What models (restore's, detect's) are named; never an input."""


def detect_input(path: Path) -> InputKind:
    """Which kind of input ``path`` is.

    Raises:
        CaptureError: missing path, or neither an image, a folder nor a bag.
    """
    path = Path(path)
    if not path.exists():
        # a model named where the input goes: the arguments are the other way round
        # (a bundled model's name is found from any folder, so the message misled)
        hint = (
            " (the model comes first: MODEL INPUT)" if path.suffix.lower() in MODEL_SUFFIXES else ""
        )
        raise CaptureError(f"{path}: no such file or folder{hint}")
    if rosbag.is_bag(path):
        return "rosbag1" if is_ros1_bag(path) else "rosbag2"
    if path.is_file():
        if path.suffix.lower() in IMAGE_SUFFIXES:
            return "image"
        raise CaptureError(
            f"{path}: not an image ({', '.join(sorted(IMAGE_SUFFIXES))}) or a bag "
            f"({', '.join(sorted(rosbag.BAG_SUFFIXES))})"
        )
    if euroc.find_euroc_root(path) is not None and (
        (path / "mav0").is_dir() or all((path / camera).is_dir() for camera in CAMERAS)
    ):
        return "euroc"
    if _is_folder_recording(path):
        return "folders"
    return "folder"


def _is_folder_recording(path: Path) -> bool:
    """``left/`` + ``right/`` folders whose file names carry timestamps: a recording.

    Left and right folders of other images stay a plain folder (every image
    restored), as before such recordings were recognised; so do folders whose
    names give one camera two frames at one time (``run1_000001.png`` and
    ``run2_000001.png``: a frame index, not a timestamp), which as a recording
    would leave the second frame unrestored as a duplicate.
    """
    if not all((path / name).is_dir() for name in folders.FOLDER_NAMES.values()):
        return False
    try:
        recording = folders.read_folders(path)
    except CaptureError:
        return False
    return not any(problem.reason.startswith(DUPLICATE_TIMESTAMP) for problem in recording.problems)


def _folder_listing(folder: Path) -> tuple[list[Path], list[str]]:
    """Image files under ``folder`` (recursive, hidden entries skipped) and what it passes over.

    Both from one walk, sorted by path. The second list has one line per entry
    the images leave out unseen: a link to a folder is not followed (a link back
    up would never end) and a link to nothing has no image, so the commands
    reading a folder say so instead of leaving them out silently.
    """
    files: list[Path] = []
    passed_over: list[str] = []
    for entry in sorted(Path(folder).rglob("*")):
        if any(part.startswith(".") for part in entry.relative_to(folder).parts):
            continue
        if entry.is_symlink() and entry.is_dir():
            passed_over.append(
                f"{entry}: a link to a folder, not followed; its images are left out"
            )
        elif entry.is_symlink() and not entry.exists():
            passed_over.append(f"{entry}: a link to nothing ({os.readlink(entry)}); left out")
        elif entry.is_file() and entry.suffix.lower() in IMAGE_SUFFIXES:
            files.append(entry)
    return files, passed_over


def _image_topics(reader: rosbag.BagReader) -> list[str]:
    return sorted(name for name, info in reader.topics.items() if info.msgtype in IMAGE_TYPES)


def bag_image_topics(path: Path) -> list[str]:
    """Every image topic of a bag (``sensor_msgs/Image`` or ``CompressedImage``), sorted."""
    reader = rosbag._open(Path(path))
    try:
        return _image_topics(reader)
    finally:
        reader.close()


def bag_topics(
    path: Path, topics: tuple[str, str] | None = None
) -> tuple[list[str], dict[str, CameraName]]:
    """Every topic of a bag (any message type, sorted) and its cameras' (:func:`bag_camera_topics`).

    From one opening, as :func:`bag_overview`: a bag cut short has no index and
    is scanned whole by each opening.
    """
    reader = rosbag._open(Path(path))
    try:
        return sorted(reader.topics), _camera_topics(_image_topics(reader), Path(path), topics)
    finally:
        reader.close()


@dataclass(frozen=True)
class BagOverview:
    """What a command reading a bag's cameras says before the first frame.

    Attributes:
        others: one line per image topic that is neither camera's: a robot's
            bag often holds more than two (a camera's ``/compressed`` twin, a
            third camera), and a command that reads only the two cameras must
            say which it left alone, or dirty frames pass unnoticed.
        frames: image messages of the chosen cameras, from the bag's index
            (None for a bag cut short: it has no index).
    """

    others: tuple[str, ...]
    frames: int | None


def bag_overview(
    path: Path, cameras: Sequence[CameraName] = CAMERAS, topics: tuple[str, str] | None = None
) -> BagOverview:
    """The :class:`BagOverview` of a bag, from one opening (a cut bag is scanned once)."""
    reader = rosbag._open(Path(path))
    try:
        image_topics = _image_topics(reader)
        named = _camera_topics(image_topics, Path(path), topics)
        counts = None
        if rosbag.cut_note(reader) is None:
            chosen = {topic for topic, camera in named.items() if camera in cameras}
            counts = sum(int(c.msgcount) for c in reader.connections if c.topic in chosen)
    finally:
        reader.close()
    by_camera = sorted(named.items(), key=lambda item: item[1])
    listed = ", ".join(f"{camera} {topic}" for topic, camera in by_camera)
    others = tuple(
        f"{path}: image topic {topic} left as recorded (camera topics: {listed}; "
        "--topics CAM0 CAM1 chooses others)"
        for topic in image_topics
        if topic not in named
    )
    return BagOverview(others, counts)


def bag_camera_topics(path: Path, topics: tuple[str, str] | None = None) -> dict[str, CameraName]:
    """Image topics of a bag and the camera each stands for.

    ``topics=(cam0, cam1)`` names them. Otherwise a single image topic is the
    camera (called ``cam0``); with two or more,
    :func:`lenspair.capture.rosbag.select_topics` picks ``(cam0, cam1)``
    among the topics that do not extend another one (``<topic>/restored``
    topics written by ``restore --suffix`` are not cameras).

    Raises:
        CaptureError: no image topic, a named topic that is not an image
            topic, or an ambiguous choice (lists topics).
    """
    return _camera_topics(bag_image_topics(path), Path(path), topics)


def _camera_topics(
    image_topics: list[str], path: Path, topics: tuple[str, str] | None
) -> dict[str, CameraName]:
    if topics is not None:
        rosbag._check_chosen(tuple(topics), image_topics, path)
        return {topics[0]: "cam0", topics[1]: "cam1"}
    if not image_topics:
        raise CaptureError(f"{path}: no image topic (sensor_msgs/Image or CompressedImage)")
    if len(image_topics) == 1:
        return {image_topics[0]: "cam0"}
    # A bag written by ``restore --suffix`` holds /cam1/image_raw and
    # /cam1/image_raw/restored: the cameras are the original topics.
    originals = [t for t in image_topics if not any(t.startswith(o + "/") for o in image_topics)]
    cam0, cam1 = rosbag.select_topics(originals if len(originals) >= 2 else image_topics, path)
    return {cam0: "cam0", cam1: "cam1"}


def iter_frames(
    path: Path,
    cameras: Sequence[CameraName] = CAMERAS,
    problems: list[str] | None = None,
    topics: tuple[str, str] | None = None,
    dropped: list[FrameProblem] | None = None,
) -> Iterator[InputFrame]:
    """Every frame of ``path`` (any kind, see the module docstring), decoded.

    Args:
        path: the input.
        cameras: recordings and bags only: the cameras whose frames are wanted.
        problems: appended to (one line each) when a bag stops part-way, and
            for recordings, what their listing reported for the chosen cameras
            (images ``data.csv`` does not list, duplicate timestamps, ...).
        topics: bags only: the ``(cam0, cam1)`` image topics; None picks them.
        dropped: recordings only: appended to with the listing's problems that
            leave an image out (a file ``data.csv`` lists but that is missing,
            an image it does not list, a second file with a repeated
            timestamp), so that a caller can account for those frames too.

    Returns:
        An iterator of :class:`InputFrame` in input order (files sorted by
        path; recordings by camera then time; bags by log time), each decoded
        when reached.

    Raises:
        CaptureError: at the call, before any frame is read: the input cannot
            be opened at all (unknown layout, no images, no usable image
            topic), or ``topics`` given for a non-bag; a bag none of whose
            messages can be read raises when iterated.
    """
    kind = detect_input(path)
    if kind in ("rosbag1", "rosbag2"):
        messages = iter_bag_messages(path, cameras, problems, topics)
        return (item.frame for item in messages if item.frame is not None)
    if topics is not None:
        raise CaptureError(f"{path}: topics can only be chosen for bags, this is a {kind}")
    entries = _file_entries(path, kind, cameras, problems, dropped)
    return _iter_files(Path(path), kind, entries)


def frame_files(path: Path, kind: InputKind, cameras: Sequence[CameraName]) -> list[Path]:
    """The image files :func:`iter_frames` reads for a file-based input, in order."""
    return [file for file, _, _ in _file_entries(path, kind, cameras)]


def _file_entries(
    path: Path,
    kind: InputKind,
    cameras: Sequence[CameraName],
    problems: list[str] | None = None,
    dropped: list[FrameProblem] | None = None,
) -> list[tuple[Path, CameraName | None, int | None]]:
    """``(file, camera, t_ns)`` per frame; recordings take both from their listing.

    ``problems`` receives the recording's listing problems for ``cameras``,
    ``dropped`` those of them that leave a frame out.

    Raises:
        CaptureError: a folder without images (the caller asked for frames).
    """
    path = Path(path)
    if kind == "image":
        return [(path, None, None)]
    if kind == "folder":
        files, passed_over = _folder_listing(path)
        if not files:
            raise CaptureError(
                f"{path}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) found "
                "and not a recording or a bag"
            )
        if problems is not None:
            problems.extend(passed_over)
        return [(file, None, None) for file in files]
    recording = open_recording(path, cameras=cameras)
    mine = [p for p in recording.problems if p.camera is None or p.camera in cameras]
    if problems is not None:
        problems.extend(str(problem) for problem in mine)
    if dropped is not None:  # images, not rows of a listing: a frame each
        dropped.extend(
            problem
            for problem in mine
            if problem.dropped
            and problem.camera is not None
            and (problem.t_ns is not None or Path(problem.source).suffix.lower() in IMAGE_SUFFIXES)
        )
    return [
        (ref.source, camera, ref.t_ns) for camera in cameras for ref in recording.frames[camera]
    ]


def _iter_files(
    path: Path, kind: InputKind, entries: list[tuple[Path, CameraName | None, int | None]]
) -> Iterator[InputFrame]:
    base = path.parent if kind == "image" else path
    for index, (file, camera, t_ns) in enumerate(entries):
        name = file.relative_to(base).as_posix()
        try:
            image, error = read_image(file), None
        except LenspairError as exc:
            image, error = None, str(exc)
        yield InputFrame(index, name, camera, t_ns, str(file), image, error)


def iter_bag_messages(
    path: Path,
    cameras: Sequence[CameraName] = CAMERAS,
    problems: list[str] | None = None,
    topics: tuple[str, str] | None = None,
) -> Iterator[BagMessage]:
    """Every message of a bag in log-time order; chosen camera images decoded.

    Args:
        path: ``.bag`` file, ROS 2 bag folder, or ``.db3``/``.mcap`` file.
        cameras: cameras (see :func:`bag_camera_topics`) whose images are decoded.
        problems: appended to (one line) when reading stops part-way.
        topics: the ``(cam0, cam1)`` image topics; None picks them.

    Raises:
        CaptureError: at the call: the bag cannot be opened or its topics
            chosen; when iterated: no message can be read.
    """
    path = Path(path)
    named = bag_camera_topics(path, topics) if cameras else {}
    chosen = {topic: camera for topic, camera in named.items() if camera in cameras}
    return _bag_messages(path, chosen, problems)


def _bag_messages(
    path: Path, chosen: dict[str, CameraName], problems: list[str] | None
) -> Iterator[BagMessage]:
    reader = rosbag._open(path)
    index = 0
    read = 0
    occurrences: dict[tuple[str, int], int] = {}
    try:
        stream = reader.messages()
        while True:
            try:
                connection, log_time, raw = next(stream)
            except StopIteration:
                break
            except Exception as exc:  # storage backends raise assorted types when damaged
                if read == 0:
                    raise CaptureError(f"{path}: cannot read messages ({one_line(exc)})") from None
                if problems is not None:
                    problems.append(
                        f"{path}: reading stopped early after {read} messages ({one_line(exc)})"
                    )
                break
            read += 1
            raw = bytes(raw)
            camera = chosen.get(connection.topic)
            if camera is None:
                yield BagMessage(connection, log_time, raw)
                continue
            key = (connection.topic, log_time)
            occurrence = occurrences.get(key, 0)
            occurrences[key] = occurrence + 1
            name = f"{connection.topic}@{log_time}#{occurrence}"
            where = f"{path} {connection.topic} @ log time {log_time}"
            message: Any = None
            t_ns: int | None = None
            try:
                message = reader.deserialize(raw, connection.msgtype)
                t_ns = rosbag._stamp_ns(message)
                image, error = decode_message(connection.msgtype, message, where), None
            except CaptureError as exc:
                image, error = None, str(exc)
            except Exception as exc:  # corrupt serialisation: the frame only
                image, error = None, f"{where}: cannot deserialise ({one_line(exc)})"
            frame = InputFrame(index, name, camera, t_ns, where, image, error, log_time)
            index += 1
            yield BagMessage(connection, log_time, raw, frame, message)
        note = rosbag.cut_note(reader)
        if note is not None and problems is not None:
            problems.append(f"{path}: reading stopped early after {read} messages ({note})")
    finally:
        reader.close()
