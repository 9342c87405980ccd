"""Files of a folder input that may hold frames no command reads, and the line that says so.

A folder's other files are copied as they are (``restore``) or left unjudged
(``detect``), which is right for notes and calibration files but lets dirty
frames pass unnoticed when the file is a bag, a video, a camera raw file or
an image format that is not read: the report names each such file.
"""

from pathlib import Path

from lenspair.capture.folders import RAW_IMAGE_SUFFIXES, UNREAD_IMAGE_SUFFIXES
from lenspair.capture.rosbag import is_bag_name

VIDEO_SUFFIXES = frozenset(
    {".avi", ".mp4", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg", ".ogv"}
    | {".ts", ".m2ts", ".mts", ".flv", ".wmv", ".3gp"}
)
"""Video files: their frames are not read (split them into images first)."""
_MPEG_TS_SYNC = 0x47
"""The first byte of every MPEG transport stream packet."""


def _is_video(source: Path) -> bool:
    """Whether ``source`` is named as a video (an MPEG-TS ``.ts`` by its first byte too).

    ``.ts`` also names TypeScript sources, which a folder of a project's frames may
    hold beside its scripts: those must not be called videos in every report.
    """
    suffix = source.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        return False
    if suffix != ".ts":
        return True
    try:
        with source.open("rb") as stream:
            return stream.read(1) == bytes([_MPEG_TS_SYNC])
    except OSError:  # unreadable: named by its suffix, as the other videos are
        return True


def unread_frames_note(source: Path, command: str, left: str) -> str | None:
    """A line for a file of a folder input that may hold frames ``command`` did not read.

    Bags (a killed recorder's ``.bag.active`` too), videos, camera raw files and
    images in formats that are not read; None for every other file (notes,
    calibration files, listings hold no frame).

    Args:
        source: the file.
        command: ``restore`` or ``detect``, for the advice.
        left: what the command did with the file (``copied as it is``, ``not judged``).
    """
    suffix = source.suffix.lower()
    if is_bag_name(source):
        return f"{source}: a bag, {left}: {command} it as an INPUT of its own"
    if _is_video(source):
        return f"{source}: a video, {left}: {command} takes its frames as images"
    if suffix in RAW_IMAGE_SUFFIXES:
        return (
            f"{source}: a camera raw file, {left}: it needs demosaicing by the camera's "
            f"software; export it as PNG or TIFF to {command} it"
        )
    if suffix in UNREAD_IMAGE_SUFFIXES:
        return (
            f"{source}: {suffix} images are not read, {left}: convert it to PNG or "
            f"TIFF to {command} it"
        )
    return None


def unrestored_note(source: Path) -> str | None:
    """A line for a file of a folder input that holds frames restore left as they were.

    Every other file of a folder is copied as it is, which is right for notes
    and calibration files but lets dirty frames pass unnoticed when the file
    is a bag, a video or an image format that is not read: the report says so.
    """
    return unread_frames_note(source, "restore", "copied as it is")
