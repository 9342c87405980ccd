"""Re-encoding restored pixels into image messages: every writable encoding round-trips."""

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.interfaces import MessageDefinitionFormat
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.bagwrite import BagCopy, compressed_codec, encode_image, is_storage_file
from lenspair.capture.errors import CaptureError
from lenspair.capture.image_messages import (
    BAYER_PATTERNS,
    COMPRESSED_IMAGE,
    RAW_IMAGE,
    compressed_mosaic,
    decode_message,
)
from tests.capture.test_rosbag import _write_bag
from tests.images import texture

STORE = get_typestore(Stores.ROS2_HUMBLE)
TYPES = STORE.types


def _header() -> object:
    stamp = TYPES["builtin_interfaces/msg/Time"](sec=12, nanosec=34)
    return TYPES["std_msgs/msg/Header"](stamp=stamp, frame_id="cam1")


def _raw(encoding: str, shape: tuple[int, ...], dtype: type, bigendian: bool = False) -> object:
    channels = 1 if len(shape) == 2 else shape[2]
    itemsize = np.dtype(dtype).itemsize
    step = shape[1] * channels * itemsize + 6  # row padding, as some drivers write
    return TYPES[RAW_IMAGE](
        header=_header(),
        height=shape[0],
        width=shape[1],
        encoding=encoding,
        is_bigendian=int(bigendian),
        step=step,
        data=np.zeros(step * shape[0], dtype=np.uint8),
    )


@pytest.mark.parametrize(
    ("encoding", "channels", "dtype", "bigendian"),
    [
        ("mono8", 1, np.uint8, False),
        ("mono16", 1, np.uint16, True),
        ("16UC1", 1, np.uint16, False),
        ("rgb8", 3, np.uint8, False),
        ("bgr8", 3, np.uint8, False),
        ("bgr16", 3, np.uint16, False),
    ],
)
def test_raw_encodings_round_trip(
    encoding: str, channels: int, dtype: type, bigendian: bool
) -> None:
    shape = (5, 7) if channels == 1 else (5, 7, 3)
    rng = np.random.default_rng(0)
    image = rng.integers(0, np.iinfo(dtype).max, shape, dtype=dtype, endpoint=True)
    original = _raw(encoding, shape, dtype, bigendian)
    message = encode_image(RAW_IMAGE, original, image)
    assert message.encoding == encoding and message.header == original.header  # type: ignore[attr-defined]
    serialised = STORE.serialize_cdr(message, RAW_IMAGE)
    decoded = decode_message(RAW_IMAGE, STORE.deserialize_cdr(serialised, RAW_IMAGE), "test")
    np.testing.assert_array_equal(decoded, image)


@pytest.mark.parametrize("fmt", ["png", "mono16; png compressed"])
def test_compressed_png_round_trips_exactly(fmt: str) -> None:
    dtype = np.uint16 if "16" in fmt else np.uint8
    rng = np.random.default_rng(1)
    image = rng.integers(0, np.iinfo(dtype).max, (6, 9), dtype=dtype, endpoint=True)
    original = TYPES[COMPRESSED_IMAGE](header=_header(), format=fmt, data=np.zeros(1, np.uint8))
    message = encode_image(COMPRESSED_IMAGE, original, image)
    assert message.format == fmt  # type: ignore[attr-defined]
    np.testing.assert_array_equal(decode_message(COMPRESSED_IMAGE, message, "test"), image)


def test_rgb_compressed_keeps_channel_order() -> None:
    image = np.zeros((8, 8, 3), np.uint8)
    image[..., 0] = 200  # red
    original = TYPES[COMPRESSED_IMAGE](header=_header(), format="png", data=np.zeros(1, np.uint8))
    decoded = decode_message(COMPRESSED_IMAGE, encode_image(COMPRESSED_IMAGE, original, image), "t")
    np.testing.assert_array_equal(decoded, image)


@pytest.mark.parametrize("encoding", ["rgba8", "bgra8"])
def test_rgba_frames_are_written_back_in_colour_with_their_recorded_alpha(encoding: str) -> None:
    # restore could not write these back: every frame of a ZED (bgra8) failed, copied as it was
    rng = np.random.default_rng(3)
    recorded = rng.integers(0, 256, (5, 7, 4), dtype=np.uint8)  # in the message's order
    padded = np.zeros((5, 7 * 4 + 6), np.uint8)  # rows padded, as _raw's step says
    padded[:, : 7 * 4] = recorded.reshape(5, -1)
    original = replace(_raw(encoding, (5, 7, 4), np.uint8), data=padded.reshape(-1))  # type: ignore[type-var]
    restored = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)  # RGB
    message = encode_image(RAW_IMAGE, original, restored)
    assert (message.encoding, message.step) == (encoding, 7 * 4)  # type: ignore[attr-defined]
    np.testing.assert_array_equal(decode_message(RAW_IMAGE, message, "t"), restored)
    written = np.asarray(message.data).reshape(5, 7, 4)  # type: ignore[attr-defined]
    np.testing.assert_array_equal(written[:, :, 3], recorded[:, :, 3])
    colour = written[:, :, :3] if encoding == "rgba8" else written[:, :, 2::-1]
    np.testing.assert_array_equal(colour, restored)


def test_a_colour_image_cannot_be_written_as_a_mono_message() -> None:
    original = _raw("mono8", (4, 4), np.uint8)
    with pytest.raises(CaptureError, match="cannot write restored pixels as encoding 'mono8'"):
        encode_image(RAW_IMAGE, original, np.zeros((4, 4, 3), np.uint8))


def test_a_jpeg_message_is_encoded_at_the_quality_asked_and_a_png_is_not_affected() -> None:
    # a JPEG CompressedImage was always encoded at OpenCV's default quality (95)
    image = (texture((96, 128), seed=4) * 255).astype(np.uint8)

    def encoded(fmt: str, quality: int | None) -> bytes:
        original = TYPES[COMPRESSED_IMAGE](header=_header(), format=fmt, data=np.zeros(1, np.uint8))
        return bytes(encode_image(COMPRESSED_IMAGE, original, image, quality).data)  # type: ignore[attr-defined]

    assert encoded("jpeg", None) == encoded("jpeg", 95)  # None: OpenCV's default
    assert len(encoded("jpeg", 30)) < 0.5 * len(encoded("jpeg", 95))
    low = TYPES[COMPRESSED_IMAGE](header=_header(), format="jpeg", data=np.zeros(1, np.uint8))
    decoded = decode_message(COMPRESSED_IMAGE, encode_image(COMPRESSED_IMAGE, low, image, 30), "t")
    assert decoded.shape == image.shape and np.abs(decoded.astype(float) - image).mean() < 12
    assert encoded("png", 1) == encoded("png", None)  # lossless whatever the quality


def _yuv_message(encoding: str, packed: np.ndarray) -> object:
    height, width = packed.shape[0], packed.shape[1] // 2
    return replace(
        _raw("mono8", (height, width), np.uint8),  # type: ignore[type-var]
        encoding=encoding,
        step=width * 2,
        data=np.ascontiguousarray(packed).reshape(-1),
    )


@pytest.mark.parametrize(
    ("encoding", "luma_at"), [("yuv422", 1), ("uyvy", 1), ("yuv422_yuy2", 0), ("yuyv", 0)]
)
def test_packed_yuv422_frames_are_read_in_their_byte_order(encoding: str, luma_at: int) -> None:
    # a USB camera's raw yuv422 frames were refused as an unsupported encoding
    packed = np.full((2, 4), 128, np.uint8)  # no chroma: grey pixels
    packed[:, luma_at] = 40  # the first pixel's luma
    packed[:, luma_at + 2] = 210  # the second's
    rgb = decode_message(RAW_IMAGE, _yuv_message(encoding, packed), "t")
    assert rgb.shape == (2, 2, 3)
    assert np.ptp(rgb.astype(int), axis=2).max() <= 1  # grey stays grey
    assert rgb[0, 0, 0] < 60 and rgb[0, 1, 0] > 200  # each pixel its own luma


@pytest.mark.parametrize("encoding", ["yuv422", "yuv422_yuy2"])
def test_restored_yuv422_frames_are_packed_back(encoding: str) -> None:
    # the colour of two neighbours is shared: an image whose colour changes only every two
    # columns comes back within the rounding of the conversion
    rng = np.random.default_rng(5)
    image = np.repeat(rng.integers(30, 220, (6, 4, 3), dtype=np.uint8), 2, axis=1)
    original = _yuv_message(encoding, np.zeros((6, 16), np.uint8))
    message = encode_image(RAW_IMAGE, original, image)
    assert (message.encoding, message.step) == (encoding, 8 * 2)  # type: ignore[attr-defined]
    decoded = decode_message(RAW_IMAGE, message, "t")
    assert np.abs(decoded.astype(int) - image).max() <= 3


def test_a_yuv422_frame_of_odd_width_is_one_line_naming_it() -> None:
    message = replace(_yuv_message("yuv422", np.zeros((2, 6), np.uint8)), width=3)  # type: ignore[type-var]
    with pytest.raises(CaptureError, match=r"^run @ 1: yuv422 image of odd width 3$"):
        decode_message(RAW_IMAGE, message, "run @ 1")


@pytest.mark.parametrize(
    ("fmt", "extension", "dtype"),
    [
        ("", ".png", np.uint16),
        ("mono16; tiff", ".tif", np.uint16),
        ("tiff", ".tif", np.uint8),
        ("", ".png", np.uint8),
    ],
)
def test_a_compressed_image_is_written_back_in_the_codec_its_payload_was_written_in(
    fmt: str, extension: str, dtype: type
) -> None:
    # chosen by whether the format said "png", a 16-bit PNG with an empty format and a
    # 16-bit TIFF came back as 8-bit JPEGs, their samples clipped to 255
    rng = np.random.default_rng(7)
    top = np.iinfo(dtype).max
    recorded, restored = (rng.integers(0, top, (6, 9), dtype=dtype, endpoint=True) for _ in "ab")
    payload = np.asarray(cv2.imencode(extension, recorded)[1], np.uint8).reshape(-1)
    original = TYPES[COMPRESSED_IMAGE](header=_header(), format=fmt, data=payload)
    message = encode_image(COMPRESSED_IMAGE, original, restored)
    written = bytes(message.data[:4])  # type: ignore[attr-defined]
    assert written == bytes(payload[:4]) and message.format == fmt  # type: ignore[attr-defined]
    decoded = decode_message(COMPRESSED_IMAGE, message, "t")
    assert decoded.dtype == dtype
    np.testing.assert_array_equal(decoded, restored)


def test_a_16_bit_image_is_not_written_as_a_jpeg() -> None:
    original = TYPES[COMPRESSED_IMAGE](header=_header(), format="jpeg", data=np.zeros(1, np.uint8))
    with pytest.raises(
        CaptureError, match=r"^cannot write a uint16 image as JPEG \(format 'jpeg'\)$"
    ):
        encode_image(COMPRESSED_IMAGE, original, np.zeros((4, 4), np.uint16))


@settings(max_examples=60, deadline=None)
@given(
    shape=st.tuples(st.integers(3, 12), st.integers(3, 12)),
    pattern=st.sampled_from(BAYER_PATTERNS),
    sixteen=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_a_bayer_frame_comes_back_as_recorded_border_and_all(
    shape: tuple[int, int], pattern: str, sixteen: bool, seed: int
) -> None:
    # OpenCV fills the outermost pixels of its demosaic from their neighbours: sampled
    # back, a frame the network left alone came back with its border samples changed
    dtype = np.uint16 if sixteen else np.uint8
    recorded = np.random.default_rng(seed).integers(0, np.iinfo(dtype).max, shape, dtype=dtype)
    encoding = f"bayer_{pattern}{16 if sixteen else 8}"
    original = replace(
        _raw("mono16" if sixteen else "mono8", shape, dtype),  # type: ignore[type-var]
        encoding=encoding,
        step=shape[1] * recorded.itemsize,
        data=recorded.astype(recorded.dtype.newbyteorder("<")).view(np.uint8).reshape(-1),
    )
    rgb = decode_message(RAW_IMAGE, original, "t")
    assert rgb.shape == (*shape, 3)
    message = encode_image(RAW_IMAGE, original, rgb)
    written = np.frombuffer(bytes(message.data), dtype=recorded.dtype.newbyteorder("<"))  # type: ignore[attr-defined]
    np.testing.assert_array_equal(written.reshape(shape), recorded)


def test_a_compressed_bayer_mosaic_is_demosaiced_and_written_back_as_a_mosaic() -> None:
    # read as one grey channel, the mosaic's checkerboard was "restored" as a grey image
    recorded = np.random.default_rng(2).integers(0, 256, (8, 10), dtype=np.uint8)
    payload = np.asarray(cv2.imencode(".png", recorded)[1], np.uint8).reshape(-1)
    fmt = "bayer_rggb8; png compressed "
    original = TYPES[COMPRESSED_IMAGE](header=_header(), format=fmt, data=payload)
    rgb = decode_message(COMPRESSED_IMAGE, original, "t")
    raw = replace(
        _raw("mono8", (8, 10), np.uint8),  # type: ignore[type-var]
        encoding="bayer_rggb8",
        step=10,
        data=recorded.reshape(-1),
    )
    np.testing.assert_array_equal(rgb, decode_message(RAW_IMAGE, raw, "t"))
    message = encode_image(COMPRESSED_IMAGE, original, rgb)
    back = cv2.imdecode(np.asarray(message.data), cv2.IMREAD_UNCHANGED)  # type: ignore[attr-defined]
    np.testing.assert_array_equal(back, recorded)
    assert compressed_mosaic(fmt) == "rggb"
    assert compressed_mosaic("bayer_rggb8; jpeg compressed bgr8") is None  # colour inside
    assert compressed_mosaic("bayer_gbrg16") == "gbrg"
    assert compressed_mosaic("rgb8; png compressed rgb8") is None


def test_a_definition_labelled_idl_is_read_as_idl_though_not_in_sections(
    tmp_path: Path,
) -> None:
    # parsed as .msg text, a bare IDL definition (rosbags' reader takes it) failed the topic
    idl = (
        "module custom_msgs {\n  module msg {\n    struct Exposure {\n"
        "      uint32 exposure_us;\n    };\n  };\n};\n"
    )
    source = _write_bag(tmp_path / "src", "mcap", [])
    copy = BagCopy(source, tmp_path / "copy")
    connection = SimpleNamespace(
        topic="/cam0/exposure",
        msgtype="custom_msgs/msg/Exposure",
        msgdef=SimpleNamespace(data=idl, format=MessageDefinitionFormat.IDL),
    )
    store = copy._store(connection)
    message = store.types["custom_msgs/msg/Exposure"](exposure_us=700)
    raw = store.serialize_cdr(message, "custom_msgs/msg/Exposure")
    assert store.deserialize_cdr(raw, "custom_msgs/msg/Exposure").exposure_us == 700


@pytest.mark.parametrize(
    ("name", "storage"),
    [
        ("run.db3", True),
        ("run.db3-wal", True),
        ("run_0.mcap.zstd", True),
        ("rec.2026.11.29.mcap", True),
        ("metadata.yaml", True),
        ("notes.db3.txt", False),  # was taken for storage (a .db3 suffix anywhere) and not copied
        ("run_0.mcap.sha256", False),
        ("rig.yaml", False),
    ],
)
def test_which_files_of_a_bag_folder_are_its_storage(name: str, storage: bool) -> None:
    assert is_storage_file(Path(name)) is storage


def test_the_codec_is_told_from_a_payload_given_as_bytes_too() -> None:
    png = bytes(cv2.imencode(".png", np.zeros((2, 2), np.uint8))[1])
    assert compressed_codec("", png) == ".png"
    assert compressed_codec("jpeg", np.frombuffer(png, np.uint8)) == ".png"
    assert compressed_codec("png", b"") == ".png" and compressed_codec("", b"\x00") == ".jpg"
