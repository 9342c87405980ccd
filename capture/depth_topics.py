"""Depth and disparity maps in a bag: never chosen as a camera by themselves.

A RealSense, ZED or OAK-D bag holds depth maps beside its cameras
(``/camera/depth/image_rect_raw``, ``16UC1`` millimetres; OAK-D's
``/oak/stereo/image_raw``). Chosen as a camera ("the only two image topics"),
a depth map was "restored" (rewritten, exit 0) or paired with a camera. A
topic is a depth topic when its name says so (:func:`is_depth_topic`) or when
its first message does (:func:`depth_topics`: a raw ``16UC1``/``32FC1`` image,
or a ``compressedDepth`` one). ``--topics`` still names one.
"""

import re
from collections.abc import Collection, Sequence
from contextlib import suppress
from pathlib import Path
from typing import Any

from lenspair.capture.bag_cursor import first_message
from lenspair.capture.errors import CaptureError
from lenspair.capture.image_messages import COMPRESSED_IMAGE, RAW_IMAGE

DEPTH_WORDS = ("depth", "disparity")
"""Words that name a depth or disparity map's topic."""
_DEPTH_WORD = re.compile(rf"(?<![a-z0-9])(?:{'|'.join(DEPTH_WORDS)})(?![a-z])")
DEPTH_ENCODINGS = frozenset({"16uc1", "32fc1"})
"""Raw encodings of depth maps (millimetres, metres); cameras publish ``mono16``."""
_DEPTH_RULE = (
    "a depth topic (named depth or disparity, or a 16UC1, 32FC1 or compressedDepth image) "
    "is read as a camera only when named with --topics CAM0 CAM1"
)


def is_depth_topic(topic: str) -> bool:
    """True for a topic named as a depth or disparity map (a word of its name, any case).

    The word alone or in a longer name (``aligned_depth_to_color``, ``depth2``),
    not inside another word (``/depthai/left`` stays a camera).
    """
    return _DEPTH_WORD.search(topic.lower()) is not None


def depth_topics(reader: Any, image_topics: Sequence[str]) -> list[str]:
    """The image topics of an open bag that hold depth maps, by name or by first message.

    One message of each topic not named as depth is read: a raw image whose
    encoding is ``16UC1``/``32FC1``, or a ``CompressedImage`` whose format
    says ``compressedDepth``. A topic whose first message cannot be read is
    taken as a camera (its frames then fail one by one, named).
    """
    found = sorted(set(image_topics))
    depth = [topic for topic in found if is_depth_topic(topic)]
    for topic in found:
        if topic not in depth and _first_is_depth(reader, topic):
            depth.append(topic)
    return sorted(depth)


def _first_is_depth(reader: Any, topic: str) -> bool:
    with suppress(Exception):  # rosbags and its storage backends raise assorted types
        first = first_message(reader, topic)
        if first is None:
            return False
        connection, _, raw = first
        message = reader.deserialize(raw, connection.msgtype)
        if connection.msgtype == RAW_IMAGE:
            return str(message.encoding).lower() in DEPTH_ENCODINGS
        if connection.msgtype == COMPRESSED_IMAGE:
            return "compresseddepth" in str(message.format).lower().replace(" ", "")
    return False


def camera_candidates(
    image_topics: Sequence[str], bag: Path, depth: Collection[str] = ()
) -> tuple[list[str], list[str]]:
    """The image topics (sorted, once each) that may be chosen as cameras, and the depth ones.

    Depth topics are those named so (:func:`is_depth_topic`) and ``depth``
    (:func:`depth_topics`, for a caller that has read the first messages).

    Raises:
        CaptureError: every image topic is a depth topic (names them).
    """
    found = sorted(set(image_topics))
    left_out = [topic for topic in found if is_depth_topic(topic) or topic in depth]
    cameras = [topic for topic in found if topic not in left_out]
    if left_out and not cameras:
        raise CaptureError(
            f"{bag}: the only image topics are depth topics ({', '.join(left_out)}); {_DEPTH_RULE}"
        )
    return cameras, left_out


def depth_note(depth: Sequence[str]) -> str:
    """One line saying which depth topics the automatic choice left out (without the bag)."""
    return f"depth image topics not chosen as cameras: {', '.join(depth)} ({_DEPTH_RULE})"
