"""``left/`` + ``right/`` image folders with timestamps in the file names.

Layout::

    <rec>/left/1403636579763555584.png     cam0
    <rec>/right/1403636579763555584.png    cam1

The timestamp is read from the file stem, the first rule that applies:

1. seconds with a fraction, ``<9-10 digits>.<up to 9 digits>`` anywhere in
   the stem (``1403636579.7635.png``, ``1403636579.763555584_left.png``), or
   ``<up to 10 digits>.<digits>`` ending it (``12.5.png``: seconds from the
   start; zeros in front aside, more digits are no seconds before 2286:
   ``1700000000050164.0.png`` goes on to rule 3);
2. seconds and nanoseconds, ``<9-10 digits>_<up to 9 digits>`` (or ``-``)
   anywhere in the stem, as ROS tools name frames
   (``1403636579_763555584.png``; an unpadded ``1403636579_5.png`` is 5 ns
   past the second): read as nanoseconds alone, those would lose their
   seconds and pair frames of different seconds;
3. else the longest group of digits, in nanoseconds (the last of the longest
   when several are as long), when it has at least 9 digits (a time):
   ``left_000017_1403636579763555584.png`` and
   ``1403636579763555584_cam0.png`` are both at ``1403636579763555584``, not
   at frame ``17`` or at ``0`` (the digit of ``cam0``);
4. else the last group of digits: ``rec_20240501_000001.png`` is ``1`` (a
   frame number, which ``capture-ingest`` then refuses as no time, while
   ``calibrate`` pairs such frames by it), not the date.

Seconds are Unix seconds (9-10 digits, 1973 to 2286) except at the end of
the stem: ``v1.2_<t_ns>.png`` is not 1.2 s. A time past int64 nanoseconds
(2262) is no time: the file is recorded as a problem with the value read. A
camera whose files mostly read as one timestamp is refused: the names hold
their time in a way these rules do not read, and pairing would keep one
frame. So is a camera whose times are Unix milli- or microseconds
(``1700000000049.png``, ``1700000000049941.png``: 13 or 16 digits, steps
under a millisecond read as nanoseconds): scaled they would be guesses, read
as nanoseconds they look like frame numbers.

Hidden files and files that are not images are ignored. Folders have no
recording order, so frames are taken in time order; two files with the same
timestamp keep the first by name and record the other. A file named as a
frame of its time, a separator and a word (``<t>_depth.png``,
``<t>-thumb.jpg`` beside ``<t>.png``) is that frame's companion, not a
frame: left out, like a raw file or a depth EXR beside it, and counted in
one note of the folder.
"""

import os
import re
import statistics
from collections import Counter
from collections.abc import Sequence
from datetime import UTC, datetime
from itertools import pairwise
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
from lenspair.core.wording import counted

IMAGE_SUFFIXES = frozenset(
    {".png", ".tif", ".tiff", ".bmp"}
    | {".jpg", ".jpeg", ".jpe", ".jfif"}  # JPEG, by each name cameras and tools give it
    | {".pgm", ".ppm", ".pnm", ".pbm"}  # netpbm; a 1-bit PBM reads as 8-bit grey, 0 and 255
)
"""Image files read as frames (OpenImageIO). Camera raw and video are not images to read
here: :mod:`lenspair.model.inference.unread_files` names them where a folder holds them."""
RAW_IMAGE_SUFFIXES = frozenset(
    {".dng", ".cr2", ".cr3", ".nef", ".arw", ".orf", ".rw2", ".raf", ".pef", ".srw"}
)
"""Camera raw files: the sensor's mosaic, not an image until the camera's software
demosaics it (a DNG is a TIFF container, which OpenImageIO may open all the same)."""
UNREAD_IMAGE_SUFFIXES = frozenset({".webp", ".gif", ".heic", ".heif", ".jp2", ".exr", ".avif"})
"""Images in formats that are not read (convert them to PNG or TIFF)."""

FOLDER_NAMES: dict[CameraName, str] = {"cam0": "left", "cam1": "right"}

_UNIX_SECONDS_FRACTION = re.compile(r"(?<![\d.])(\d{9,10})\.(\d{1,9})(?![\d])")
_SECONDS_AT_END = re.compile(r"(?<!\d)0*(\d{1,10})\.(\d{1,9})$")
"""Seconds ending the stem: up to 10 digits (before 2286), zeros in front aside."""
_SECONDS_NANOSECONDS = re.compile(r"(?<!\d)(\d{9,10})[_-](\d{1,9})(?!\d)")
"""Unix seconds (9-10 digits: 1973 to 2286) and a nanosecond field of up to 9 digits
(export scripts that print ``f"{secs}_{nsecs}"`` do not zero-pad it)."""
_DIGITS = re.compile(r"\d+")
TIME_DIGITS = 9
"""Digits of the shortest group read as a time before a name's last group: Unix seconds
have 9-10, milli- to nanoseconds more; a date (``20240501``) or a short serial has fewer."""
INT64_MAX = 2**63 - 1
"""The last nanosecond int64 holds (2262-04-11): timestamps are int64 ns everywhere."""
SUBUNIT_DIGITS = {13: "milliseconds", 16: "microseconds"}
"""Digits of a Unix time (2001 to 2286) in milli- and microseconds; in nanoseconds it has 19."""
SUBUNIT_STEP_NS = 1_000_000
"""Frames stepping under this (1 ms, 1000 frames/s) read as nanoseconds, with 13 or 16
digits, are Unix milli- or microseconds: a 13-digit time in nanoseconds is 17 minutes to
3 hours after 1970 (a clock since boot), and such a clock runs with a camera's period."""


def timestamp_from_name(name: str) -> int | None:
    """Timestamp (ns) encoded in an image file name, or None when there is none.

    Args:
        name: file name with extension, e.g. ``1403636579763555584.png``.

    Returns:
        Nanoseconds: ``<s>.<fraction>`` read as seconds, ``<s>_<ns>``, or the
        stem's longest digit group (module docstring).
    """
    read = _read_time(Path(name).stem)
    return read[0] if read is not None and read[0] <= INT64_MAX else None


def _read_time(stem: str) -> tuple[int, int] | None:
    """``(value in ns, digits)`` read from a file stem by the module's rules, or None.

    ``digits`` is the length of the digit group rule 3 read as nanoseconds,
    0 when another rule read the value. The value may exceed int64.
    """
    fraction = _UNIX_SECONDS_FRACTION.search(stem) or _SECONDS_AT_END.search(stem)
    if fraction is not None:  # a decimal fraction: "5" is half a second
        seconds = int(fraction.group(1)) * 1_000_000_000
        return seconds + int(fraction.group(2).ljust(9, "0")), 0
    split = _SECONDS_NANOSECONDS.search(stem)
    if split is not None:  # a nanosecond count: "5" is five nanoseconds
        return int(split.group(1)) * 1_000_000_000 + int(split.group(2)), 0
    groups = _DIGITS.findall(stem)
    if not groups:
        return None
    # a name's other digits (cam0, a frame index) are shorter than a time in ns; max() keeps
    # the first of equals, so search from the end: the last of the longest. Only a group as
    # long as a time (TIME_DIGITS) wins so: a date or a serial number (rec_20240501_000001)
    # is not one, and the last group there is the frame's number, as it always was
    longest = max(reversed(groups), key=len)
    if len(longest) >= TIME_DIGITS:
        return int(longest), len(longest.lstrip("0") or "0")
    return int(groups[-1]), 0


def image_files(folder: Path) -> list[Path]:
    """Visible image files of ``folder`` (not recursive), sorted by name.

    Raises:
        CaptureError: the folder cannot be listed (another user's, a failing
            disk): a problem of the input, exit 2, not the refused write that
            the CLI's exit 1 for ``EACCES`` means.
    """
    try:
        entries = list(folder.iterdir())
    except OSError as exc:
        raise CaptureError(f"{folder}: cannot be read ({exc.strerror or exc})") from None
    return sorted(
        p
        for p in entries
        if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".") and p.is_file()
    )


def dangling_link(entry: Path) -> str:
    """Why a symbolic link to nothing named as a frame is left out, with where it points."""
    return f"a link to nothing ({os.readlink(entry)}); left out"


def passed_over_frames(folder: Path) -> list[tuple[Path, str]]:
    """``(file, why)`` for each visible file of ``folder`` that looks like a frame but is not read.

    :func:`image_files` leaves out an image in a format that is not read (a
    WebP, an EXR), a camera raw file, and a link to nothing or a folder named
    as an image: each such frame vanished from a recording without a word.
    Sorted by name; an unlistable folder gives nothing (:func:`image_files`
    says so).
    """
    try:
        entries = sorted(p for p in folder.iterdir() if not p.name.startswith("."))
    except OSError:
        return []
    found = []
    for entry in entries:
        suffix = entry.suffix.lower()
        if suffix in UNREAD_IMAGE_SUFFIXES:
            found.append((entry, f"{suffix} images are not read: convert it to PNG or TIFF"))
        elif suffix in RAW_IMAGE_SUFFIXES:
            found.append((entry, "a camera raw file: export it as PNG or TIFF"))
        elif suffix in IMAGE_SUFFIXES and entry.is_symlink() and not entry.exists():
            found.append((entry, dangling_link(entry)))
        elif suffix in IMAGE_SUFFIXES and entry.is_dir():
            found.append((entry, "a folder named as an image; left out"))
    return found


def note_passed_over(
    camera: CameraName, folder: Path, frames: list[FrameRef], problems: list[FrameProblem]
) -> None:
    """Append a problem for each of ``folder``'s :func:`passed_over_frames` that is a frame.

    A file whose name holds the time of a frame that is read is that frame's
    companion (a camera's raw file beside its PNG, a depth EXR), not a frame
    lost: left out of the problems, as a note beside the frames is.
    """
    times = {frame.t_ns for frame in frames}
    for file, why in passed_over_frames(folder):
        t_ns = timestamp_from_name(file.name)
        if t_ns is None or t_ns not in times:
            problems.append(FrameProblem(camera, t_ns, str(file), why))


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

    Raises:
        CaptureError: more than half of the folder's (two or more) timed files
            read as one timestamp, or as Unix milli- or microseconds; names
            the folder and the value.
    """
    frames = []
    digits = []
    for file in image_files(folder):
        read = _read_time(Path(file.name).stem)
        if read is None:
            problems.append(FrameProblem(camera, None, str(file), "no timestamp in file name"))
            continue
        if read[0] > INT64_MAX:
            reason = f"timestamp {read[0]} ns in file name is past 2262 (int64 nanoseconds)"
            problems.append(FrameProblem(camera, None, str(file), reason))
            continue
        frames.append(FrameRef(camera, read[0], file))
        digits.append(read[1])
    frames, digits = _without_companions(camera, folder, frames, digits, problems)
    _check_distinct_times(camera, folder, frames)
    _check_subunit_times(camera, folder, frames, digits)
    note_passed_over(camera, folder, frames, problems)
    frames.sort(key=lambda f: f.t_ns)  # stable: same timestamps keep name order
    return order_frames(camera, frames, problems)


def _without_companions(
    camera: CameraName,
    folder: Path,
    frames: list[FrameRef],
    digits: list[int],
    problems: list[FrameProblem],
) -> tuple[list[FrameRef], list[int]]:
    """``frames`` (and their ``digits``) less the companions of another frame of their time.

    A file whose stem is another same-time file's stem, a separator (``_``,
    ``-``, ``.``) and a word (``<t>_depth.png``, ``<t>-8bit.png`` beside
    ``<t>.png``) goes with that frame: a depth map or a preview, not a second
    frame of the time. Kept, each was a "duplicate timestamp", and
    ``<t>-depth.png``, which sorts first, was the frame and the camera's image
    the duplicate. A number alone after the separator (``<t>_1.png``, a second
    save) is no word: that file stays a duplicate. The companions are counted
    in one note of the folder (``problems``), not one a file.
    """
    stems: dict[int, set[str]] = {}
    for frame in frames:
        stems.setdefault(frame.t_ns, set()).add(frame.source.stem)

    def extension(frame: FrameRef) -> str | None:
        """What ``frame``'s stem adds to a same-time stem after a separator, or None."""
        stem = frame.source.stem
        for base in stems[frame.t_ns]:
            if len(stem) > len(base) + 1 and stem.startswith(base) and stem[len(base)] in "_-.":
                return stem[len(base) + 1 :]
        return None

    added = [extension(frame) for frame in frames]
    companion = [a is not None and not a.isdigit() for a in added]
    companions = [f for f, c in zip(frames, companion, strict=True) if c]
    kept = [(f, d, a) for f, d, a, c in zip(frames, digits, added, companion, strict=True) if not c]
    # of a frame and its second save (<t>.png, <t>-2.png) the frame is kept, though the
    # save's name sorts first; twins of one stem keep name order (stable)
    kept.sort(key=lambda item: (item[0].t_ns, item[2] is not None))
    if companions:
        reason = (
            f"{counted(len(companions), 'file')} named as a frame of the same time and a word "
            f"(the first: {companions[0].source.name}): companions of those frames (depth "
            "maps, thumbnails), not frames"
        )
        problems.append(FrameProblem(camera, None, str(folder), reason, dropped=False))
    return [f for f, _, _ in kept], [d for _, d, _ in kept]


def _check_distinct_times(camera: CameraName, folder: Path, frames: list[FrameRef]) -> None:
    """Refuse a folder whose files mostly read as one timestamp.

    Such names hold their time some other way (or none): each would be a
    "duplicate timestamp" of the first, and the ingest would keep one frame
    and call the run a success.
    """
    if len(frames) < 2:
        return
    t_ns, count = Counter(f.t_ns for f in frames).most_common(1)[0]
    if 2 * count > len(frames):
        raise CaptureError(
            f"{folder}: {count} of {len(frames)} {camera} file names read as one timestamp, "
            f"t_ns={t_ns} (e.g. {next(f for f in frames if f.t_ns == t_ns).source.name}): "
            "name the images by capture time "
            "in ns or in seconds with a fraction (1403636579763555584.png, "
            "1403636579.763555584.png)"
        )


def _check_subunit_times(
    camera: CameraName, folder: Path, frames: list[FrameRef], digits: list[int]
) -> None:
    """Refuse a folder whose file names hold Unix times in milli- or microseconds.

    Read as nanoseconds (rule 3), ``1700000000049.png`` steps by 50 ns a
    frame, which the frame-period check called frame numbers, and a 16-digit
    microsecond time at 10 frames/s or slower passed as a 10,000 frames/s
    camera. Scaling them would be a guess at the unit; the names say it.

    Args:
        camera: the folder's camera.
        folder: the folder, named in the refusal.
        frames: the folder's timed frames.
        digits: each frame's rule-3 digit count (0: read by another rule).

    Raises:
        CaptureError: more than half of the times have 13 (or 16) digits and
            they step by under :data:`SUBUNIT_STEP_NS` read as nanoseconds.
    """
    length, count = Counter(digits).most_common(1)[0] if digits else (0, 0)
    if length not in SUBUNIT_DIGITS or 2 * count <= len(frames):
        return
    stamps = sorted({f.t_ns for f, d in zip(frames, digits, strict=True) if d == length})
    steps = [b - a for a, b in pairwise(stamps)]
    if not steps or statistics.median(steps) >= SUBUNIT_STEP_NS:
        return
    unit = SUBUNIT_DIGITS[length]
    example = next(f for f, d in zip(frames, digits, strict=True) if d == length)
    scale = 1_000 if length == 13 else 1_000_000
    date = datetime.fromtimestamp(example.t_ns / scale, tz=UTC).strftime("%Y-%m-%d")
    raise CaptureError(
        f"{folder}: these {camera} file names look like Unix times in {unit} ({length} "
        f"digits: {example.source.name} reads as {date} so; as nanoseconds they step by "
        f"{round(statistics.median(steps))} ns, like frame numbers): name frames in "
        "nanoseconds or seconds.fraction (1403636579763555584.png, 1403636579.763555584.png)"
    )


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
