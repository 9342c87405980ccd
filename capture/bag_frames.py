"""Frames of a bag: its camera topics, an overview, and every message in log-time order.

The bag half of :func:`lenspair.capture.frames.iter_frames` (which yields
only the images), and what ``restore`` copies a bag with::

    from lenspair.capture.bag_frames import bag_overview, iter_bag_messages

    overview = bag_overview(Path("run.bag"))            # other image topics, frame count
    for item in iter_bag_messages(Path("run.bag"), cameras=("cam1",)):
        if item.frame is not None:                      # an image of a chosen camera
            use(item.frame.image)
        copy(item.connection, item.log_time_ns, item.raw)

A ``.bag`` file, a ROS 2 bag folder or a bare ``.db3``/``.mcap`` file is read
once from start to end (no seeking); the chosen cameras' image topics are
decoded (picked as in :func:`bag_camera_topics`, never a depth or disparity
topic, or passed as ``topics=(cam0, cam1)``). A message that cannot be
decoded is yielded with ``frame.image=None`` and ``frame.error`` set. A bag cut short yields its
complete messages (see :mod:`lenspair.capture.salvage`); that, or a bag that
stops part-way, is appended once to the ``problems`` list passed in.
"""

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lenspair.capture import rosbag
from lenspair.capture.depth_topics import camera_candidates, depth_note, depth_topics
from lenspair.capture.errors import CaptureError
from lenspair.capture.frame_types import BagMessage, InputFrame
from lenspair.capture.image_messages import decode_message, one_line
from lenspair.capture.recording import CAMERAS
from lenspair.capture.rigfile import CameraName


def bag_topics(
    path: Path, topics: tuple[str, str] | None = None
) -> tuple[list[str], dict[str, CameraName]]:
    """Every topic of a bag (any message type, sorted) and its cameras' (:func:`bag_camera_topics`).

    From one opening, as :func:`bag_overview`: a bag cut short has no index and
    is scanned whole by each opening.
    """
    reader = rosbag.open_bag(Path(path))
    try:
        return sorted(reader.topics), _camera_topics(reader, Path(path), topics)[0]
    finally:
        reader.close()


@dataclass(frozen=True)
class BagOverview:
    """What a command reading a bag's cameras says before the first frame.

    Attributes:
        others: one line per image topic that is neither camera's: a robot's
            bag often holds more than two (a camera's ``/compressed`` twin, a
            third camera), and a command that reads only the two cameras must
            say which it left alone, or dirty frames pass unnoticed. Depth
            topics left out by the automatic choice share one line.
        frames: image messages of the chosen cameras, from the bag's index
            (None for a bag cut short: it has no index).
        camera_topics: the chosen cameras' topics.
    """

    others: tuple[str, ...]
    frames: int | None
    camera_topics: tuple[str, ...] = ()

    def nothing_to_read(self, path: Path) -> str | None:
        """Why a command reading these cameras has no frame (None where the index counts some).

        A bag whose camera topics hold no message (a recording stopped before
        the cameras started) would otherwise run to an empty result and exit 0;
        a bag cut short has no index and is read as far as it goes.
        """
        if self.frames != 0:
            return None
        return f"{path}: no image messages on {', '.join(self.camera_topics)}"


def bag_overview(
    path: Path, cameras: Sequence[CameraName] = CAMERAS, topics: tuple[str, str] | None = None
) -> BagOverview:
    """The :class:`BagOverview` of a bag, from one opening (a cut bag is scanned once)."""
    reader = rosbag.open_bag(Path(path))
    try:
        image_topics = rosbag.image_topics(reader)
        named, depth = _camera_topics(reader, Path(path), topics)
        counts = None
        if (by_topic := rosbag.topic_counts(reader)) is not None:
            chosen = {topic for topic, camera in named.items() if camera in cameras}
            counts = sum(by_topic.get(topic, 0) for topic in chosen)
    finally:
        reader.close()
    by_camera = sorted(named.items(), key=lambda item: item[1])
    listed = ", ".join(f"{camera} {topic}" for topic, camera in by_camera)
    others = tuple(
        f"{path}: image topic {topic} left as recorded (camera topics: {listed}; "
        "--topics CAM0 CAM1 chooses others)"
        for topic in image_topics
        if topic not in named and topic not in depth
    )
    if depth:  # one line for them all: a RealSense bag's depth, aligned depth, ...
        note = depth_note(depth)
        others += (f"{path}: {note}; left as recorded (camera topics: {listed})",)
    chosen_topics = tuple(topic for topic, camera in by_camera if camera in cameras)
    return BagOverview(others, counts, chosen_topics)


def bag_camera_topics(path: Path, topics: tuple[str, str] | None = None) -> dict[str, CameraName]:
    """Image topics of a bag and the camera each stands for.

    ``topics=(cam0, cam1)`` names them. Otherwise depth and disparity topics
    are left out (:mod:`lenspair.capture.depth_topics`, by name or first message: a depth
    map restored or judged as an image is corrupted or nonsense); a single
    image topic left is the camera (called ``cam0``); with two or more,
    :func:`lenspair.capture.rosbag.select_topics` picks ``(cam0, cam1)``
    among the topics that do not extend another one (``<topic>/restored``
    topics written by ``restore --suffix`` are not cameras).

    Raises:
        CaptureError: no image topic, only depth topics, a named topic that is
            not an image topic, or an ambiguous choice (lists topics).
    """
    reader = rosbag.open_bag(Path(path))
    try:
        return _camera_topics(reader, Path(path), topics)[0]
    finally:
        reader.close()


def _camera_topics(
    reader: rosbag.BagReader, path: Path, topics: tuple[str, str] | None
) -> tuple[dict[str, CameraName], list[str]]:
    """The cameras' topics and the depth topics left out of the choice (none when named)."""
    if topics is not None:
        rosbag.check_chosen(tuple(topics), rosbag.topic_types(reader), path)
        return {topics[0]: "cam0", topics[1]: "cam1"}, []
    image_topics, empty = rosbag.image_topics_of(reader)
    if not image_topics and not empty:
        raise rosbag.no_image_topic(path, rosbag.topic_types(reader))
    if not image_topics:
        raise CaptureError(f"{path}: every image topic is empty: {', '.join(empty)}")
    cameras, depth = camera_candidates(image_topics, path, depth_topics(reader, image_topics))
    # A bag written by ``restore --suffix`` holds /cam1/image_raw and
    # /cam1/image_raw<suffix> (any suffix): the cameras are the original topics,
    # one of them a one-camera bag (its copy was taken for a second camera).
    originals = [t for t in cameras if not any(t.startswith(o + "/") for o in cameras)]
    if len(originals) == 1:
        return {originals[0]: "cam0"}, depth
    cam0, cam1 = rosbag.select_topics(originals, path, empty=empty)
    return {cam0: "cam0", cam1: "cam1"}, depth


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
    reader = rosbag.open_bag(path)
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
                t_ns = rosbag.stamp_ns(message)
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
        elif (note := rosbag.salvage_note(reader)) is not None and problems is not None:
            problems.append(f"{path}: {note}")
    finally:
        reader.close()
