"""Depth and disparity topics are never chosen as cameras by themselves.

A RealSense bag holds an infrared camera beside ``/camera/depth/image_rect_raw``
(``16UC1``, millimetres): taken as "the only two image topics", restore changed
the depth map (by about half a metre) and capture-ingest would pair a camera
with it. The choice is made from the topics' names, before a message is read.
"""

import csv
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.capture.bag_frames import bag_camera_topics, bag_overview, iter_bag_messages
from lenspair.capture.depth_topics import is_depth_topic
from lenspair.capture.errors import CaptureError
from lenspair.capture.frames import iter_frames
from lenspair.capture.recording import open_recording
from lenspair.capture.rosbag import select_topics
from lenspair.cli import main
from lenspair.model.inference.backends import TorchBackend, open_backend
from lenspair.model.inference.pipeline import restore_input
from tests.capture.test_rosbag import IMAGE, MS, T0, Message, _raw_fields, _write_bag
from tests.images import texture
from tests.model.train_fixtures import make_checkpoint

INFRA1 = "/camera/infra1/image_rect_raw"
INFRA2 = "/camera/infra2/image_rect_raw"
DEPTH = "/camera/depth/image_rect_raw"
ALIGNED = "/camera/aligned_depth_to_infra1/image_raw"
RULE = (
    "a depth topic (named depth or disparity, or a 16UC1, 32FC1 or compressedDepth image) "
    "is read as a camera only when named with --topics CAM0 CAM1"
)
OAK_LEFT = "/oak/left/image_rect"
OAK_DEPTH = "/oak/stereo/image_raw"
"""OAK-D's depth output: named as no depth, a 16UC1 image."""


def _depth(seed: int) -> np.ndarray:
    """A depth map in millimetres, as a RealSense's Z16 stream gives it."""
    return np.random.default_rng(seed).integers(400, 3000, (32, 48)).astype(np.uint16)


def _realsense(path: Path, kind: str, topics: tuple[str, ...], frames: int = 3) -> Path:
    """A bag of the ``topics`` (infra: mono8 texture; depth: 16UC1 millimetres)."""
    messages: list[Message] = []
    for i in range(frames):
        t = T0 + i * 33 * MS
        for k, topic in enumerate(topics):
            if is_depth_topic(topic) or topic == OAK_DEPTH:
                fields = _raw_fields(_depth(10 * i + k), "16UC1", pad=0)
            else:
                infrared = (texture((32, 48), seed=10 * i + k) * 255).astype(np.uint8)
                fields = _raw_fields(infrared, "mono8", pad=0)
            messages.append((topic, IMAGE, t + k, fields))
    return _write_bag(path, kind, messages)


def test_depth_topics_are_told_by_a_word_of_their_name() -> None:
    for topic in (
        DEPTH,
        ALIGNED,
        "/Stereo/Disparity",
        "/zed/depth_registered",
        "/cam/depth2/image",
    ):
        assert is_depth_topic(topic), topic
    for topic in (INFRA1, "/camera/color/image_raw", "/depthai/left/image", "/left/depthcam"):
        assert not is_depth_topic(topic), topic


def test_select_topics_leaves_depth_out() -> None:
    bag = Path("rs.bag")
    # three image topics, one of them depth: the two infrared cameras, in sorted order
    assert select_topics([DEPTH, INFRA2, INFRA1], bag) == (INFRA1, INFRA2)
    assert select_topics(["/stereo/disparity", "/stereo/left", "/stereo/right"], bag) == (
        "/stereo/left",
        "/stereo/right",
    )
    with pytest.raises(CaptureError) as caught:
        select_topics([DEPTH, INFRA1], bag)  # "the only two": an IR camera and a depth map
    assert str(caught.value) == (
        f"rs.bag: need two image topics (sensor_msgs/Image or CompressedImage), found 1: "
        f"{INFRA1}; depth image topics not chosen as cameras: {DEPTH} ({RULE})"
    )
    with pytest.raises(CaptureError) as caught:
        select_topics([DEPTH, ALIGNED], bag)
    assert str(caught.value) == (
        f"rs.bag: the only image topics are depth topics ({ALIGNED}, {DEPTH}); {RULE}"
    )


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_capture_ingest_reads_the_two_infrared_cameras_and_says_depth_was_left_out(
    tmp_path: Path, kind: str
) -> None:
    bag = _realsense(tmp_path / "rs", kind, (INFRA1, INFRA2, DEPTH))
    recording = open_recording(bag)
    assert recording.topics == (INFRA1, INFRA2)
    said = [str(p) for p in recording.problems]
    assert said == [f"{bag}: depth image topics not chosen as cameras: {DEPTH} ({RULE})"]
    assert not recording.problems[0].dropped and recording.problems[0].camera is None
    # named, a depth topic is still read (and nothing is said of a choice not made)
    named = open_recording(bag, topics=(INFRA1, DEPTH))
    assert named.topics == (INFRA1, DEPTH) and named.problems == []
    np.testing.assert_array_equal(named.load(named.frames["cam1"][1]), _depth(12))
    with pytest.raises(CaptureError, match=rf"found 1: {INFRA1}; depth image topics not chosen"):
        open_recording(_realsense(tmp_path / "one", kind, (INFRA1, DEPTH)))


def test_a_one_camera_bag_restored_beside_its_topic_is_still_one_camera(tmp_path: Path) -> None:
    """restore --suffix /clean on a one-camera bag wrote <topic>/clean beside it: restored
    again, the camera and its copy were taken for a stereo pair."""
    bag = _realsense(tmp_path / "restored", "mcap", (INFRA1, f"{INFRA1}/clean"))
    assert bag_camera_topics(bag) == {INFRA1: "cam0"}


def test_restore_and_detect_choose_the_infrared_camera_alone(tmp_path: Path) -> None:
    bag = _realsense(tmp_path / "rs", "mcap", (INFRA1, DEPTH, ALIGNED))
    assert bag_camera_topics(bag) == {INFRA1: "cam0"}  # a one-camera bag
    assert [f.name.split("@")[0] for f in iter_frames(bag)] == [INFRA1] * 3
    assert bag_overview(bag).others == (
        f"{bag}: depth image topics not chosen as cameras: {ALIGNED}, {DEPTH} ({RULE}); "
        f"left as recorded (camera topics: cam0 {INFRA1})",
    )
    # --topics still names them: then the usual line for the topic not chosen
    assert bag_camera_topics(bag, (INFRA1, DEPTH)) == {INFRA1: "cam0", DEPTH: "cam1"}
    assert bag_overview(bag, topics=(INFRA1, DEPTH)).others == (
        f"{bag}: image topic {ALIGNED} left as recorded (camera topics: cam0 {INFRA1}, "
        f"cam1 {DEPTH}; --topics CAM0 CAM1 chooses others)",
    )


def test_a_bag_of_depth_topics_alone_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = _realsense(tmp_path / "depth", "db3", (DEPTH,))
    message = f"{bag}: the only image topics are depth topics ({DEPTH}); {RULE}"
    with pytest.raises(CaptureError) as caught:
        iter_frames(bag)
    assert str(caught.value) == message
    out = tmp_path / "out"
    assert main(["detect", "detector.pt", str(bag), "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"lenspair detect: error: {message}"


def test_detect_judges_the_camera_and_warns_of_depth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = _realsense(tmp_path / "rs", "ros1", (INFRA1, DEPTH))
    out = tmp_path / "out"
    assert main(["detect", "detector.pt", str(bag), "--out", str(out)]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert warnings == [
        f"lenspair detect: warning: {bag}: depth image topics not chosen as cameras: {DEPTH} "
        f"({RULE}); left as recorded (camera topics: cam0 {INFRA1})"
    ]
    with (out / "detections.csv").open() as handle:
        judged = [row["name"].split("@")[0] for row in csv.DictReader(handle)]
    assert judged == [INFRA1] * 3


@pytest.fixture
def backend(tmp_path: Path) -> Iterator[TorchBackend]:
    before = torch.get_num_threads()
    torch.set_num_threads(1)  # the machine is shared: more threads only contend
    loaded = open_backend(make_checkpoint(tmp_path / "ck.pt"), torch.device("cpu"), "fp32")
    assert isinstance(loaded, TorchBackend)
    yield loaded
    torch.set_num_threads(before)


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_restore_copies_the_depth_map_byte_for_byte(
    tmp_path: Path, backend: TorchBackend, kind: str
) -> None:
    bag = _realsense(tmp_path / "rs", kind, (INFRA1, DEPTH))
    report = restore_input(bag, tmp_path / "out", backend)
    source = list(iter_bag_messages(bag, cameras=()))
    copy = list(iter_bag_messages(Path(report.output), cameras=()))
    depth = [(m.log_time_ns, m.raw) for m in source if m.connection.topic == DEPTH]
    assert len(depth) == 3
    assert [(m.log_time_ns, m.raw) for m in copy if m.connection.topic == DEPTH] == depth
    assert (report.cameras, report.restored, report.failed) == (["cam0"], 3, 0)
    assert [p["reason"] for p in report.problems] == [
        f"{bag}: depth image topics not chosen as cameras: {DEPTH} ({RULE}); "
        f"left as recorded (camera topics: cam0 {INFRA1})"
    ]
    infra = [m.raw for m in source if m.connection.topic == INFRA1]
    assert [m.raw for m in copy if m.connection.topic == INFRA1] != infra  # restored


@pytest.mark.parametrize("kind", ["ros1", "db3", "mcap"])
def test_a_depth_map_named_as_none_is_told_by_its_encoding(tmp_path: Path, kind: str) -> None:
    # OAK-D's /oak/stereo/image_raw (16UC1) was chosen as cam1 beside /oak/left/image_rect
    bag = _realsense(tmp_path / "oak", kind, (OAK_LEFT, OAK_DEPTH))
    assert bag_camera_topics(bag) == {OAK_LEFT: "cam0"}
    with pytest.raises(CaptureError, match=rf"found 1: {OAK_LEFT}; depth image topics not chosen"):
        open_recording(bag)
    said = f"{bag}: depth image topics not chosen as cameras: {OAK_DEPTH} ({RULE})"
    chose = f"left as recorded (camera topics: cam0 {OAK_LEFT})"
    assert bag_overview(bag).others == (f"{said}; {chose}",)
