import multiprocessing
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.errors import CaptureError
from lenspair.capture.image_messages import decode_raw
from lenspair.capture.recording import FrameRef, load_frame, open_recording, resolve_obstructed
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.capture.rosbag import close_bag_readers, read_bag, select_topics

MS = 1_000_000
T0 = 1_700_000_000_000_000_000
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
KINDS = ["ros1", "db3", "mcap"]

# (topic, msgtype, header stamp ns, fields besides the header)
Message = tuple[str, str, int, dict[str, Any]]


def _image(seed: int, dtype: type = np.uint8, colour: bool = False) -> np.ndarray:
    shape = (6, 5, 3) if colour else (6, 5)
    rng = np.random.default_rng(seed)
    return rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)


def _raw_fields(
    image: np.ndarray, encoding: str, pad: int = 3, big: bool = False
) -> dict[str, Any]:
    """Image message fields with ``pad`` junk bytes at the end of every row."""
    pixels = image[:, :, ::-1] if encoding.startswith("bgr") else image
    sample = pixels.dtype.newbyteorder(">") if big else pixels.dtype.newbyteorder("<")
    rows = np.ascontiguousarray(pixels).astype(sample)
    row_bytes = rows.reshape(image.shape[0], -1).view(np.uint8)
    junk = np.full((image.shape[0], pad), 0xAB, np.uint8)
    data = np.ascontiguousarray(np.hstack([row_bytes, junk])).reshape(-1)
    return {
        "height": image.shape[0],
        "width": image.shape[1],
        "encoding": encoding,
        "is_bigendian": int(big),
        "step": row_bytes.shape[1] + pad,
        "data": data,
    }


def _write_bag(path: Path, kind: str, messages: Iterable[Message], store: Any = None) -> Path:
    """Write a bag; log time = stamp + 1 ms unless ``_log_ns`` is given. Returns its path.

    ``store``: the type store whose definitions the bag records (default: the stock one).
    """
    if store is None:
        store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = store.types
    if kind == "ros1":
        writer: Any = Writer1(path.with_suffix(".bag"))
    else:
        plugin = StoragePlugin.SQLITE3 if kind == "db3" else StoragePlugin.MCAP
        writer = Writer2(path, version=9, storage_plugin=plugin)
    connections: dict[str, Any] = {}
    with writer:
        for topic, msgtype, t_ns, fields in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            extra = {"seq": 0} if kind == "ros1" else {}
            header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam", **extra)
            log_ns = fields.pop("_log_ns", t_ns + MS)
            message = types[msgtype](header=header, **fields)
            if kind == "ros1":
                raw = store.serialize_ros1(message, msgtype)
            else:
                raw = store.serialize_cdr(message, msgtype)
            writer.write(connections[topic], log_ns, raw)
    return path.with_suffix(".bag") if kind == "ros1" else path


def _stereo(
    count: int, topics: tuple[str, str] = ("/cam0/image_raw", "/cam1/image_raw")
) -> list[Message]:
    messages = []
    for i in range(count):
        t = T0 + i * 50 * MS
        messages.append((topics[0], IMAGE, t, _raw_fields(_image(i), "mono8")))
        messages.append((topics[1], IMAGE, t + 2 * MS, _raw_fields(_image(100 + i), "mono8")))
    return messages


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(
    ("encoding", "dtype", "colour", "big"),
    [
        ("mono8", np.uint8, False, False),
        ("mono16", np.uint16, False, False),
        ("mono16", np.uint16, False, True),
        ("rgb8", np.uint8, True, False),
        ("bgr8", np.uint8, True, False),
    ],
)
def test_round_trip_pixels(
    tmp_path: Path, kind: str, encoding: str, dtype: type, colour: bool, big: bool
) -> None:
    images = [_image(i, dtype, colour) for i in range(4)]
    messages = [
        (
            f"/cam{i % 2}/image_raw",
            IMAGE,
            T0 + (i // 2) * 50 * MS,
            _raw_fields(im, encoding, big=big),
        )
        for i, im in enumerate(images)
    ]
    bag = _write_bag(tmp_path / "run", kind, messages)
    recording = open_recording(bag)
    assert recording.layout == ("rosbag1" if kind == "ros1" else "rosbag2")
    assert recording.recording_id == "run"
    assert recording.topics == ("/cam0/image_raw", "/cam1/image_raw")
    assert recording.timestamps("cam0") == [T0, T0 + 50 * MS] == recording.timestamps("cam1")
    assert recording.problems == []
    for i, image in enumerate(images):
        loaded = recording.load(recording.frames[f"cam{i % 2}"][i // 2])  # type: ignore[index]
        assert loaded.dtype == image.dtype and loaded.flags.c_contiguous
        np.testing.assert_array_equal(loaded, image)


@pytest.mark.parametrize("kind", ["db3", "mcap"])
def test_bare_storage_file_opens_too(tmp_path: Path, kind: str) -> None:
    folder = _write_bag(tmp_path / "run", kind, _stereo(3))
    (storage,) = folder.glob(f"*.{kind}")
    recording = open_recording(storage)
    assert recording.layout == "rosbag2"
    np.testing.assert_array_equal(recording.load(recording.frames["cam1"][2]), _image(102))


@pytest.mark.parametrize("suffix", [".db3", ".mcap"])
def test_a_ros1_bag_named_as_a_ros2_file_is_said_so(tmp_path: Path, suffix: str) -> None:
    # read whole by the salvage, then reported as "cut short": a damaged recording, it said
    bag = _write_bag(tmp_path / "run", "ros1", _stereo(2))
    misnamed = bag.rename(tmp_path / f"run{suffix}")
    with pytest.raises(CaptureError, match=rf"run\{suffix}: a ROS 1 bag .* rename it to \.bag$"):
        open_recording(misnamed)
    assert open_recording(misnamed.rename(tmp_path / "run.bag")).frames["cam0"]


def test_topic_choice_duplicates_and_order(tmp_path: Path) -> None:
    messages = _stereo(3, ("/stereo/left/image", "/stereo/right/image"))
    messages.append(("/aux/image", IMAGE, T0, _raw_fields(_image(7), "mono8")))
    # Received last: a repeated header stamp, and a stamp going back.
    late = [(T0 + 50 * MS, 8), (T0 + 60 * MS, 9)]
    for k, (t, seed) in enumerate(late):
        fields = {**_raw_fields(_image(seed), "mono8"), "_log_ns": T0 + (200 + k) * MS}
        messages.append(("/stereo/left/image", IMAGE, t, fields))
    recording = open_recording(_write_bag(tmp_path / "run", "db3", messages))
    assert recording.topics == ("/stereo/left/image", "/stereo/right/image")
    assert recording.timestamps("cam0") == [T0, T0 + 50 * MS, T0 + 60 * MS, T0 + 100 * MS]
    dropped = [(p.reason.split(" (")[0], p.t_ns) for p in recording.problems if p.dropped]
    assert dropped == [("duplicate timestamp", T0 + 50 * MS)]
    warned = [p for p in recording.problems if not p.dropped]
    assert len(warned) == 1 and warned[0].reason.startswith("timestamp goes back by 40.000 ms")
    frame = recording.frames["cam0"][2]
    np.testing.assert_array_equal(recording.load(frame), _image(9))
    assert "/stereo/left/image @ t_ns=" in frame.describe()
    explicit = open_recording(recording.path, topics=("/aux/image", "/stereo/right/image"))
    assert explicit.timestamps("cam0") == [T0]
    with pytest.raises(CaptureError, match=r"no topic /imu in the bag; image topics: /aux/image"):
        open_recording(recording.path, topics=("/imu", "/aux/image"))


def test_select_topics() -> None:
    bag = Path("b.bag")
    assert select_topics(["/b", "/a"], bag) == ("/a", "/b")
    assert select_topics(["/cam1/img", "/cam0/img", "/cam2/img"], bag) == ("/cam0/img", "/cam1/img")
    assert select_topics(["/right", "/left", "/depth"], bag) == ("/left", "/right")
    with pytest.raises(CaptureError, match=r"b.bag: need two image topics .* found 1: /only"):
        select_topics(["/only"], bag)
    with pytest.raises(CaptureError, match=r"cannot tell which of 3 .* name them with --topics"):
        select_topics(["/x", "/y", "/z"], bag)
    # image_transport records each camera twice: the raw topics are the cameras (capture-ingest
    # and calibrate refused these four as ambiguous, while restore and detect chose the raw pair)
    stereo = ["/stereo/left/image_raw", "/stereo/right/image_raw"]
    twins = [*stereo, *(f"{topic}/compressed" for topic in stereo)]
    assert select_topics(sorted(twins), bag) == tuple(stereo)
    alone = ("/a/compressed", "/b/compressed")  # compressed topics alone are the cameras
    assert select_topics(list(alone), bag) == alone
    # only a transport's or restore's last name makes a copy: /stereo/image/left is a camera
    nested = ["/mono", "/stereo/image", "/stereo/image/left", "/stereo/image/right"]
    assert select_topics(nested, bag) == ("/stereo/image/left", "/stereo/image/right")
    # one camera and its copy are one camera, not a stereo pair of a camera and itself
    with pytest.raises(CaptureError, match=r"found 1: /c/image_raw; copies of a camera left"):
        select_topics(["/c/image_raw", "/c/image_raw/compressed"], bag)


def test_one_image_topic_is_a_clear_error(tmp_path: Path) -> None:
    messages = [m for m in _stereo(2) if m[0] == "/cam0/image_raw"]
    bag = _write_bag(tmp_path / "run", "ros1", messages)
    with pytest.raises(CaptureError, match=r"run.bag: need two image topics .* /cam0/image_raw"):
        open_recording(bag)


def test_compressed_images(tmp_path: Path) -> None:
    images = [_image(i, colour=True) for i in range(2)] + [_image(5, np.uint16)] * 2
    messages = []
    for i, image in enumerate(images):
        encoded = image[:, :, ::-1] if image.ndim == 3 else image
        ok, png = cv2.imencode(".png", encoded)
        assert ok
        fields = {"format": "png", "data": png.reshape(-1)}
        messages.append((f"/cam{i // 2}/compressed", COMPRESSED, T0 + (i % 2) * MS, fields))
    recording = open_recording(_write_bag(tmp_path / "run", "mcap", messages))
    loaded = [recording.load(f) for camera in ("cam0", "cam1") for f in recording.frames[camera]]  # type: ignore[index]
    for back, image in zip(loaded, images, strict=True):
        np.testing.assert_array_equal(back, image)
    bad = [("/cam0/c", COMPRESSED, T0, {"format": "jpeg", "data": np.zeros(9, np.uint8)})]
    bad.append(("/cam1/c", COMPRESSED, T0, {"format": "jpeg", "data": np.zeros(9, np.uint8)}))
    broken = open_recording(_write_bag(tmp_path / "bad", "db3", bad))
    with pytest.raises(CaptureError, match=r"bad /cam0/c @ t_ns=.*cannot decode compressed"):
        broken.load(broken.frames["cam0"][0])


def test_corrupt_messages_fail_on_load_only(tmp_path: Path) -> None:
    short = _raw_fields(_image(1), "mono8")
    short["data"] = short["data"][:-10]
    messages = [
        ("/cam0/image_raw", IMAGE, T0, _raw_fields(_image(0), "nv21")),
        ("/cam1/image_raw", IMAGE, T0, short),
    ]
    recording = open_recording(_write_bag(tmp_path / "run", "ros1", messages))
    with pytest.raises(
        CaptureError,
        match=r"run.bag /cam0/image_raw @ t_ns=\d+ \(logged \d+\): unsupported encoding "
        r"'nv21'; supported: .*yuv422_yuy2.*bayer_<rggb\|bggr\|gbrg\|grbg><8\|16>",
    ):
        recording.load(recording.frames["cam0"][0])
    with pytest.raises(
        CaptureError,
        match=r"/cam1/image_raw @ t_ns=\d+ \(logged \d+\): truncated image data \(38 of 45 bytes\)",
    ):
        recording.load(recording.frames["cam1"][0])


def test_decode_raw_checks_step() -> None:
    with pytest.raises(CaptureError, match="step 4 is smaller than a row"):
        decode_raw(2, 5, "mono8", False, 4, np.zeros(10, np.uint8), "here")
    image = decode_raw(2, 2, "mono16", True, 4, bytes([1, 2, 3, 4, 5, 6, 7, 8]), "here")
    np.testing.assert_array_equal(image, [[0x0102, 0x0304], [0x0506, 0x0708]])


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_bag_cut_before_any_message_names_the_bag(tmp_path: Path, kind: str) -> None:
    # Cut later, the complete messages are kept (tests/capture/test_salvage*.py).
    bag = _write_bag(tmp_path / "run", kind, _stereo(5))
    storage = bag if kind == "ros1" else next(bag.glob("*.mcap"))
    storage.write_bytes(storage.read_bytes()[:300])
    with pytest.raises(
        CaptureError, match=rf"{bag.name}: cannot open bag \(.*\); .* found nothing to keep"
    ):
        open_recording(bag)


def test_truncated_db3_keeps_frames_read_before(tmp_path: Path) -> None:
    # Whole pages before the cut are read; the rows on the cut page are lost.
    image = _image(3, colour=True).repeat(20, 0).repeat(20, 1)
    messages = [(t, m, s, _raw_fields(image, "rgb8")) for t, m, s, _ in _stereo(6)]
    bag = _write_bag(tmp_path / "run", "db3", messages)
    storage = next(bag.glob("*.db3"))
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) - 100])
    recording = open_recording(bag)
    (stopped,) = recording.problems
    assert stopped.camera is None and stopped.source == str(bag)
    assert stopped.reason.startswith("reading stopped early (")
    assert 0 < len(recording.frames["cam0"]) + len(recording.frames["cam1"]) < 12
    np.testing.assert_array_equal(recording.load(recording.frames["cam0"][0]), image)


def _load_shape(frame: FrameRef) -> tuple[int, ...]:
    return tuple(load_frame(frame).shape)


def test_bag_frames_load_in_forked_workers(tmp_path: Path) -> None:
    recording = open_recording(_write_bag(tmp_path / "run", "db3", _stereo(4)))
    frames = recording.frames["cam0"] + recording.frames["cam1"]
    recording.load(frames[0])  # the parent holds an open reader when forking
    with multiprocessing.get_context("fork").Pool(2) as pool:
        assert pool.map(_load_shape, frames) == [(6, 5)] * 8
    np.testing.assert_array_equal(recording.load(frames[-1]), _image(103))
    close_bag_readers()


def test_rig_file_beside_a_bag(tmp_path: Path) -> None:
    bag = _write_bag(tmp_path / "run", "ros1", _stereo(2))
    write_rig_file(tmp_path / "rig.yaml", RigFile("cam1", ("rain",)))
    assert resolve_obstructed(bag).obstructed == "cam1"
    folder = _write_bag(tmp_path / "ros2" / "run", "db3", _stereo(2))
    write_rig_file(folder / "rig.yaml", RigFile("cam0"))
    assert resolve_obstructed(folder).obstructed == "cam0"


def test_empty_bag_is_a_clear_error(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Writer2(tmp_path / "empty", version=9) as writer:
        for topic in ("/cam0/image_raw", "/cam1/image_raw"):
            writer.add_connection(topic, IMAGE, typestore=store)
    said = r"empty: no cam0 frames could be listed: its topic /cam0/image_raw holds no message"
    with pytest.raises(CaptureError, match=said):  # it named neither the topic nor why
        open_recording(tmp_path / "empty")


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_header_stamps_never_set_are_replaced_by_the_log_time(tmp_path: Path, kind: str) -> None:
    # A driver that never sets header.stamp (all 0): every frame but the first was
    # a "duplicate timestamp", and a 4-frame recording came down to one frame.
    messages = []
    for i in range(4):
        log = T0 + i * 50 * MS
        for camera in (0, 1):
            fields = {**_raw_fields(_image(10 * camera + i), "mono8"), "_log_ns": log + camera}
            messages.append((f"/cam{camera}/image_raw", IMAGE, 0, fields))
    recording = open_recording(_write_bag(tmp_path / "run", kind, messages))
    assert recording.timestamps("cam0") == [T0 + i * 50 * MS for i in range(4)]
    assert recording.timestamps("cam1") == [T0 + i * 50 * MS + 1 for i in range(4)]
    (said,) = recording.problems
    assert said.camera is None and not said.dropped
    assert "every header.stamp of /cam0/image_raw 0 ns, /cam1" in said.reason
    assert "timed by the bag's log time" in said.reason
    # turned round in memory, it is the bag read the other way round, its problems too
    crossed = read_bag(recording.path, ("/cam1/image_raw", "/cam0/image_raw"))
    assert recording.swapped() == crossed and crossed.problems
    for camera in ("cam0", "cam1"):  # each frame still loads, and is the right one
        for i, frame in enumerate(recording.frames[camera]):  # type: ignore[index]
            expected = _image(10 * int(camera[-1]) + i)
            np.testing.assert_array_equal(recording.load(frame), expected)


def test_a_bayer_frame_too_small_to_demosaic_is_one_line() -> None:
    from lenspair.capture.image_messages import decode_raw

    data = np.full((2, 8), 200, np.uint8).tobytes()  # OpenCV gave an all-black image
    with pytest.raises(CaptureError, match=r"^x: 8x2 Bayer image: too small to demosaic$"):
        decode_raw(2, 8, "bayer_rggb8", False, 8, data, "x")


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_bayer_frames_are_demosaiced_to_rgb_and_written_back_as_their_mosaic(
    tmp_path: Path, pattern: str, dtype: type
) -> None:
    # bayer_rggb8 and kin (raw frames of most colour machine-vision cameras) were
    # "unsupported encoding"
    from lenspair.capture.bagwrite import encode_image, mosaic
    from lenspair.capture.image_messages import decode_message

    top = np.iinfo(dtype).max
    colours = np.array([[0.9, 0.2, 0.1], [0.1, 0.8, 0.3], [0.2, 0.3, 0.9]]) * top
    rgb = np.zeros((24, 36, 3), dtype)
    for index, colour in enumerate(colours):  # three flat blocks: red, green, blue
        rgb[:, 12 * index : 12 * (index + 1)] = colour.astype(dtype)
    raw = mosaic(rgb, pattern)
    encoding = f"bayer_{pattern}{8 if dtype == np.uint8 else 16}"
    messages = [
        (f"/cam{c}/image_raw", IMAGE, T0, _raw_fields(raw, encoding, big=dtype == np.uint16))
        for c in (0, 1)
    ]
    recording = open_recording(_write_bag(tmp_path / "run", "ros1", messages))
    decoded = recording.load(recording.frames["cam0"][0])
    assert decoded.shape == (24, 36, 3) and decoded.dtype == dtype
    for index, colour in enumerate(colours):  # block centres: the block's own colour
        centre = decoded[8:16, 12 * index + 4 : 12 * index + 8].reshape(-1, 3).astype(float)
        np.testing.assert_allclose(centre.mean(axis=0), colour.astype(dtype), atol=0.01 * top)
    # restore writes a frame back in its mosaic: each site keeps its own colour's value
    store = get_typestore(Stores.ROS1_NOETIC)
    fields = _raw_fields(raw, encoding)
    header = store.types["std_msgs/msg/Header"](
        seq=0, stamp=store.types["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="c"
    )
    message = store.types[IMAGE](header=header, **fields)
    back = decode_message(IMAGE, encode_image(IMAGE, message, decoded), "x")
    # (OpenCV's demosaicing keeps each site's own value but on the frame's outer rows)
    np.testing.assert_array_equal(mosaic(back, pattern)[1:-1, 1:-1], raw[1:-1, 1:-1])
