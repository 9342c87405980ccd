"""Inputs for the restore tests: bags with image and non-image topics."""

import contextlib
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.core.imageio import read_image
from lenspair.model.inference.report import REPORT_NAME, RESTORE_LOCK
from tests.capture.ingest_helpers import frame_files, make_recording

IMAGE = "sensor_msgs/msg/Image"
STRING = "std_msgs/msg/String"


def write_bag(
    path: Path,
    kind: str,
    images: dict[str, list[tuple[int, np.ndarray]]],
    encoding: str = "mono8",
    stamp: int | None = None,
    compress_files: bool = False,
    cut: frozenset[int] = frozenset(),
    topic: str = "/{camera}/image_raw",
) -> Path:
    """A bag (``ros1``, ``db3`` or ``mcap``) with images on ``/<camera>/image_raw`` (``topic``).

    ``cut``: the times of messages whose pixel data is cut in half (undecodable).

    A ``/status`` ``std_msgs/String`` message follows every image, so copies of
    non-image topics are checked too. Log time = stamp + 1 ms; ``stamp`` set:
    every header carries it instead (a driver that never sets it).
    ``compress_files``: a ROS 2 bag's storage file compressed whole (zstd), as
    ``ros2 bag record --compression-mode file`` writes it.
    """
    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = store.types
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    bag = path.with_suffix(".bag") if kind == "ros1" else path
    writer: Any = Writer1(bag) if kind == "ros1" else Writer2(bag, version=9, storage_plugin=plugin)
    if compress_files:
        writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
    messages = sorted((t, camera, image) for camera, items in images.items() for t, image in items)

    def serialize(message: Any, msgtype: str) -> bytes:
        if kind == "ros1":
            return bytes(store.serialize_ros1(message, msgtype))
        return bytes(store.serialize_cdr(message, msgtype))

    with writer:
        connections = {
            camera: writer.add_connection(topic.format(camera=camera), IMAGE, typestore=store)
            for camera in sorted(images)
        }
        status = writer.add_connection("/status", STRING, typestore=store)
        for t_ns, camera, image in messages:
            said = t_ns if stamp is None else stamp
            time = types["builtin_interfaces/msg/Time"](sec=said // 10**9, nanosec=said % 10**9)
            extra = {"seq": 7} if kind == "ros1" else {}
            header = types["std_msgs/msg/Header"](stamp=time, frame_id=camera, **extra)
            pixels = image if image.ndim == 2 else image[:, :, ::-1] if "bgr" in encoding else image
            message = types[IMAGE](
                header=header,
                height=image.shape[0],
                width=image.shape[1],
                encoding=encoding,
                is_bigendian=0,
                step=image.shape[1] * image.itemsize * (1 if image.ndim == 2 else 3),
                data=np.frombuffer(np.ascontiguousarray(pixels).tobytes(), dtype=np.uint8),
            )
            if t_ns in cut:
                message.data = message.data[: message.data.size // 2]
            writer.write(connections[camera], t_ns + 1_000_000, serialize(message, IMAGE))
            text = types[STRING](data=f"frame {t_ns}")
            writer.write(status, t_ns + 2_000_000, serialize(text, STRING))
    return bag


def bag_from_recording(
    tmp_path: Path,
    kind: str,
    frames: int = 3,
    colour: bool = False,
    topic: str = "/{camera}/image_raw",
) -> Path:
    """A stereo bag from a simulated-style EuRoC recording, rig.yaml beside it (cam1)."""
    euroc = make_recording(tmp_path / "euroc", frames=frames, colour=colour)
    images = {
        camera: [(int(p.stem), read_image(p)) for p in frame_files(euroc, camera)]
        for camera in ("cam0", "cam1")
    }
    folder = tmp_path / "bags"
    folder.mkdir()
    write_rig_file(folder / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    return write_bag(folder / "run", kind, images, "rgb8" if colour else "mono8", topic=topic)


HEALTH = "my_msgs/msg/Health"
"""A vendor's message type: neither a Humble bag nor rosbags' type store defines it."""


def humble_bag(path: Path, images: list[tuple[int, np.ndarray]], vendor: bool = False) -> Path:
    """A ROS 2 Humble bag folder: metadata version 5, SQLite schema 3, no definitions or hashes.

    Mono8 images on ``/cam0/image_raw``, a ``/status`` string after each, and
    with ``vendor`` a ``/vendor/health`` message of :data:`HEALTH` too.
    Written with SQLite, as Humble's recorder lays it out (rosbags writes only
    versions 8 and 9).
    """
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg("string name\nfloat32 temperature\n", HEALTH))
    types = store.types
    topics = [("/cam0/image_raw", IMAGE), ("/status", STRING)]
    topics += [("/vendor/health", HEALTH)] if vendor else []
    path.mkdir(parents=True)
    database = path / f"{path.name}_0.db3"
    rows = []
    for t_ns, image in images:
        stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam0")
        message = types[IMAGE](
            header=header, height=image.shape[0], width=image.shape[1], encoding="mono8",
            is_bigendian=0, step=image.shape[1], data=image.reshape(-1),
        )  # fmt: skip
        rows.append((1, t_ns + 1, bytes(store.serialize_cdr(message, IMAGE))))
        text = types[STRING](data=f"frame {t_ns}")
        rows.append((2, t_ns + 2, bytes(store.serialize_cdr(text, STRING))))
        if vendor:
            health = types[HEALTH](name="cam0", temperature=40.5)
            rows.append((3, t_ns + 3, bytes(store.serialize_cdr(health, HEALTH))))
    with contextlib.closing(sqlite3.connect(database)) as db, db:
        db.executescript(
            "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);"
            "INSERT INTO schema VALUES(3, 'humble');"
            "CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,"
            " metadata TEXT NOT NULL);"
            "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,"
            " serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
            "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,"
            " timestamp INTEGER NOT NULL, data BLOB NOT NULL);"
        )
        db.executemany(
            "INSERT INTO topics VALUES(?, ?, ?, 'cdr', '')",
            [(i, name, msgtype) for i, (name, msgtype) in enumerate(topics, 1)],
        )
        db.executemany("INSERT INTO messages(topic_id, timestamp, data) VALUES(?, ?, ?)", rows)
    times = [t for _, t, _ in rows]
    counts = [sum(1 for topic, _, _ in rows if topic == i) for i in range(1, len(topics) + 1)]
    info = {
        "version": 5, "storage_identifier": "sqlite3",
        "duration": {"nanoseconds": max(times) - min(times)},
        "starting_time": {"nanoseconds_since_epoch": min(times)}, "message_count": len(rows),
        "topics_with_message_count": [
            {"topic_metadata": {"name": name, "type": msgtype, "serialization_format": "cdr",
                                "offered_qos_profiles": ""}, "message_count": count}
            for (name, msgtype), count in zip(topics, counts, strict=True)
        ],
        "compression_format": "", "compression_mode": "",
        "relative_file_paths": [database.name],
        "files": [{"path": database.name,
                   "starting_time": {"nanoseconds_since_epoch": min(times)},
                   "duration": {"nanoseconds": max(times) - min(times)},
                   "message_count": len(rows)}],
    }  # fmt: skip
    (path / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
    return path


def file_tree(root: Path, without: frozenset[str] = frozenset()) -> dict[str, bytes]:
    """Every file below ``root`` (relative POSIX path -> bytes), less those named in ``without``."""
    return {
        p.relative_to(root).as_posix(): p.read_bytes()
        for p in root.rglob("*")
        if p.is_file() and p.name not in without
    }


def restored_files(root: Path) -> dict[str, bytes]:
    """:func:`file_tree` less ``restore_report.json`` (its timings differ from run to run)
    and the run's lock file (empty, hidden)."""
    return file_tree(root, without=frozenset({REPORT_NAME, RESTORE_LOCK}))
