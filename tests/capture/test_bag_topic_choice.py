"""Bags as robots record them: empty raw topics, foreign types, split and refused bags.

``ros2 bag record -a`` records a camera's raw topic empty beside its
``/compressed`` twin; rosjava writes message definitions naming types they
never define; a split bag can lose one of its files. Each was misread: the
empty raw topics were chosen (no frame at all), and a whole bag that rosbags
refused was reported as "cut short" without rosbags' reason.
"""

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.bag_frames import bag_camera_topics, iter_bag_messages
from lenspair.capture.errors import CaptureError
from lenspair.capture.recording import open_recording
from lenspair.capture.rosbag import close_bag_readers
from tests.capture.test_rosbag import (
    COMPRESSED,
    IMAGE,
    KINDS,
    MS,
    T0,
    _image,
    _stereo,
    _write_bag,
)

RAW = ("/cam0/image_raw", "/cam1/image_raw")
TEMPERATURE = "sensor_msgs/msg/Temperature"


def _compressed_twins(path: Path, kind: str, count: int = 3) -> Path:
    """Raw camera topics declared but empty; the frames on their ``/compressed`` twins."""
    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = store.types
    if kind == "ros1":
        writer: Writer1 | Writer2 = Writer1(path.with_suffix(".bag"))
    else:
        plugin = StoragePlugin.SQLITE3 if kind == "db3" else StoragePlugin.MCAP
        writer = Writer2(path, version=9, storage_plugin=plugin)
    with writer:
        for topic in RAW:  # never published (or a QoS mismatch): declared, no message
            writer.add_connection(topic, IMAGE, typestore=store)
        twins = [writer.add_connection(f"{t}/compressed", COMPRESSED, typestore=store) for t in RAW]
        for i in range(count):
            for camera, connection in enumerate(twins):
                t_ns = T0 + i * 50 * MS + camera * 2 * MS
                stamp = types["builtin_interfaces/msg/Time"](
                    sec=t_ns // 10**9, nanosec=t_ns % 10**9
                )
                extra = {"seq": 0} if kind == "ros1" else {}
                header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam", **extra)
                png = cv2.imencode(".png", _image(10 * camera + i))[1].reshape(-1)
                message = types[COMPRESSED](header=header, format="png", data=png)
                serialize = store.serialize_ros1 if kind == "ros1" else store.serialize_cdr
                writer.write(connection, t_ns + MS, serialize(message, COMPRESSED))
    return path.with_suffix(".bag") if kind == "ros1" else path


@pytest.mark.parametrize("kind", KINDS)
def test_empty_raw_topics_leave_their_compressed_twins_as_the_cameras(
    tmp_path: Path, kind: str
) -> None:
    # capture-ingest said "no cam0 frames could be listed: its topic /cam0/image_raw holds
    # no message" and restore or detect found nothing, though every frame was there
    bag = _compressed_twins(tmp_path / "run", kind)
    recording = open_recording(bag)
    assert recording.topics == ("/cam0/image_raw/compressed", "/cam1/image_raw/compressed")
    assert [len(recording.frames[c]) for c in ("cam0", "cam1")] == [3, 3]
    np.testing.assert_array_equal(recording.load(recording.frames["cam1"][2]), _image(12))
    close_bag_readers()
    assert bag_camera_topics(bag) == {
        "/cam0/image_raw/compressed": "cam0",
        "/cam1/image_raw/compressed": "cam1",
    }
    # named, an empty topic is still taken, and said to be empty
    with pytest.raises(CaptureError, match=r"/cam0/image_raw holds no message"):
        open_recording(bag, topics=RAW)


def test_topics_named_wrongly_say_whether_they_are_missing_or_not_images(
    tmp_path: Path,
) -> None:
    messages = [*_stereo(2), ("/thermal", TEMPERATURE, T0, {"temperature": 20.5, "variance": 0})]
    bag = _write_bag(tmp_path / "run", "db3", messages)
    listing = "image topics: /cam0/image_raw, /cam1/image_raw"
    with pytest.raises(CaptureError, match=rf"no topic /left/image_raw in the bag; {listing}"):
        open_recording(bag, topics=("/left/image_raw", "/cam1/image_raw"))
    said = rf"/thermal is a {TEMPERATURE}, not an image; {listing}"
    with pytest.raises(CaptureError, match=said):
        open_recording(bag, topics=("/thermal", "/cam1/image_raw"))


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_a_bag_without_image_topics_lists_the_topics_it_holds(tmp_path: Path, kind: str) -> None:
    # it said "found 0: none", leaving the user to find out what the bag did hold
    messages = [("/thermal", TEMPERATURE, T0, {"temperature": 20.5, "variance": 0})]
    bag = _write_bag(tmp_path / "run", kind, messages)
    said = rf"no image topic .*; its topics: /thermal \({TEMPERATURE}\)"
    with pytest.raises(CaptureError, match=said):
        open_recording(bag)
    with pytest.raises(CaptureError, match=said):
        bag_camera_topics(bag)


def _with_undefined_type(path: Path, kind: str, count: int = 3) -> Path:
    """Stereo mono8 frames, and a topic whose definition names a type it never defines."""
    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = store.types
    foreign = "ff_msgs/msg/GuestScienceData"
    writer: Writer1 | Writer2
    if kind == "ros1":
        writer = Writer1(path.with_suffix(".bag"))
        definition = "Header header\nff_msgs/GuestScienceState state\n"
        extra = {"md5sum": "0123456789abcdef0123456789abcdef"}
    else:
        writer = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
        definition = "std_msgs/Header header\nff_msgs/GuestScienceState state\n"
        extra = {"rihs01": "RIHS01_" + "0" * 64}
    serialize = store.serialize_ros1 if kind == "ros1" else store.serialize_cdr
    with writer:
        cameras = [writer.add_connection(t, IMAGE, typestore=store) for t in RAW]
        status = writer.add_connection("/gs/status", foreign, msgdef=definition, **extra)
        for topic, _, t_ns, fields in _stereo(count):
            stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            seq = {"seq": 0} if kind == "ros1" else {}
            header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam", **seq)
            message = types[IMAGE](header=header, **fields)
            writer.write(cameras[RAW.index(topic)], t_ns + MS, serialize(message, IMAGE))
        writer.write(status, T0 + 500 * MS, bytes(16))
    return path.with_suffix(".bag") if kind == "ros1" else path


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_a_whole_bag_rosbags_refuses_is_read_whole_and_not_called_cut(
    tmp_path: Path, kind: str
) -> None:
    # it was read record by record, every frame kept, but reported as "cut short" and
    # rosbags' reason (an undefined type in a definition) was thrown away
    bag = _with_undefined_type(tmp_path / "run", kind)
    recording = open_recording(bag)
    assert [len(recording.frames[c]) for c in ("cam0", "cam1")] == [3, 3]
    np.testing.assert_array_equal(recording.load(recording.frames["cam1"][1]), _image(101))
    (note,) = [p for p in recording.problems if p.camera is None]
    assert not note.dropped and "cut short" not in note.reason
    assert note.reason.startswith("rosbags could not open the bag (")
    assert "GuestScienceState" in note.reason and "all 7 messages" in note.reason
    problems: list[str] = []
    close_bag_readers()
    frames = [m.frame for m in iter_bag_messages(bag, problems=problems) if m.frame is not None]
    assert len(frames) == 6 and all(f.image is not None for f in frames)
    (line,) = problems
    assert line.startswith(f"{bag}: rosbags could not open the bag (") and "cut" not in line
    close_bag_readers()


def test_a_split_bag_missing_a_file_names_it_and_keeps_the_rest(tmp_path: Path) -> None:
    # it kept half the frames and called the intact file "cut short"
    bag = _write_bag(tmp_path / "run", "db3", _stereo(4))
    storage = next(bag.glob("*.db3"))
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = metadata["rosbag2_bagfile_information"]
    info["relative_file_paths"].append("run_1.db3")  # a second file, lost in the copy
    (bag / "metadata.yaml").write_text(yaml.safe_dump(metadata))
    recording = open_recording(bag)
    assert [len(recording.frames[c]) for c in ("cam0", "cam1")] == [4, 4]
    (note,) = [p for p in recording.problems if p.camera is None]
    assert "run_1.db3" in note.reason and "cut short" not in note.reason
    assert f"{storage}: read record by record: all 8 messages" in note.reason
    close_bag_readers()


def test_a_split_bag_without_readable_metadata_says_to_reindex(tmp_path: Path) -> None:
    bag = _write_bag(tmp_path / "run", "db3", _stereo(2))
    storage = next(bag.glob("*.db3"))
    (bag / "run_1.db3").write_bytes(storage.read_bytes())
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: [")
    # it said "cannot salvage: need one .db3/.mcap file, found 2", and no way out
    with pytest.raises(CaptureError, match=rf"metadata.yaml: run `ros2 bag reindex {bag}` to"):
        open_recording(bag)


def test_a_folder_of_bags_says_to_pass_each_bag(tmp_path: Path) -> None:
    # a robot's bags/ folder got "unknown recording layout; expected ..." with no word of bags
    folder = tmp_path / "bags"
    folder.mkdir()
    _write_bag(folder / "morning", "ros1", _stereo(2))
    _write_bag(folder / "noon", "db3", _stereo(2))
    said = r"a folder of bags \(morning.bag, noon\); pass each bag itself"
    with pytest.raises(CaptureError, match=said):
        open_recording(folder)
