"""``left/`` + ``right/`` image folders with timestamps in the file names.

Layout::

    <rec>/left/1403636579763555584.png     cam0
    <rec>/right/1403636579763555584.png    cam1

The timestamp is the last group of digits of the file stem, in nanoseconds
(``left_000017_1403636579763555584.png`` works too), or seconds with a
fraction when the stem ends in ``<digits>.<digits>`` (``1403636579.7635.png``),
or seconds and nanoseconds when it ends in ``<9-10 digits>_<up to 9 digits>``
(or ``-``), as ROS tools name frames (``1403636579_763555584.png``; an
unpadded ``1403636579_5.png`` is 5 ns past the second): read as
nanoseconds alone, those would lose their seconds and pair frames of
different seconds.
Hidden files and files that are not images are ignored. Folders have no
recording order, so frames are taken in time order; two files with the same
timestamp keep the first by name and record the other.
"""

import re
from collections.abc import Sequence
from pathlib import Path

from lenspair.capture.errors import CaptureError
from lenspair.capture.recording_types import (
    CAMERAS,
    FrameProblem,
    FrameRef,
    Recording,
    order_frames,
    recording_id_for,
)
from lenspair.capture.rigfile import CameraName

IMAGE_SUFFIXES = frozenset({".png", ".tif", ".tiff", ".jpg", ".jpeg", ".pgm", ".ppm", ".bmp"})
FOLDER_NAMES: dict[CameraName, str] = {"cam0": "left", "cam1": "right"}

_SECONDS = re.compile(r"(\d+)\.(\d{1,9})$")
_SECONDS_NANOSECONDS = re.compile(r"(?<!\d)(\d{9,10})[_-](\d{1,9})$")
"""Unix seconds (9-10 digits: 1973 to 2286) and a nanosecond field of up to 9 digits
(export scripts that print ``f"{secs}_{nsecs}"`` do not zero-pad it)."""
_LAST_DIGITS = re.compile(r"(\d+)\D*$")


def timestamp_from_name(name: str) -> int | None:
    """Timestamp (ns) encoded in an image file name, or None when there is none.

    Args:
        name: file name with extension, e.g. ``1403636579763555584.png``.

    Returns:
        Nanoseconds: the stem's last digit group, or ``<s>.<fraction>`` read as
        seconds, or ``<s>_<ns>`` (module docstring).
    """
    stem = Path(name).stem
    fraction = _SECONDS.search(stem)
    if fraction is not None:  # a decimal fraction: "5" is half a second
        return int(fraction.group(1)) * 1_000_000_000 + int(fraction.group(2).ljust(9, "0"))
    split = _SECONDS_NANOSECONDS.search(stem)
    if split is not None:  # a nanosecond count: "5" is five nanoseconds
        return int(split.group(1)) * 1_000_000_000 + int(split.group(2))
    digits = _LAST_DIGITS.search(stem)
    return int(digits.group(1)) if digits is not None else None


def image_files(folder: Path) -> list[Path]:
    """Visible image files of ``folder`` (not recursive), sorted by name."""
    return sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".") and p.is_file()
    )


def list_image_folder(
    camera: CameraName, folder: Path, problems: list[FrameProblem]
) -> list[FrameRef]:
    """Frames of one camera from image file names.

    Args:
        camera: the camera the folder belongs to.
        folder: folder of images named by timestamp.
        problems: appended to: files without a timestamp, duplicate timestamps.

    Returns:
        Frames sorted by ``t_ns``, unique timestamps.
    """
    frames = []
    for file in image_files(folder):
        t_ns = timestamp_from_name(file.name)
        if t_ns is None:
            problems.append(FrameProblem(camera, None, str(file), "no timestamp in file name"))
            continue
        frames.append(FrameRef(camera, t_ns, file))
    frames.sort(key=lambda f: f.t_ns)  # stable: same timestamps keep name order
    return order_frames(camera, frames, problems)


def is_left_right(path: Path) -> bool:
    """True when ``path`` holds a ``left/`` or a ``right/`` folder."""
    return any((Path(path) / name).is_dir() for name in FOLDER_NAMES.values())


def read_folders(path: Path, cameras: Sequence[CameraName] = CAMERAS) -> Recording:
    """List a ``left/`` + ``right/`` recording (its ``cameras``: ``left/`` is cam0).

    Raises:
        CaptureError: one of the two folders is missing, or a camera has no
            frames.
    """
    path = Path(path)
    problems: list[FrameProblem] = []
    frames: dict[CameraName, list[FrameRef]] = {}
    for camera in cameras:
        folder = path / FOLDER_NAMES[camera]
        if not folder.is_dir():
            raise CaptureError(
                f"{folder}: missing camera folder ({camera}); expected left/ and right/"
            )
        frames[camera] = list_image_folder(camera, folder, problems)
    return Recording(path, recording_id_for(path), "folders", frames, problems)
