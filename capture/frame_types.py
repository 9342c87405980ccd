"""What the frame sources yield: a decoded frame of any input, and a bag message.

:class:`InputFrame` is one frame of an image, folder, recording or bag
(:func:`lenspair.capture.frames.iter_frames`); :class:`BagMessage` is one
message of a bag, carrying its :class:`InputFrame` when it is an image of a
chosen camera (:func:`lenspair.capture.bag_frames.iter_bag_messages`). Both
live apart from the readers so that consumers (restore's sinks, the detector's
report, :mod:`lenspair.capture.bagwrite`) need not import them.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from lenspair.capture.rigfile import CameraName


@dataclass(frozen=True)
class InputFrame:
    """One frame of an input, decoded (or not, with the reason).

    Attributes:
        index: position among the frames yielded (0-based, input order).
        name: stable identifier; for files the path relative to the input
            folder (POSIX), for bags ``<topic>@<log_time_ns>#<occurrence>``.
        camera: ``cam0``/``cam1`` for recordings and bags, None otherwise.
        t_ns: timestamp (ns) when the input has one, else None.
        source: where it came from, for messages (file, or ``bag topic @ t``).
        image: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)`` RGB, or None
            when it could not be read.
        error: one line saying why ``image`` is None.
        log_time_ns: a bag message's receive time (ns), else None.
    """

    index: int
    name: str
    camera: CameraName | None
    t_ns: int | None
    source: str
    image: np.ndarray | None
    error: str | None = None
    log_time_ns: int | None = None


@dataclass(frozen=True)
class BagMessage:
    """One message of a bag, in log-time order, with its image decoded when chosen.

    Attributes:
        connection: the ``rosbags`` connection it was recorded on.
        log_time_ns: the bag's receive time (ns).
        raw: serialised bytes as stored (ROS1 or CDR).
        frame: the decoded frame when the message is an image of a chosen
            camera topic, else None.
        message: the deserialised message when ``frame`` is set (to re-encode).
    """

    connection: Any
    log_time_ns: int
    raw: bytes
    frame: InputFrame | None = None
    message: Any = None
