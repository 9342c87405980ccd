"""Frames of any input, in order: an image, a folder of images, an EuRoC/ASL recording, a bag.

The one place that answers "give me every frame of this input", shared by
``lenspair restore`` and the anomaly detector (``detect``)::

    from lenspair.capture.frames import detect_input, iter_frames

    kind = detect_input(Path("run.bag"))                # "rosbag1"
    for frame in iter_frames(Path("run.bag"), cameras=("cam1",)):
        if frame.image is None:
            print(frame.name, "failed:", frame.error)   # recorded, not fatal
        else:
            use(frame.image)                            # uint8/uint16 (H, W) or (H, W, 3) RGB

Inputs (:func:`detect_input`):

* ``image``: one image file (``.png``, ``.tif``, ``.jpg``, ...).
* ``folder``: a folder of images, searched recursively; ``name`` is the path
  relative to the folder (so an output can keep the tree).
* ``folders``: a left/right folder recording (``left/`` and ``right/`` of
  images named by timestamp, :mod:`lenspair.capture.folders`); frames of the
  chosen cameras in time order, ``name`` relative to the recording folder.
  Left and right folders whose names carry no timestamps are a ``folder``.
* ``euroc``: an EuRoC/ASL recording (``mav0/cam{0,1}/data.csv``); frames of
  the chosen cameras in time order, ``name`` relative to the recording folder
  (``mav0/cam1/data/<t_ns>.png``).
* ``rosbag1`` / ``rosbag2``: a ``.bag`` file, a ROS 2 bag folder or a bare
  ``.db3``/``.mcap`` file, read once from start to end (no seeking); the
  chosen cameras' image topics are decoded (picked as in
  :func:`~lenspair.capture.bag_frames.bag_camera_topics`, or passed as
  ``topics=(cam0, cam1)``). :mod:`lenspair.capture.bag_frames` reads bags:
  its :func:`~lenspair.capture.bag_frames.iter_bag_messages` gives every
  message (for copying a bag), :func:`iter_frames` only the images.

Anything else (another kind of file, a folder without images) is a one-line
:class:`~lenspair.capture.errors.CaptureError`; for a folder of ``.db3``/``.mcap``
files without ``metadata.yaml`` (``ros2 bag record`` killed before it closed)
it names them and says to pass the storage file itself or run ``ros2 bag
reindex``. Frames are decoded one at a time: a caller that needs the count up
front (a progress bar) takes it from :func:`frame_files` (files) rather than
holding the frames.

A frame that cannot be read (corrupt file, undecodable message) is yielded
(an :class:`~lenspair.capture.frame_types.InputFrame`) with ``image=None``
and ``error`` set, so the caller records it and goes on.
A bag cut short yields its complete messages (see
:mod:`lenspair.capture.salvage`); that, or a bag that stops part-way, is
appended once to the ``problems`` list passed in.
"""

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Literal

from lenspair.capture import euroc, folders, rosbag
from lenspair.capture.bag_frames import iter_bag_messages
from lenspair.capture.errors import CaptureError
from lenspair.capture.frame_types import InputFrame
from lenspair.capture.recording import CAMERAS, open_recording
from lenspair.capture.recording_types import DUPLICATE_TIMESTAMP, FrameProblem, is_ros1_bag
from lenspair.capture.rigfile import CameraName
from lenspair.core.errors import LenspairError
from lenspair.core.imageio import read_image

InputKind = Literal["image", "folder", "euroc", "folders", "rosbag1", "rosbag2"]
IMAGE_SUFFIXES = folders.IMAGE_SUFFIXES
MODEL_SUFFIXES = (".pt", ".onnx")
"""What models (restore's, detect's) are named; never an input."""


def detect_input(path: Path) -> InputKind:
    """Which kind of input ``path`` is.

    Raises:
        CaptureError: missing path, or neither an image, a folder nor a bag.
    """
    path = Path(path)
    if not path.exists():
        # a model named where the input goes: the arguments are the other way round
        # (a bundled model's name is found from any folder, so the message misled)
        hint = (
            " (the model comes first: MODEL INPUT)" if path.suffix.lower() in MODEL_SUFFIXES else ""
        )
        raise CaptureError(f"{path}: no such file or folder{hint}")
    if rosbag.is_bag(path):
        return "rosbag1" if is_ros1_bag(path) else "rosbag2"
    if path.is_file():
        if path.suffix.lower() in IMAGE_SUFFIXES:
            return "image"
        raise CaptureError(
            f"{path}: not an image ({', '.join(sorted(IMAGE_SUFFIXES))}) or a bag "
            f"({', '.join(sorted(rosbag.BAG_SUFFIXES))})"
        )
    if euroc.find_euroc_root(path) is not None and (
        (path / "mav0").is_dir() or all((path / camera).is_dir() for camera in CAMERAS)
    ):
        return "euroc"
    if _is_folder_recording(path):
        return "folders"
    return "folder"


def _is_folder_recording(path: Path) -> bool:
    """``left/`` + ``right/`` folders whose file names carry timestamps: a recording.

    Left and right folders of other images stay a plain folder (every image
    restored), as before such recordings were recognised; so do folders whose
    names give one camera two frames at one time (``run1_000001.png`` and
    ``run2_000001.png``: a frame index, not a timestamp), which as a recording
    would leave the second frame unrestored as a duplicate.
    """
    if not all((path / name).is_dir() for name in folders.FOLDER_NAMES.values()):
        return False
    try:
        recording = folders.read_folders(path)
    except CaptureError:
        return False
    return not any(problem.reason.startswith(DUPLICATE_TIMESTAMP) for problem in recording.problems)


def _folder_listing(folder: Path) -> tuple[list[Path], list[str]]:
    """Image files under ``folder`` (recursive, hidden entries skipped) and what it passes over.

    Both from one walk, sorted by path. The second list has one line per entry
    the images leave out unseen: a link to a folder is not followed (a link back
    up would never end) and a link to nothing has no image, so the commands
    reading a folder say so instead of leaving them out silently.
    """
    files: list[Path] = []
    passed_over: list[str] = []
    for entry in sorted(Path(folder).rglob("*")):
        if any(part.startswith(".") for part in entry.relative_to(folder).parts):
            continue
        if entry.is_symlink() and entry.is_dir():
            passed_over.append(
                f"{entry}: a link to a folder, not followed; its images are left out"
            )
        elif entry.is_symlink() and not entry.exists():
            passed_over.append(f"{entry}: a link to nothing ({os.readlink(entry)}); left out")
        elif entry.is_file() and entry.suffix.lower() in IMAGE_SUFFIXES:
            files.append(entry)
    return files, passed_over


def iter_frames(
    path: Path,
    cameras: Sequence[CameraName] = CAMERAS,
    problems: list[str] | None = None,
    topics: tuple[str, str] | None = None,
    dropped: list[FrameProblem] | None = None,
) -> Iterator[InputFrame]:
    """Every frame of ``path`` (any kind, see the module docstring), decoded.

    Args:
        path: the input.
        cameras: recordings and bags only: the cameras whose frames are wanted.
        problems: appended to (one line each) when a bag stops part-way, and
            for recordings, what their listing reported for the chosen cameras
            (images ``data.csv`` does not list, duplicate timestamps, ...).
        topics: bags only: the ``(cam0, cam1)`` image topics; None picks them.
        dropped: recordings only: appended to with the listing's problems that
            leave an image out (a file ``data.csv`` lists but that is missing,
            an image it does not list, a second file with a repeated
            timestamp), so that a caller can account for those frames too.

    Returns:
        An iterator of :class:`~lenspair.capture.frame_types.InputFrame` in
        input order (files sorted by path; recordings by camera then time;
        bags by log time), each decoded when reached.

    Raises:
        CaptureError: at the call, before any frame is read: the input cannot
            be opened at all (unknown layout, no images, no usable image
            topic), or ``topics`` given for a non-bag; a bag none of whose
            messages can be read raises when iterated.
    """
    kind = detect_input(path)
    if kind in ("rosbag1", "rosbag2"):
        messages = iter_bag_messages(path, cameras, problems, topics)
        return (item.frame for item in messages if item.frame is not None)
    if topics is not None:
        raise CaptureError(f"{path}: topics can only be chosen for bags, this is a {kind}")
    entries = _file_entries(path, kind, cameras, problems, dropped)
    return _iter_files(Path(path), kind, entries)


def frame_files(path: Path, kind: InputKind, cameras: Sequence[CameraName]) -> list[Path]:
    """The image files :func:`iter_frames` reads for a file-based input, in order."""
    return [file for file, _, _ in _file_entries(path, kind, cameras)]


def _file_entries(
    path: Path,
    kind: InputKind,
    cameras: Sequence[CameraName],
    problems: list[str] | None = None,
    dropped: list[FrameProblem] | None = None,
) -> list[tuple[Path, CameraName | None, int | None]]:
    """``(file, camera, t_ns)`` per frame; recordings take both from their listing.

    ``problems`` receives the recording's listing problems for ``cameras``,
    ``dropped`` those of them that leave a frame out.

    Raises:
        CaptureError: a folder without images (the caller asked for frames).
    """
    path = Path(path)
    if kind == "image":
        return [(path, None, None)]
    if kind == "folder":
        files, passed_over = _folder_listing(path)
        if not files:
            raise CaptureError(_no_images(path))
        if problems is not None:
            problems.extend(passed_over)
        return [(file, None, None) for file in files]
    recording = open_recording(path, cameras=cameras)
    mine = [p for p in recording.problems if p.camera is None or p.camera in cameras]
    if problems is not None:
        problems.extend(str(problem) for problem in mine)
    if dropped is not None:  # images, not rows of a listing: a frame each
        dropped.extend(
            problem
            for problem in mine
            if problem.dropped
            and problem.camera is not None
            and (problem.t_ns is not None or Path(problem.source).suffix.lower() in IMAGE_SUFFIXES)
        )
    return [
        (ref.source, camera, ref.t_ns) for camera in cameras for ref in recording.frames[camera]
    ]


def _no_images(folder: Path) -> str:
    """Why a folder gives no frames, in one line (a ROS 2 bag's storage left without metadata)."""
    hint = rosbag.storage_without_metadata(folder)
    if hint is not None:
        return f"{folder}: no images, and {hint}"
    suffixes = ", ".join(sorted(IMAGE_SUFFIXES))
    return f"{folder}: no images ({suffixes}) found and not a recording or a bag"


def _iter_files(
    path: Path, kind: InputKind, entries: list[tuple[Path, CameraName | None, int | None]]
) -> Iterator[InputFrame]:
    base = path.parent if kind == "image" else path
    for index, (file, camera, t_ns) in enumerate(entries):
        name = file.relative_to(base).as_posix()
        try:
            image, error = read_image(file), None
        except LenspairError as exc:
            image, error = None, str(exc)
        yield InputFrame(index, name, camera, t_ns, str(file), image, error)
