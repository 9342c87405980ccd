"""Decoding ROS image messages (``sensor_msgs/Image``, ``CompressedImage``) into arrays.

What :mod:`lenspair.capture.rosbag` reads a frame's pixels with, and what
:mod:`lenspair.capture.bag_frames` and :mod:`lenspair.capture.bagwrite` name message
types and Bayer encodings by. Messages of type ``sensor_msgs/msg/Image``
(encodings ``mono8``/``8UC1``, ``mono16``/``16UC1``, ``rgb8``, ``bgr8``,
``rgba8``, ``bgra8`` (colour only; :func:`raw_alpha` reads the alpha), ``rgb16``,
``bgr16``, the packed 4:2:2 ``yuv422``/``uyvy`` and ``yuv422_yuy2``/``yuyv``
(:data:`YUV422_CONVERSIONS`), and the Bayer mosaics
``bayer_rggb8`` ... ``bayer_grbg16``, demosaiced by OpenCV; ``step`` row
padding and ``is_bigendian`` respected; colour returned as RGB) and
``sensor_msgs/msg/CompressedImage`` (JPEG/PNG/TIFF, decoded with OpenCV; a
Bayer mosaic compressed as it was recorded is demosaiced; a PNG with an alpha
channel is that frame's error) are decoded. Images come back
``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)`` RGB, C-contiguous.
"""

from typing import Any

import cv2
import numpy as np

from lenspair.capture.errors import CaptureError

RAW_IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (RAW_IMAGE, COMPRESSED_IMAGE)

# encoding -> (dtype, channels, channel order to RGB or None)
_ENCODINGS: dict[str, tuple[type[np.unsignedinteger[Any]], int, tuple[int, ...] | None]] = {
    "mono8": (np.uint8, 1, None),
    "8uc1": (np.uint8, 1, None),
    "mono16": (np.uint16, 1, None),
    "16uc1": (np.uint16, 1, None),
    "rgb8": (np.uint8, 3, (0, 1, 2)),
    "bgr8": (np.uint8, 3, (2, 1, 0)),
    "rgba8": (np.uint8, 4, (0, 1, 2)),
    "bgra8": (np.uint8, 4, (2, 1, 0)),
    "rgb16": (np.uint16, 3, (0, 1, 2)),
    "bgr16": (np.uint16, 3, (2, 1, 0)),
}


YUV422_CONVERSIONS: dict[str, tuple[int, int]] = {
    "yuv422": (cv2.COLOR_YUV2RGB_UYVY, cv2.COLOR_RGB2YUV_UYVY),
    "uyvy": (cv2.COLOR_YUV2RGB_UYVY, cv2.COLOR_RGB2YUV_UYVY),
    "yuv422_yuy2": (cv2.COLOR_YUV2RGB_YUY2, cv2.COLOR_RGB2YUV_YUY2),
    "yuyv": (cv2.COLOR_YUV2RGB_YUY2, cv2.COLOR_RGB2YUV_YUY2),
}
"""ROS's packed 4:2:2 encodings (a USB camera's raw output): OpenCV's conversions to RGB
and back, as cv_bridge uses them. ``yuv422`` is UYVY (U Y0 V Y1), ``yuv422_yuy2`` is
YUYV; ``uyvy`` and ``yuyv`` are the newer names of the two."""

BAYER_PATTERNS = ("rggb", "bggr", "gbrg", "grbg")
"""ROS Bayer encodings ``bayer_<pattern>8`` / ``bayer_<pattern>16``: the colours of the
top-left 2x2 cell, row by row."""

# OpenCV names a Bayer pattern by the second row's second and third pixels, so ROS's
# rggb is OpenCV's BG (the mapping cv_bridge uses)
_DEMOSAIC = {
    "rggb": cv2.COLOR_BayerBG2RGB,
    "bggr": cv2.COLOR_BayerRG2RGB,
    "gbrg": cv2.COLOR_BayerGR2RGB,
    "grbg": cv2.COLOR_BayerGB2RGB,
}


def bayer_pattern(encoding: str) -> tuple[str, type[np.unsignedinteger[Any]]] | None:
    """``(pattern, dtype)`` of a ROS Bayer encoding (``bayer_rggb8``), else None."""
    key = encoding.lower()
    for pattern in BAYER_PATTERNS:
        for bits, dtype in (("8", np.uint8), ("16", np.uint16)):
            if key == f"bayer_{pattern}{bits}":
                return pattern, dtype
    return None


def demosaic(mosaic: np.ndarray, pattern: str, encoding: str, where: str) -> np.ndarray:
    """A Bayer ``mosaic`` (``rggb``...) as RGB, by OpenCV's bilinear demosaic.

    The mosaic is padded by two pixels, mirrored without repeating the edge
    (which keeps the pattern), and the padding cropped afterwards: OpenCV
    fills its outermost pixels from their neighbours, so a frame sampled back
    into its mosaic (:func:`lenspair.capture.bagwrite.mosaic`) changed its
    border samples even where the network changed nothing. Inside, each site
    keeps the sample it recorded.

    Raises:
        CaptureError: a mosaic under 3 pixels a side, or one OpenCV refuses,
            naming ``where`` and ``encoding``.
    """
    height, width = mosaic.shape[:2]
    if min(height, width) < 3:  # OpenCV returns black below 3 px
        raise CaptureError(f"{where}: {width}x{height} Bayer image: too small to demosaic")
    padded = cv2.copyMakeBorder(mosaic, 2, 2, 2, 2, cv2.BORDER_REFLECT_101)
    try:
        rgb = cv2.cvtColor(padded, _DEMOSAIC[pattern])
    except cv2.error as exc:  # one bad frame is that frame's problem, not the run's
        raise CaptureError(f"{where}: cannot demosaic {encoding} ({one_line(exc)})") from None
    return np.ascontiguousarray(rgb[2:-2, 2:-2])


def compressed_mosaic(fmt: str) -> str | None:
    """The Bayer pattern a ``CompressedImage``'s payload holds its mosaic in, or None.

    ``compressed_image_transport`` names the format ``<encoding>; <codec>
    compressed <payload encoding>``: ``bayer_rggb8; png compressed `` holds
    the mosaic itself (demosaiced as a raw Bayer frame is), while
    ``bayer_rggb8; jpeg compressed bgr8`` holds colour.
    """
    source, _, rest = str(fmt).lower().partition(";")
    held = rest.partition("compressed")[2].strip()
    pattern = bayer_pattern(source.strip())
    if pattern is None or (held and bayer_pattern(held) is None):
        return None
    return pattern[0]


def decode_message(msgtype: str, message: Any, where: str) -> np.ndarray:
    """Pixels of a deserialised ``Image`` or ``CompressedImage`` message (RGB order)."""
    if msgtype == COMPRESSED_IMAGE:
        return decode_compressed(message.format, message.data, where)
    return decode_raw(
        message.height,
        message.width,
        message.encoding,
        bool(message.is_bigendian),
        message.step,
        message.data,
        where,
    )


def decode_raw(
    height: int,
    width: int,
    encoding: str,
    is_bigendian: bool,
    step: int,
    data: np.ndarray | bytes,
    where: str,
) -> np.ndarray:
    """Decode ``sensor_msgs/Image`` fields into an array.

    Args:
        height: rows.
        width: columns.
        encoding: ROS image encoding (see module docstring).
        is_bigendian: byte order of 16-bit samples.
        step: bytes per row including padding (>= width * bytes per pixel).
        data: the ``uint8`` payload.
        where: names the message in errors.

    Returns:
        ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)`` RGB, native byte
        order, C-contiguous.

    Raises:
        CaptureError: unsupported encoding, zero size, ``step`` too small or
            payload shorter than ``step * (height - 1) + row bytes``.
    """
    key = encoding.lower()
    bayer = bayer_pattern(key)
    if bayer is not None:  # the raw mosaic, demosaiced to RGB (OpenCV, bilinear)
        mosaic = decode_raw(
            height, width, "mono16" if bayer[1] == np.uint16 else "mono8", is_bigendian, step,
            data, where,
        )  # fmt: skip
        return demosaic(mosaic, bayer[0], encoding, where)
    if key in YUV422_CONVERSIONS:  # two bytes a pixel, a chroma pair shared by two pixels
        if width % 2:
            raise CaptureError(f"{where}: {encoding} image of odd width {width}")
        packed = _samples(height, width, np.uint8, 2, False, step, data, where)
        return np.ascontiguousarray(cv2.cvtColor(packed, YUV422_CONVERSIONS[key][0]))
    if key not in _ENCODINGS:
        supported = ", ".join(
            [*sorted(_ENCODINGS), *YUV422_CONVERSIONS, "bayer_<rggb|bggr|gbrg|grbg><8|16>"]
        )
        raise CaptureError(f"{where}: unsupported encoding {encoding!r}; supported: {supported}")
    dtype, channels, order = _ENCODINGS[key]
    pixels = _samples(height, width, dtype, channels, is_bigendian, step, data, where)
    if order is None:
        return np.ascontiguousarray(pixels[:, :, 0])
    return np.ascontiguousarray(pixels[:, :, list(order)])


def colour_order(encoding: str) -> tuple[int, ...] | None:
    """The RGB channels of a raw colour encoding's samples (``bgr8``: ``(2, 1, 0)``), else None.

    Each order is its own inverse, so it also lays RGB out in the message's
    order (:func:`lenspair.capture.bagwrite.encode_image`); an alpha channel,
    which ``rgba8``/``bgra8`` add after the colour, is not among them.
    """
    entry = _ENCODINGS.get(encoding.lower())
    return None if entry is None else entry[2]


def raw_alpha(message: Any, where: str) -> np.ndarray | None:
    """The alpha channel of a raw ``rgba8``/``bgra8`` message, ``(H, W)``; None for others.

    What a restored frame of such a camera (a ZED publishes ``bgra8``) is
    written back with: :func:`decode_raw` returns its colour only.

    Raises:
        CaptureError: as :func:`decode_raw`, for a message too short or badly laid out.
    """
    key = str(message.encoding).lower()
    if key not in _ENCODINGS or _ENCODINGS[key][1] != 4:
        return None
    pixels = _samples(
        message.height, message.width, _ENCODINGS[key][0], 4, bool(message.is_bigendian),
        message.step, message.data, where,
    )  # fmt: skip
    return np.ascontiguousarray(pixels[:, :, 3])


def _samples(
    height: int,
    width: int,
    dtype: type[np.unsignedinteger[Any]],
    channels: int,
    is_bigendian: bool,
    step: int,
    data: np.ndarray | bytes,
    where: str,
) -> np.ndarray:
    """``(H, W, channels)`` samples of a raw image, in the message's order."""
    itemsize = np.dtype(dtype).itemsize
    row_bytes = width * channels * itemsize
    if height <= 0 or width <= 0:
        raise CaptureError(f"{where}: empty image ({height}x{width})")
    if step < row_bytes:
        raise CaptureError(f"{where}: step {step} is smaller than a row ({row_bytes} bytes)")
    payload = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes) else data
    payload = np.ascontiguousarray(payload, dtype=np.uint8).reshape(-1)
    needed = step * (height - 1) + row_bytes
    if payload.size < needed:
        raise CaptureError(f"{where}: truncated image data ({payload.size} of {needed} bytes)")
    rows = np.lib.stride_tricks.as_strided(payload, (height, row_bytes), (step, 1))
    sample = np.dtype(dtype).newbyteorder(">" if is_bigendian else "<")
    pixels = np.ascontiguousarray(rows).view(sample).astype(dtype)
    return pixels.reshape(height, width, channels)


def decode_compressed(fmt: str, data: np.ndarray | bytes, where: str) -> np.ndarray:
    """Decode a ``sensor_msgs/CompressedImage`` payload (JPEG/PNG) to mono or RGB.

    Returns:
        ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)`` RGB, C-contiguous.

    Raises:
        CaptureError: the payload is empty (a driver's failed frame), cannot
            be decoded, has an unsupported depth, or has an alpha channel (a
            PNG of grey or colour with alpha); names the message.
    """
    payload = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes) else data
    payload = np.ascontiguousarray(payload, dtype=np.uint8).reshape(-1)
    if payload.size == 0:  # OpenCV asserts on an empty buffer instead of returning None
        raise CaptureError(f"{where}: empty compressed image (format {fmt!r}, no data)")
    try:
        decoded = cv2.imdecode(payload, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:  # a decoder's assertion is this frame's problem, not the run's
        raise CaptureError(
            f"{where}: cannot decode compressed image (format {fmt!r}: {one_line(exc)})"
        ) from None
    if decoded is None:
        raise CaptureError(f"{where}: cannot decode compressed image (format {fmt!r})")
    image = np.asarray(decoded)
    if image.dtype not in (np.uint8, np.uint16):
        raise CaptureError(f"{where}: unsupported compressed sample type {image.dtype}")
    channels = 1 if image.ndim == 2 else image.shape[2]
    if channels in (2, 4):
        # Decoded without it, the alpha would be gone from a restored copy that still
        # says bgra8, and nothing would tell: the frame fails instead, named (as a raw
        # rgba8 frame does in restore, which cannot write that encoding back).
        raise CaptureError(
            f"{where}: compressed image with an alpha channel ({channels} channels, format "
            f"{fmt!r}): not read, since its alpha would be lost"
        )
    if channels not in (1, 3):
        raise CaptureError(f"{where}: compressed image of {channels} channels (format {fmt!r})")
    if image.ndim == 3 and channels == 1:
        image = image[:, :, 0]
    elif image.ndim == 3:  # OpenCV decodes colour as BGR
        image = image[:, :, ::-1]
    pattern = compressed_mosaic(fmt)
    if image.ndim == 2 and pattern is not None:  # a camera's mosaic, compressed as it was
        return demosaic(image, pattern, fmt, where)
    return np.ascontiguousarray(image)


def one_line(exc: BaseException) -> str:
    """``exc``'s message on one line of at most 200 characters (its type when it says nothing)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."
