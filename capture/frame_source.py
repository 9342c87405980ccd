"""Frames to judge or restore, from any input a robotics user has at hand.

:func:`input_frames` lists (never loads) the frames of:

* one image file (PNG/JPG/TIFF);
* a folder of images, searched recursively, sorted by relative path
  (recordings are not folders of images: a folder that is a recording is
  read as one);
* a stereo recording in any layout of :mod:`lenspair.capture.recording`
  (EuRoC/ASL, ROS 1 bag, ROS 2 bag, left/right folders): the frames of both
  cameras, ``cam0`` first, each sorted by time.

Each :class:`InputFrame` is small and picklable and names itself
(``name``: relative path, or ``cam0/<t_ns>``); :meth:`InputFrame.load` reads
the pixels (``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)``) and raises
:class:`lenspair.core.errors.ImageIOError` or ``CaptureError`` naming the
file, so a caller can record an unreadable frame and go on.

One module on purpose: ``detect`` and ``restore`` read the same inputs.
"""

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lenspair.capture.errors import CaptureError
from lenspair.capture.recording import FrameRef, load_frame, open_recording
from lenspair.core.imageio import read_image

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


@dataclass(frozen=True)
class InputFrame:
    """One frame of an input.

    Attributes:
        name: unique within the input: the path relative to the folder (or
            the file name), or ``<camera>/<t_ns>`` for recordings.
        camera: ``cam0``/``cam1`` for recordings, else None.
        t_ns: timestamp (ns) for recordings, else None.
        path: the image file, or None for a bag message.
        ref: the recording frame, or None for plain image files.
    """

    name: str
    camera: str | None = None
    t_ns: int | None = None
    path: Path | None = None
    ref: FrameRef | None = None

    def load(self) -> np.ndarray:
        """Read the pixels (see the module docstring)."""
        if self.ref is not None:
            return load_frame(self.ref)
        if self.path is None:
            raise CaptureError(f"{self.name}: frame has neither a file nor a recording reference")
        return read_image(self.path)


def _is_recording(path: Path) -> bool:
    from lenspair.capture import euroc, folders, rosbag

    if rosbag.is_bag(path):
        return True
    return path.is_dir() and (
        euroc.find_euroc_root(path) is not None or folders.is_left_right(path)
    )


def input_frames(path: Path, topics: tuple[str, str] | None = None) -> Iterator[InputFrame]:
    """The frames of ``path`` (module docstring), in a stable order.

    Raises:
        CaptureError: the path does not exist, or holds no image and is no recording.
    """
    path = Path(path)
    if not path.exists():
        raise CaptureError(f"{path}: no such file or folder")
    if _is_recording(path):
        recording = open_recording(path, topics)
        for camera in ("cam0", "cam1"):
            for ref in recording.frames[camera]:  # type: ignore[index]
                yield InputFrame(
                    f"{camera}/{ref.t_ns}",
                    camera,
                    ref.t_ns,
                    None if ref.in_bag else ref.source,
                    ref,
                )
        return
    if path.is_file():
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            raise CaptureError(f"{path}: not an image ({', '.join(IMAGE_SUFFIXES)}) or a bag")
        yield InputFrame(path.name, path=path)
        return
    files = sorted(
        p
        for p in path.rglob("*")
        if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file() and not p.name.startswith(".")
    )
    if not files:
        raise CaptureError(f"{path}: no images (PNG/JPG/TIFF) found and not a recording")
    for file in files:
        yield InputFrame(file.relative_to(path).as_posix(), path=file)
