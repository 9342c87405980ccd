"""ROS1 and ROS2 bags through ``rosbags``: listing image topics and loading frames.

Accepted: a ROS1 ``.bag`` file (or ``.bag.active``, what a killed ``rosbag
record`` leaves: unindexed, so always read as a bag cut short), a ROS2 bag
folder (``metadata.yaml`` with ``.db3`` or ``.mcap`` storage) or a bare
``.db3``/``.mcap`` file. Messages of type ``sensor_msgs/msg/Image`` and
``sensor_msgs/msg/CompressedImage`` are read; their pixels are decoded by
:mod:`lenspair.capture.image_messages` (which lists the encodings). A frame's
timestamp is ``header.stamp``; the bag's receive (log) time is kept in the
:class:`FrameRef` to seek back to the message lazily.

Listing reads every message of the two topics once (deserialising only to
get the header). A bag cut short, which ``rosbags`` cannot open (or, for a
``.db3``, would open and fail part-way), is read up to its cut by
:mod:`lenspair.capture.salvage`: its complete messages are listed and the cut
is recorded as one problem naming the file and the byte reading stopped at.
If reading stops part-way for another reason, frames read so far are kept and
the stop is recorded the same way.

Open readers are cached per process (a few at a time) so that loading many
frames does not reopen the bag, and each topic is read forward by a cursor so
that loading them in order reads the bag once (:mod:`lenspair.capture.bag_cursor`);
a forked worker opens its own.
"""

import dataclasses
import re
from collections import Counter
from collections.abc import Collection, Mapping, Sequence
from contextlib import suppress
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.bag_cursor import OpenBags
from lenspair.capture.depth_topics import camera_candidates, depth_note, depth_topics
from lenspair.capture.errors import AmbiguousTopicsError, CaptureError
from lenspair.capture.image_messages import IMAGE_TYPES, decode_message, one_line
from lenspair.capture.recording_types import (
    ACTIVE_BAG_SUFFIX,
    FrameProblem,
    FrameRef,
    Layout,
    Recording,
    active_bag_stem,
    is_ros1_bag,
    order_frames,
    recording_id_for,
)
from lenspair.capture.rigfile import CameraName
from lenspair.capture.salvage import SalvagedBag, is_cut_db3, salvage_bag
from lenspair.capture.salvage_records import ROS1_MAGIC

K = TypeVar("K")

ROS2_STORAGE_SUFFIXES = frozenset({".db3", ".mcap"})
"""A ROS 2 bag's storage files, in its folder beside ``metadata.yaml`` or on their own."""
FILE_COMPRESSION_SUFFIX = ".zstd"
"""What ``ros2 bag record --compression-mode file`` adds to a storage file's name."""
BAG_SUFFIXES = frozenset({".bag", ACTIVE_BAG_SUFFIX, *ROS2_STORAGE_SUFFIXES})
"""How bag files are named (:func:`is_bag_name`): ``.bag.active`` is two suffixes, so
compare names with :func:`is_bag_name`, not ``Path.suffix`` with this set."""
BagReader = AnyReader | SalvagedBag


def storage_suffix(path: Path) -> str | None:
    """``.db3`` or ``.mcap`` for a ROS 2 bag's storage file, else None.

    Also for SQLite's side files (``run.db3-wal``) and a file compressed whole
    (``run_0.mcap.zstd``); not for ``notes.db3.txt``.
    """
    suffixes = [suffix.lower() for suffix in path.suffixes]
    if suffixes and suffixes[-1] == FILE_COMPRESSION_SUFFIX:
        suffixes.pop()
    last = suffixes[-1].split("-")[0] if suffixes else ""
    return last if last in ROS2_STORAGE_SUFFIXES else None


def is_bag_name(path: Path) -> bool:
    """True when ``path`` is named as a bag file is: one of :data:`BAG_SUFFIXES` ends it.

    By name only (nothing is read): what folder listings use to name the bags among
    their files, a killed recorder's ``.bag.active`` as well as a ``.bag``.
    """
    name = Path(path).name.lower()
    return any(name.endswith(suffix) for suffix in BAG_SUFFIXES)


def is_bag(path: Path) -> bool:
    """True for a ``.bag`` (or ``.bag.active``), ``.db3`` or ``.mcap`` file, or a ROS 2 bag folder.

    A ROS 2 bag folder is one with ``metadata.yaml``.
    """
    path = Path(path)
    if path.is_file():
        return is_bag_name(path)
    return path.is_dir() and (path / "metadata.yaml").is_file()


def storage_files(folder: Path) -> list[Path]:
    """The ``.db3``/``.mcap`` files directly in ``folder``, sorted (a ROS 2 bag's storage)."""
    return sorted(
        entry
        for entry in folder.iterdir()
        if entry.is_file() and entry.suffix.lower() in ROS2_STORAGE_SUFFIXES
    )


def storage_without_metadata(folder: Path) -> str | None:
    """What a folder of ROS 2 bag storage without ``metadata.yaml`` is, and what to do; else None.

    ``ros2 bag record`` writes ``metadata.yaml`` when it closes: killed hard, it
    leaves a folder of ``.db3``/``.mcap`` files that is no bag folder, and "not a
    bag" alone sent users looking for another cause.
    """
    if not folder.is_dir() or (folder / "metadata.yaml").exists():
        return None
    storage = [entry.name for entry in storage_files(folder)]
    if not storage:
        return None
    named = ", ".join(storage[:3]) + (f" and {len(storage) - 3} more" if len(storage) > 3 else "")
    return (
        f"not a bag folder: it holds ROS 2 bag storage ({named}) but no metadata.yaml (a "
        f"recording killed before it closed?); pass the storage file itself "
        f"({folder / storage[0]}) or run `ros2 bag reindex {folder}` to write metadata.yaml"
    )


COPY_SUFFIXES = frozenset({"compressed", "compressedDepth", "theora", "ffmpeg", "zstd", "restored"})
"""Last names of topics that copy the topic above them: image_transport's, and restore's own."""


def _parent(topic: str) -> str:
    return topic.rsplit("/", 1)[0]


def select_topics(
    image_topics: Sequence[str],
    bag: Path,
    depth: Collection[str] = (),
    empty: Sequence[str] = (),
) -> tuple[str, str]:
    """Choose the ``(cam0, cam1)`` topics among a bag's image topics.

    Depth and disparity topics are left out (those named so, and ``depth``:
    :func:`lenspair.capture.depth_topics.camera_candidates`): a depth map is no
    camera's image. Nor is a copy of a camera's topic (:data:`COPY_SUFFIXES`:
    ``<topic>/compressed``, ``<topic>/restored``).
    Topics naming ``cam0``/``cam1`` win, then ``left``/``right`` (left =
    cam0); otherwise exactly two image topics are taken in sorted order.
    ``empty`` names the image topics already left out as holding no message
    (:func:`image_topics_of`), for the error.

    Raises:
        CaptureError: fewer than two image topics besides depth topics, or
            more than two with no unambiguous cam0/cam1 or left/right pair;
            lists the topics found.
    """
    found, left_out = camera_candidates(image_topics, bag, depth)
    # image_transport's <topic>/compressed, restore's <topic>/restored: copies of a camera
    # (restore and detect chose the originals; capture-ingest and calibrate refused the
    # four topics of a stereo pair and its twins as ambiguous)
    copies = [t for t in found if t.rsplit("/", 1)[-1] in COPY_SUFFIXES and _parent(t) in found]
    found = [t for t in found if t not in copies]
    listing = ", ".join(found) or "none"
    if len(found) < 2:
        besides = f"; {depth_note(left_out)}" if left_out else ""
        besides += f"; copies of a camera left out: {', '.join(copies)}" if copies else ""
        besides += f"; empty image topics left out: {', '.join(empty)}" if empty else ""
        raise CaptureError(
            f"{bag}: need two image topics (sensor_msgs/Image or CompressedImage), "
            f"found {len(found)}: {listing}{besides}"
        )
    for first, second in (("cam0", "cam1"), ("left", "right")):
        firsts = [t for t in found if _mentions(t, first)]
        seconds = [t for t in found if _mentions(t, second)]
        if len(firsts) == 1 and len(seconds) == 1 and firsts != seconds:
            return firsts[0], seconds[0]
    if len(found) == 2:
        return found[0], found[1]
    raise AmbiguousTopicsError(
        f"{bag}: cannot tell which of {len(found)} image topics are cam0 and cam1 "
        f"({listing}); name them with --topics CAM0 CAM1",
        tuple(found),
    )


def read_bag(path: Path, topics: tuple[str, str] | None = None) -> Recording:
    """List the frames of two image topics of a bag.

    Args:
        path: ``.bag``, ``.db3``/``.mcap`` file, or ROS2 bag folder.
        topics: ``(cam0_topic, cam1_topic)``; None chooses with
            :func:`select_topics`.

    Raises:
        CaptureError: the bag cannot be opened or read at all, a topic is
            missing or not an image topic, or a camera has no frames.
    """
    path = Path(path)
    reader = open_bag(path)
    try:
        available = topic_types(reader)
        candidates, empty = image_topics_of(reader)
        depth = [] if topics is not None else depth_topics(reader, candidates)
        try:
            if topics is None and not candidates and not empty:
                raise no_image_topic(path, available)
            chosen = select_topics(candidates, path, depth, empty) if topics is None else topics
            check_chosen(chosen, available, path)
        except CaptureError as exc:
            note = cut_note(reader)  # a cut may have left out a topic's first record
            if note is not None:
                exc.args = (f"{exc}; {note}",)  # the same error, its attributes kept
            raise
        cameras: dict[str, CameraName] = {chosen[0]: "cam0", chosen[1]: "cam1"}
        problems: list[FrameProblem] = []
        if depth:  # said once: logged and kept in report.json by capture-ingest
            problems.append(FrameProblem(None, None, str(path), depth_note(depth), dropped=False))
        listed = _timed_by_log(_list_messages(reader, path, cameras, problems), path, problems)
        note = cut_note(reader)
        if note is not None:
            read = {camera: len(frames) for camera, frames in listed.items()}
            reason = f"reading stopped early ({note}); frames read before: {read}"
            problems.append(FrameProblem(None, None, str(path), reason))
        elif (note := salvage_note(reader)) is not None:
            problems.append(FrameProblem(None, None, str(path), note, dropped=False))
    finally:
        with suppress(Exception):
            reader.close()
    frames = {camera: order_frames(camera, listed[camera], problems) for camera in listed}
    layout: Layout = "rosbag1" if is_ros1_bag(path) else "rosbag2"
    return Recording(
        path, recording_id_for(path), layout, frames, problems, topics=(chosen[0], chosen[1])
    )


def load_bag_frame(frame: FrameRef) -> np.ndarray:
    """Read and decode the image message a bag :class:`FrameRef` points to.

    Returns:
        ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)`` RGB.

    Raises:
        CaptureError: the bag, topic or message is gone, or the message is
            corrupt, truncated or has an unsupported encoding; names bag,
            topic and t_ns.
    """
    if frame.topic is None or frame.log_time_ns is None:
        raise CaptureError(f"{frame.describe()}: not a bag frame")
    where = frame.describe()
    start = frame.log_time_ns
    with _CACHE.lock:
        reader = _CACHE.get(frame.source)
        connections = [c for c in reader.connections if c.topic == frame.topic]
        if not connections:
            raise CaptureError(f"{where}: topic not found in the bag")
        try:
            wanted = (start, frame.occurrence)
            found = _CACHE.message(frame.source, frame.topic, connections, wanted)
            if found is not None:
                message: Any = reader.deserialize(found[2], found[0].msgtype)
        except Exception as exc:  # rosbags and its storage backends raise assorted types
            raise CaptureError(f"{where}: cannot read message ({one_line(exc)})") from None
    if found is None:
        raise CaptureError(f"{where}: message not found at log time {start} ns")
    msgtype = found[0].msgtype
    # (a frame timed by its log time, as _timed_by_log does, has no stamp to check)
    if frame.t_ns != frame.log_time_ns and stamp_ns(message) != frame.t_ns:
        raise CaptureError(f"{where}: message at log time {start} has t_ns={stamp_ns(message)}")
    return decode_message(msgtype, message, where)


def close_bag_readers() -> None:
    """Close the bag readers this process keeps open for :func:`load_bag_frame`."""
    with _CACHE.lock:
        _CACHE.clear()


def open_bag(path: Path) -> BagReader:
    """Open a bag with ``rosbags``; one it cannot open is read up to its cut.

    Args:
        path: ``.bag`` file, ROS 2 bag folder, or ``.db3``/``.mcap`` file.

    Returns:
        An open reader (close it); for a bag cut short a salvaged one
        (:func:`cut_note` says where it stopped).

    Raises:
        CaptureError: neither ``rosbags`` nor salvage can read the bag.
    """
    if not is_ros1_bag(path) and path.is_file() and _starts_with(path, ROS1_MAGIC):
        # rosbags goes by the name: the salvage read it whole but called it cut short
        raise CaptureError(
            f"{path}: a ROS 1 bag (it starts with {ROS1_MAGIC.strip().decode()!r}) named "
            f"{path.suffix}; rename it to .bag"
        )
    store = Stores.ROS1_NOETIC if is_ros1_bag(path) else Stores.ROS2_HUMBLE
    # SQLite opens a cut .db3 and fails part-way without saying where: salvage it.
    failure = "the SQLite file is shorter than its header says"
    if active_bag_stem(path) is not None:  # never closed, so never indexed
        failure = "a recording never closed: rosbag record writes the index on close"
    elif not is_cut_db3(path):
        try:
            reader = AnyReader([path], default_typestore=get_typestore(store))
            reader.open()
        except Exception as exc:  # rosbags and its storage backends raise assorted types
            failure = one_line(exc)
        else:
            return reader
    if path.is_dir() and len(storage_files(path)) > 1:
        # a split bag: only its metadata.yaml says how its files go together
        raise CaptureError(
            f"{path}: cannot open bag ({failure}); its storage files are read through "
            f"metadata.yaml: run `ros2 bag reindex {path}` to write it again"
        )
    try:
        salvaged = salvage_bag(path)
    except (CaptureError, OSError) as exc:
        raise CaptureError(
            f"{path}: cannot open bag ({failure}); reading it record by record "
            f"found nothing to keep ({one_line(exc)})"
        ) from None
    salvaged.refused = failure
    return salvaged


def _starts_with(path: Path, magic: bytes) -> bool:
    with open(path, "rb") as file:
        return file.read(len(magic)) == magic


def _scans_one_file(reader: BagReader) -> bool:
    """Whether the reader's message queries share one file position (:class:`OpenBags`).

    rosbags reads an MCAP file without a chunk index (written without a
    summary, or without chunks) by scanning it through the reader's one file
    handle. Its storages are looked up by rosbags' attribute names; an MCAP
    storage whose index cannot be found that way counts as one that scans.
    """
    for part in getattr(reader, "readers", ()):  # a bag folder's storage holds its files'
        outer = getattr(part, "storage", None)
        for storage in getattr(outer, "storages", None) or [outer]:
            if hasattr(storage, "messages_scan") and not getattr(storage, "chunks", None):
                return True
    return False


_CACHE = OpenBags(size=4, opener=open_bag, one_query=_scans_one_file)


def cut_note(reader: BagReader) -> str | None:
    """One line saying where a bag cut short stopped, or None for a whole bag."""
    return reader.cut if isinstance(reader, SalvagedBag) and not reader.whole else None


def salvage_note(reader: BagReader) -> str | None:
    """One line for a whole bag that ``rosbags`` refused and was read record by record, else None.

    Such a bag lost nothing (a message definition naming a type it never
    defines, as rosjava writes them; an unreadable ``metadata.yaml``), but
    why ``rosbags`` refused it is worth a line: a split bag missing one of
    its files says so here.
    """
    if not isinstance(reader, SalvagedBag) or not reader.whole:
        return None
    return f"rosbags could not open the bag ({reader.refused}); {reader.cut}"


def topic_types(reader: BagReader) -> dict[str, str]:
    """Every topic of the bag and its message type (a type the bag does not say: "unknown")."""
    return {name: info.msgtype or "unknown type" for name, info in reader.topics.items()}


def topic_counts(reader: BagReader) -> dict[str, int] | None:
    """Messages per topic from the bag's index (or a whole scan); None for a bag cut short."""
    if cut_note(reader) is not None:
        return None
    return {name: int(info.msgcount) for name, info in reader.topics.items()}


def image_topics(reader: BagReader) -> list[str]:
    """Every image topic of the bag (``sensor_msgs`` Image or CompressedImage), sorted."""
    return sorted(name for name, info in reader.topics.items() if info.msgtype in IMAGE_TYPES)


def image_topics_of(reader: BagReader) -> tuple[list[str], list[str]]:
    """A bag's image topics that may hold a camera (sorted), and those left out as empty.

    A topic the index counts no message on is left out of the automatic
    choice: ``ros2 bag record -a`` often records a camera's raw topic empty
    (never published, or a QoS mismatch) beside its ``/compressed`` twin,
    which holds the frames. Where no topic counts any message (an empty
    bag, a storage that keeps no counts) or the bag is cut short, none is
    left out.
    """
    found = image_topics(reader)
    counts = topic_counts(reader)
    if not counts or not any(counts.values()):
        return found, []
    empty = [topic for topic in found if counts.get(topic, 0) == 0]
    return [topic for topic in found if topic not in empty], empty


def check_chosen(chosen: tuple[str, ...], available: Mapping[str, str], bag: Path) -> None:
    """Check that ``chosen`` names two different image topics of ``bag``.

    Args:
        chosen: the topics given (``--topics``).
        available: every topic of the bag and its message type.
        bag: the bag, for the message.

    Raises:
        CaptureError: not two different topics, or one that is not in the bag
            or not of an image type (says which, and lists the image topics).
    """
    images = sorted(name for name, msgtype in available.items() if msgtype in IMAGE_TYPES)
    listing = ", ".join(images) or f"none ({_all_topics(available)})"
    if len(chosen) != 2 or chosen[0] == chosen[1]:
        raise CaptureError(f"{bag}: need two different topics, got {chosen}")
    for topic in chosen:
        if topic not in available:
            raise CaptureError(f"{bag}: no topic {topic} in the bag; image topics: {listing}")
        if topic not in images:
            raise CaptureError(
                f"{bag}: {topic} is a {available[topic]}, not an image; image topics: {listing}"
            )


def no_image_topic(bag: Path, available: Mapping[str, str]) -> CaptureError:
    """The error for a bag without any image topic: it lists the topics the bag does hold."""
    return CaptureError(
        f"{bag}: no image topic (sensor_msgs/Image or CompressedImage); {_all_topics(available)}"
    )


def _all_topics(available: Mapping[str, str], most: int = 8) -> str:
    """The bag's topics with their types, for a bag holding no image topic (at most ``most``)."""
    if not available:
        return "the bag holds no topic"
    named = [f"{name} ({msgtype})" for name, msgtype in sorted(available.items())[:most]]
    more = f" and {len(available) - most} more" if len(available) > most else ""
    return "its topics: " + ", ".join(named) + more


def _list_messages(
    reader: BagReader, bag: Path, cameras: dict[str, CameraName], problems: list[FrameProblem]
) -> dict[CameraName, list[FrameRef]]:
    listed: dict[CameraName, list[FrameRef]] = {"cam0": [], "cam1": []}
    occurrences: Counter[tuple[str, int]] = Counter()
    connections = [c for c in reader.connections if c.topic in cameras]
    try:
        for connection, log_time, raw in reader.messages(connections):
            topic = connection.topic
            camera = cameras[topic]
            occurrence = occurrences[topic, log_time]
            occurrences[topic, log_time] += 1
            try:
                t_ns = stamp_ns(reader.deserialize(raw, connection.msgtype))
            except Exception as exc:  # a corrupt message must not end the listing
                reason = f"cannot deserialise message at log time {log_time} ({one_line(exc)})"
                problems.append(FrameProblem(camera, None, f"{bag} {topic}", reason))
                continue
            listed[camera].append(FrameRef(camera, t_ns, bag, topic, log_time, occurrence))
    except Exception as exc:  # storage backends raise assorted types on damaged files
        if not any(listed.values()):
            raise CaptureError(f"{bag}: cannot read messages ({one_line(exc)})") from None
        read = {camera: len(frames) for camera, frames in listed.items()}
        reason = f"reading stopped early ({one_line(exc)}); frames read before: {read}"
        problems.append(FrameProblem(None, None, str(bag), reason))
    return listed


def never_stamped(stamps: Mapping[K, Sequence[int]]) -> list[K]:
    """The cameras of more than one frame whose header stamps are all one value.

    A driver that never sets ``header.stamp`` (all 0) or sets it once: such
    a camera is timed by the bag's log time instead (``capture-ingest``,
    ``detect``).
    """
    return [camera for camera, seen in stamps.items() if len(seen) > 1 and len(set(seen)) == 1]


def _timed_by_log(
    listed: dict[CameraName, list[FrameRef]], bag: Path, problems: list[FrameProblem]
) -> dict[CameraName, list[FrameRef]]:
    """The frames timed by the bag's log time when a camera's header stamps are all one value.

    Some drivers never set ``header.stamp`` (all 0) or set it once: every
    frame but the first was then a "duplicate timestamp" and a recording
    came down to one frame. Both cameras then take the log time (one clock
    for both, so that pairing stays fair), and the bag's problems say so.
    """
    unset = never_stamped({c: [f.t_ns for f in frames] for c, frames in listed.items()})
    if not unset:
        return listed
    # by topic, not by cam0/cam1: a recording turned round (Recording.swapped) says the same
    firsts = sorted((str(listed[c][0].topic), listed[c][0].t_ns) for c in unset)
    said = ", ".join(f"{topic} {t_ns} ns" for topic, t_ns in firsts)
    reason = (
        f"every header.stamp of {said}: never set by the driver? Both cameras are timed "
        "by the bag's log time instead"
    )
    problems.append(FrameProblem(None, None, str(bag), reason, dropped=False))
    return {
        camera: [dataclasses.replace(f, t_ns=f.log_time_ns or 0) for f in frames]
        for camera, frames in listed.items()
    }


def stamp_ns(message: Any) -> int:
    """A deserialised message's ``header.stamp`` in nanoseconds."""
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _mentions(topic: str, word: str) -> bool:
    return re.search(rf"(?<![a-z0-9]){word}(?![0-9])", topic.lower()) is not None
