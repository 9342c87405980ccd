"""capture-ingest from ROS bags: whole, truncated, and with chosen topics."""

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingested import read_pairs
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.cli import main
from lenspair.core.imageio import read_image
from lenspair.rectify.rig import write_kalibr
from tests.capture.ingest_helpers import CROP, frame_files, make_recording, rig

SIZE = (240, 160)


def _write_bag(path: Path, kind: str, images: dict[str, list[tuple[int, np.ndarray]]]) -> Path:
    """A bag with mono8 ``sensor_msgs/Image`` messages on ``/<camera>/image_raw``."""
    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = store.types
    msgtype = "sensor_msgs/msg/Image"
    writer: Any = (
        Writer1(path.with_suffix(".bag"))
        if kind == "ros1"
        else Writer2(path, version=9, storage_plugin=StoragePlugin.SQLITE3)
    )
    messages = sorted((t, camera, image) for camera, items in images.items() for t, image in items)
    with writer:
        connections = {
            camera: writer.add_connection(f"/{camera}/image_raw", msgtype, typestore=store)
            for camera in sorted(images)
        }
        for t_ns, camera, image in messages:
            stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            extra = {"seq": 0} if kind == "ros1" else {}
            header = types["std_msgs/msg/Header"](stamp=stamp, frame_id=camera, **extra)
            message = types[msgtype](
                header=header,
                height=image.shape[0],
                width=image.shape[1],
                encoding="mono8",
                is_bigendian=0,
                step=image.shape[1],
                data=np.ascontiguousarray(image).reshape(-1),
            )
            raw = (
                store.serialize_ros1(message, msgtype)
                if kind == "ros1"
                else store.serialize_cdr(message, msgtype)
            )
            writer.write(connections[camera], t_ns + 1_000_000, raw)
    return path.with_suffix(".bag") if kind == "ros1" else path


def _bag_from_euroc(tmp_path: Path, kind: str, frames: int = 4) -> Path:
    euroc = make_recording(tmp_path / "euroc", frames=frames)
    images = {
        camera: [(int(p.stem), read_image(p)) for p in frame_files(euroc, camera)]
        for camera in ("cam0", "cam1")
    }
    folder = tmp_path / "bags"
    folder.mkdir()
    write_rig_file(folder / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    write_kalibr(folder / "camchain.yaml", rig())
    return _write_bag(folder / "run", kind, images)


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_bag_ingests_like_folders(tmp_path: Path, kind: str) -> None:
    bag = _bag_from_euroc(tmp_path, kind)
    report = ingest_recording(bag, tmp_path / "out", size=SIZE, workers=1)
    assert report.recording_id == "run" and report.counts["kept"] == 4
    assert report.calibration_source.endswith("camchain.yaml")


def test_truncated_db3_keeps_what_was_read(tmp_path: Path) -> None:
    bag = _bag_from_euroc(tmp_path, "db3", frames=5)
    storage = next(bag.glob("*.db3"))
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) - 100])
    report = ingest_recording(bag, tmp_path / "out", size=SIZE)
    counts = report.counts
    assert counts["recording_problems"] == 1
    assert counts["frames_cam0"] + counts["frames_cam1"] < 10
    assert counts["kept"] >= 1
    assert counts["listed_cam1"] == counts["kept"] + counts["rejected"]
    assert len(read_pairs(tmp_path / "out" / "run" / "pairs.jsonl")) == counts["listed_cam1"]


def test_truncated_ros1_bag_ingests_the_frames_before_the_cut(tmp_path: Path) -> None:
    bag = _bag_from_euroc(tmp_path, "ros1")
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) * 3 // 4])
    report = ingest_recording(bag, tmp_path / "out", size=SIZE)
    counts = report.counts
    assert counts["recording_problems"] == 1
    assert counts["kept"] >= 1
    assert len(read_pairs(tmp_path / "out" / "run" / "pairs.jsonl")) == counts["listed_cam1"]


def test_bag_cut_before_any_frame_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = _bag_from_euroc(tmp_path, "ros1")
    bag.write_bytes(bag.read_bytes()[:300])
    code = main(["capture-ingest", str(bag), "--out", str(tmp_path / "out"), "--size", CROP])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and line.startswith(f"lenspair capture-ingest: error: {bag}")
    assert "cannot open bag" in line and "nothing to keep" in line


def test_topics_must_name_two_topics(tmp_path: Path) -> None:
    bag = _bag_from_euroc(tmp_path, "ros1", frames=3)
    out = str(tmp_path / "out")
    args = ["capture-ingest", str(bag), "--out", out, "--size", CROP]
    assert main([*args, "--topics", "/cam0/image_raw,/cam1/image_raw"]) == 0
    with pytest.raises(SystemExit):
        main([*args, "--topics", "/cam0/image_raw"])
