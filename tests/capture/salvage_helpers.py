"""Bags for the salvage tests: ``COUNT`` rgb8 frames, alternating cam0 / cam1.

Each image's pixels are random bytes that no other message shares (they are
found in the file, and no codec compresses them). :func:`chunk_layout` finds
where a compressed bag's chunks and their messages lie, by decoding the
whole chunks with the codecs' own decoders (``DECODERS``).
"""

import bz2
import struct
import sys
from pathlib import Path
from typing import Any, NamedTuple

import lz4.frame
import numpy as np
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.bag_frames import iter_bag_messages
from lenspair.capture.recording import open_recording
from lenspair.capture.rosbag import close_bag_readers

if sys.version_info >= (3, 14):
    from compression import zstd
else:
    from backports import zstd

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
COUNT = 16  # messages, alternating cam0 / cam1
DECODERS: dict[str, Any] = {
    "bz2": bz2.BZ2Decompressor,
    "lz4": lz4.frame.LZ4FrameDecompressor,
    "zstd": zstd.ZstdDecompressor,
}


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


class Chunk(NamedTuple):
    """A compressed chunk: its data in the file, and its messages' ends in its decoded data."""

    datapos: int
    size: int
    codec: str
    ends: dict[int, int]  # log time -> decompressed byte after the message's last


def mcap_chunk_records(data: bytes) -> list[tuple[int, int, str]]:
    """``(records' file offset, compressed size, codec)`` of each chunk of the data section."""
    chunks, pos = [], 8
    while pos + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x0F:  # data end
            break
        if op == 0x06:
            (name_size,) = struct.unpack_from("<L", data, pos + 9 + 28)
            codec = data[pos + 9 + 32 : pos + 9 + 32 + name_size].decode()
            start = pos + 9 + 32 + name_size + 8
            chunks.append((start, pos + 9 + length - start, codec))
        pos += 9 + length
    return chunks


def chunk_layout(
    whole: bytes, storage: Path, kind: str, codec: str, written: dict[int, bytes]
) -> list[Chunk]:
    """The compressed chunks of the uncut bag ``whole`` (the bytes of ``storage``)."""
    if kind == "ros1":  # rosbags' index of the uncut bag
        with Reader1(storage) as reader:
            found = [(c.datapos, c.datasize, codec) for c in reader.chunks.values()]
    else:
        found = mcap_chunk_records(whole)
    chunks = []
    for datapos, size, chunk_codec in found:
        decoded = DECODERS[chunk_codec]().decompress(whole[datapos : datapos + size])
        ends = {t: decoded.find(raw) + len(raw) for t, raw in written.items() if raw in decoded}
        chunks.append(Chunk(datapos, size, chunk_codec, ends))
    assert sum(len(c.ends) for c in chunks) == COUNT  # every message lies in a chunk
    return chunks
