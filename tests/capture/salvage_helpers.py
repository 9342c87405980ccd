"""Bags for the salvage tests: ``COUNT`` rgb8 frames, alternating cam0 / cam1.

Each image's pixels are random bytes that no other message shares (they are
found in the file, and no codec compresses them).
"""

from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.frames import iter_bag_messages
from lenspair.capture.recording import open_recording
from lenspair.capture.rosbag import close_bag_readers

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
COUNT = 16  # messages, alternating cam0 / cam1


def pixels(index: int, rows: int = 40) -> np.ndarray:
    """A rows x 50 RGB image no other message shares (its bytes can be found in the file)."""
    return np.random.default_rng(index).integers(0, 256, (rows, 50, 3), dtype=np.uint8)


def write_bag(
    path: Path, kind: str, compression: str = "none", rows: int = 40, chunk: int = 20_000
) -> tuple[Path, Path]:
    """Write ``COUNT`` rgb8 frames of ``rows`` x 50 px; returns ``(bag, storage file)``.

    ``compression``: ``bz2``/``lz4`` for ROS1 chunks of ``chunk`` bytes,
    ``zstd`` for MCAP chunks (rosbags writes 1 MiB chunks).
    """
    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = store.types
    writer: Any
    if kind == "ros1":
        writer = Writer1(path.with_suffix(".bag"))
        writer.chunk_threshold = chunk  # by default several chunks in a small bag
        if compression != "none":
            writer.set_compression(Writer1.CompressionFormat[compression.upper()])
    else:
        plugin = StoragePlugin.SQLITE3 if kind == "db3" else StoragePlugin.MCAP
        writer = Writer2(path, version=9, storage_plugin=plugin)
        if compression == "zstd":  # MCAP chunks of 1 MiB, zstd-compressed
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        connections = [
            writer.add_connection(f"/cam{i}/image_raw", "sensor_msgs/msg/Image", typestore=store)
            for i in (0, 1)
        ]
        for index in range(COUNT):
            t_ns = T0 + index * 20 * MS
            stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            extra = {"seq": 0} if kind == "ros1" else {}
            header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam", **extra)
            message = types["sensor_msgs/msg/Image"](
                header=header,
                height=rows,
                width=50,
                encoding="rgb8",
                is_bigendian=0,
                step=150,
                data=pixels(index, rows).reshape(-1),
            )
            serialize = store.serialize_ros1 if kind == "ros1" else store.serialize_cdr
            writer.write(connections[index % 2], t_ns + MS, serialize(message, message.__msgtype__))
    if kind == "ros1":
        return path.with_suffix(".bag"), path.with_suffix(".bag")
    return path, next(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))


def recovered(bag: Path, rows: int = 40) -> tuple[list[int], list[Any]]:
    """Indexes of the frames read (checked pixel-exact) and the recording's problems."""
    close_bag_readers()
    recording = open_recording(bag)
    found = []
    for camera in ("cam0", "cam1"):
        for position, frame in enumerate(recording.frames[camera]):
            index = 2 * position + (camera == "cam1")
            np.testing.assert_array_equal(recording.load(frame), pixels(index, rows))
            found.append(index)
    close_bag_readers()
    return sorted(found), recording.problems


def assert_one_cut_report(bag: Path, storage: Path, problems: list[Any]) -> None:
    """The recording's one problem is the cut: one line naming the storage file and its size."""
    (problem,) = problems
    assert problem.camera is None and problem.source == str(bag)
    assert f"{storage}: cut short ({storage.stat().st_size} bytes)" in problem.reason
    assert "\n" not in problem.reason


def bag_messages(bag: Path, problems: list[str]) -> dict[int, bytes]:
    """Every message read: log time -> raw bytes."""
    close_bag_readers()
    try:
        return {m.log_time_ns: m.raw for m in iter_bag_messages(bag, cameras=(), problems=problems)}
    finally:
        close_bag_readers()
