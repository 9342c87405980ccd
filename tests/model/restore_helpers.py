"""Inputs for the restore tests: bags with image and non-image topics."""

from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.core.imageio import read_image
from tests.capture.ingest_helpers import frame_files, make_recording

IMAGE = "sensor_msgs/msg/Image"
STRING = "std_msgs/msg/String"


def write_bag(
    path: Path, kind: str, images: dict[str, list[tuple[int, np.ndarray]]], encoding: str = "mono8"
) -> Path:
    """A bag (``ros1``, ``db3`` or ``mcap``) with images on ``/<camera>/image_raw``.

    A ``/status`` ``std_msgs/String`` message follows every image, so copies of
    non-image topics are checked too. Log time = stamp + 1 ms.
    """
    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = store.types
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    bag = path.with_suffix(".bag") if kind == "ros1" else path
    writer: Any = Writer1(bag) if kind == "ros1" else Writer2(bag, version=9, storage_plugin=plugin)
    messages = sorted((t, camera, image) for camera, items in images.items() for t, image in items)

    def serialize(message: Any, msgtype: str) -> bytes:
        if kind == "ros1":
            return bytes(store.serialize_ros1(message, msgtype))
        return bytes(store.serialize_cdr(message, msgtype))

    with writer:
        connections = {
            camera: writer.add_connection(f"/{camera}/image_raw", IMAGE, typestore=store)
            for camera in sorted(images)
        }
        status = writer.add_connection("/status", STRING, typestore=store)
        for t_ns, camera, image in messages:
            stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            extra = {"seq": 7} if kind == "ros1" else {}
            header = types["std_msgs/msg/Header"](stamp=stamp, frame_id=camera, **extra)
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
            writer.write(connections[camera], t_ns + 1_000_000, serialize(message, IMAGE))
            text = types[STRING](data=f"frame {t_ns}")
            writer.write(status, t_ns + 2_000_000, serialize(text, STRING))
    return bag


def bag_from_recording(tmp_path: Path, kind: str, frames: int = 3, colour: bool = False) -> Path:
    """A stereo bag from a simulated-style EuRoC recording, rig.yaml beside it (cam1)."""
    euroc = make_recording(tmp_path / "euroc", frames=frames, colour=colour)
    images = {
        camera: [(int(p.stem), read_image(p)) for p in frame_files(euroc, camera)]
        for camera in ("cam0", "cam1")
    }
    folder = tmp_path / "bags"
    folder.mkdir()
    write_rig_file(folder / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    return write_bag(folder / "run", kind, images, "rgb8" if colour else "mono8")
