"""Re-encoding restored pixels into image messages: every writable encoding round-trips."""

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.bagwrite import encode_image
from lenspair.capture.errors import CaptureError
from lenspair.capture.image_messages import COMPRESSED_IMAGE, RAW_IMAGE, decode_message
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


def test_rgba_cannot_be_written_back() -> None:
    original = _raw("rgba8", (4, 4, 4), np.uint8)
    with pytest.raises(CaptureError, match="rgba8"):
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
