"""A stereo calibration from a bag's own ``camera_info`` topics, for ``capture-ingest``.

A robot's bag usually records each camera's ``sensor_msgs/CameraInfo`` beside
its images (``/stereo/left/camera_info`` beside ``/stereo/left/image_raw``):
the calibration its driver was given, by ROS's ``camera_calibration`` for a
stereo pair. When no calibration file is found, ``capture-ingest`` reads the
first message of each chosen camera's ``camera_info`` and takes the rig from
the two as from two camera_info YAML files
(:func:`lenspair.rectify.calib_ros.from_ros`): intrinsics from ``K`` and
``D``, the extrinsic from the rectification and projection matrices.
"""

from pathlib import Path
from typing import Any

import yaml

from lenspair.capture.bag_cursor import first_message
from lenspair.capture.errors import CaptureError
from lenspair.capture.image_messages import one_line
from lenspair.capture.rosbag import open_bag
from lenspair.rectify.calib_ros import from_ros, message_as_camera_info
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import StereoRig

CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
INFO_NAME = "camera_info"


def info_topic(image_topic: str, info_topics: set[str]) -> str | None:
    """The ``camera_info`` topic of a camera's image topic, or None.

    The one in the image topic's namespace, or in the namespace above
    (``/cam/left/image_raw/compressed`` -> ``/cam/left/camera_info``).
    """
    namespace = image_topic
    for _ in range(3):
        namespace = namespace.rsplit("/", 1)[0]
        if f"{namespace}/{INFO_NAME}" in info_topics:
            return f"{namespace}/{INFO_NAME}"
        if not namespace:
            break
    return None


def bag_calibration(bag: Path, image_topics: tuple[str, str]) -> tuple[StereoRig, str] | None:
    """The rig in the ``camera_info`` of the bag's two chosen cameras (cam0's first).

    Returns:
        ``(rig, description)``, or None when either camera has no
        ``camera_info`` topic or no message on it.

    Raises:
        CaptureError: the bag's camera_info cannot be read or holds no usable
            calibration (a driver never calibrated publishes zeros), naming
            the topic and saying to pass ``--calib``.
    """
    reader = open_bag(bag)
    try:
        infos = {name for name, info in reader.topics.items() if info.msgtype == CAMERA_INFO}
        topics = [info_topic(topic, infos) for topic in image_topics]
        if None in topics:
            return None
        texts = []
        for topic in topics:
            message = _first_message(reader, str(topic), bag)
            if message is None:
                return None
            texts.append(yaml.safe_dump(_as_camera_info_file(message, str(topic))))
    finally:
        reader.close()
    paths = [Path(f"{bag}:{topic}") for topic in topics]
    try:
        return from_ros(paths, texts)
    except RectifyError as exc:
        raise CaptureError(
            f"{exc} (the bag's camera_info holds no usable calibration: pass --calib FILE)"
        ) from None


def _first_message(reader: Any, topic: str, bag: Path) -> Any:
    try:
        first = first_message(reader, topic)
        return None if first is None else reader.deserialize(first[2], first[0].msgtype)
    except Exception as exc:  # rosbags and its storage backends raise assorted types
        raise CaptureError(f"{bag}: cannot read {topic} ({one_line(exc)})") from None


def _as_camera_info_file(message: Any, topic: str) -> dict[str, Any]:
    """A ``CameraInfo`` message as the YAML ``camera_calibration`` writes (ROS 1 or 2 names)."""
    names = ("width", "height", "distortion_model", "K", "D", "R", "P", "binning_x", "binning_y")
    fields = {}
    for name in names:
        value = getattr(message, name, None)
        fields[name] = getattr(message, name.lower(), None) if value is None else value
    fields["roi"] = getattr(message, "roi", None)
    return message_as_camera_info(fields, topic)
