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
  (``mav0/cam1/data/<t_ns>.png``). Each camera folder holds ``data.csv`` or
  ``data/``: ``cam0/`` and ``cam1/`` folders of images alone are a ``folder``.
* ``rosbag1`` / ``rosbag2``: a ``.bag`` file, a ROS 2 bag folder or a bare
  ``.db3``/``.mcap`` file, read once from start to end (no seeking); the
  chosen cameras' image topics are decoded (picked as in
  :func:`~lenspair.capture.bag_frames.bag_camera_topics`, or passed as
  ``topics=(cam0, cam1)``). :mod:`lenspair.capture.bag_frames` reads bags:
  its :func:`~lenspair.capture.bag_frames.iter_bag_messages` gives every
  message (for copying a bag), :func:`iter_frames` only the images.

A recording's images that are no frame of its cameras (``mav0/cam2``, an
overview image beside ``left/`` and ``right/``) are listed by
:func:`images_outside_cameras`, a folder at a time, for the reports to name.

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
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Literal, NamedTuple

from lenspair.capture import euroc, folders, rosbag
from lenspair.capture.bag_frames import iter_bag_messages
from lenspair.capture.errors import CaptureError
from lenspair.capture.frame_types import InputFrame
from lenspair.capture.recording import CAMERAS, open_recording
from lenspair.capture.recording_types import DUPLICATE_TIMESTAMP, FrameProblem, is_ros1_bag
from lenspair.capture.rigfile import CameraName
from lenspair.core.errors import LenspairError
from lenspair.core.imageio import read_image
from lenspair.core.wording import counted

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
    if _is_euroc(path):
        return "euroc"
    if _is_folder_recording(path):
        return "folders"
    return "folder"


def _is_euroc(path: Path) -> bool:
    """``mav0/`` (or ``cam0/`` + ``cam1/``), each camera folder holding ``data.csv`` or ``data/``.

    Folders named ``cam0`` and ``cam1`` that hold images and neither of those
    are a plain folder (every image restored), as ``left/`` + ``right/``
    folders without timestamps are (:func:`_is_folder_recording`), rather
    than a recording refused for the ``data.csv`` it never had.
    """
    root = euroc.find_euroc_root(path)
    if root is None or not (
        (path / "mav0").is_dir() or all((path / camera).is_dir() for camera in CAMERAS)
    ):
        return False
    cameras = [root / camera for camera in CAMERAS if (root / camera).is_dir()]
    return all((c / euroc.DATA_CSV).is_file() or (c / "data").is_dir() for c in cameras)


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


SIMULATED_TRUTH = "truth"
"""A simulated recording's ground truth (``truth/geometry.json``, ``clear/``, ``mask/``):
lenspair's own, no camera's frames, so not named among the images outside the cameras."""


class OutsideImages(NamedTuple):
    """Images of a recording that are no frame of its cameras: a folder of them, or one file."""

    where: Path
    """The folder (the topmost that holds no camera's images) or the loose image file."""
    images: int
    """How many images: every one under the folder, or 1."""
    folder: bool
    cameras: str
    """The recording's cameras, as the line names them (``cam0, cam1``, ``left/, right/``)."""

    def note(self, command: str, left: str) -> str:
        """The line of a report: what ``command`` did with them (``left``) and what to do."""
        amount = counted(self.images, "image") if self.folder else "an image"
        target = "the folder" if self.folder else "it"
        return (
            f"{self.where}: {amount} outside the recording's cameras ({self.cameras}), {left}: "
            f"{command} {target} as an INPUT of its own"
        )


def camera_folders(path: Path, kind: InputKind) -> dict[CameraName, tuple[Path, Path]]:
    """Per camera a folder recording holds: its folder and the folder of its images.

    ``mav0/cam0`` and ``mav0/cam0/data``; ``left`` and ``left`` (relative to
    ``path``). Empty for every other kind.
    """
    path = Path(path)
    homes: dict[CameraName, Path] = {}
    if kind == "euroc" and (root := euroc.find_euroc_root(path)) is not None:
        homes = {camera: root / camera for camera in CAMERAS}
    elif kind == "folders":
        homes = {camera: path / folders.FOLDER_NAMES[camera] for camera in CAMERAS}
    return {
        camera: (
            home.relative_to(path),
            (home / "data" if kind == "euroc" else home).relative_to(path),
        )
        for camera, home in homes.items()
        if home.is_dir()
    }


def images_outside_cameras(
    path: Path,
    kind: InputKind,
    cameras: Sequence[CameraName],
    read: Iterable[Path],
    files: Iterable[Path],
) -> list[OutsideImages]:
    """A recording's images that no camera of it holds (``mav0/cam2``, an overview beside them).

    They are copied (``restore``) or passed over (``detect``) like any other
    file of the recording, where a bag's third camera is named: so they are
    named too, a folder at a time. An image in the image folder of a camera
    read is a frame or a problem of the listing already (not in ``data.csv``,
    no timestamp in its name), and a camera left out by choice (``--camera``,
    ``rig.yaml``) keeps its whole folder, as a simulated recording keeps its
    ground truth (:data:`SIMULATED_TRUTH`); hidden files stay quiet, as a
    folder's are.

    Args:
        path: the input.
        kind: its kind; only ``euroc`` and ``folders`` are looked through.
        cameras: the cameras read.
        read: the image files read as frames.
        files: every file under ``path``, relative to it.

    Returns:
        By path: each topmost folder that holds no camera's images, with
        the images below it, and each image lying beside the cameras' folders.
    """
    places = camera_folders(path, kind)
    if not places:
        return []
    frames = {Path(file).resolve() for file in read}
    quiet = [home for camera, (home, _) in places.items() if camera not in cameras]
    if (Path(path) / SIMULATED_TRUTH / "geometry.json").is_file():
        quiet.append(Path(SIMULATED_TRUTH))  # the simulator's clean views and masks
    image_dirs = [images for _, images in places.values()]
    groups: dict[Path, int] = {}
    loose: set[Path] = set()  # images beside the cameras' folders, not in a folder of their own
    for relative in map(Path, files):
        if relative.suffix.lower() not in IMAGE_SUFFIXES or any(
            part.startswith(".") for part in relative.parts
        ):
            continue
        if relative.parent in image_dirs or any(relative.is_relative_to(q) for q in quiet):
            continue
        if (Path(path) / relative).resolve() in frames:
            continue
        # the topmost folder holding no camera's images, else the file alone
        key = next(
            (
                relative.parents[depth]
                for depth in range(len(relative.parts) - 2, -1, -1)
                if not any(d.is_relative_to(relative.parents[depth]) for d in image_dirs)
            ),
            relative,
        )
        groups[key] = groups.get(key, 0) + 1
        if key == relative:
            loose.add(key)
    names = ", ".join(
        camera if kind == "euroc" else f"{images}/" for camera, (_, images) in places.items()
    )
    return [
        OutsideImages(Path(path) / key, count, key not in loose, names)
        for key, count in sorted(groups.items())
    ]


DETECT_OUTPUT = "detections.csv"
"""The table ``lenspair detect`` writes in its output folder (``model.detection.report``
writes it by this name); a folder holding one is a detect output, not frames."""


def _folder_listing(folder: Path) -> tuple[list[Path], list[str]]:
    """Image files under ``folder`` (recursive, hidden entries skipped) and what it passes over.

    Both from one walk, sorted by path. The second list has one line per entry
    the images leave out unseen: a folder that cannot be read (its images
    cannot even be counted), a link to a folder is not followed (a link back
    up would never end), a link to nothing has no image, and a ``detect``
    output's contact sheet is no frame, so the commands reading a folder say
    so instead of leaving them out silently.
    """
    files: list[Path] = []
    passed_over: list[str] = []

    def refused(error: OSError) -> None:
        passed_over.append(
            f"{error.filename}: cannot read this folder ({error.strerror}); its images are left out"
        )

    for here, subfolders, names in os.walk(folder, onerror=refused):
        subfolders[:] = sorted(name for name in subfolders if not name.startswith("."))
        for name in [n for n in subfolders if (Path(here) / n / DETECT_OUTPUT).is_file()]:
            subfolders.remove(name)  # `detect frame.png` run beside the frame writes one here
            passed_over.append(
                f"{Path(here) / name}: a detect output ({DETECT_OUTPUT}); its contact sheet "
                "is no frame, left out"
            )
        for name in subfolders:
            if (entry := Path(here) / name).is_symlink():
                passed_over.append(
                    f"{entry}: a link to a folder, not followed; its images are left out"
                )
        for name in sorted(n for n in names if not n.startswith(".")):
            entry = Path(here) / name
            if entry.is_symlink() and not entry.exists():
                passed_over.append(f"{entry}: {folders.dangling_link(entry)}")
            elif entry.is_file() and entry.suffix.lower() in IMAGE_SUFFIXES:
                files.append(entry)
    return sorted(files), passed_over


def iter_frames(
    path: Path,
    cameras: Sequence[CameraName] = CAMERAS,
    problems: list[str] | None = None,
    topics: tuple[str, str] | None = None,
    dropped: list[FrameProblem] | None = None,
    say_pages: bool = True,
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
        say_pages: name the first TIFF of several pages, whose first page is
            the frame (:func:`~lenspair.core.imageio.read_image`); ``restore``,
            which copies such a file whole and lists it, says it its way.

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
    return _iter_files(Path(path), kind, entries, say_pages)


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
    # an image restore copies and detect leaves unjudged is named by them, with what they
    # did with it (lenspair.model.inference.unread_files): said once, not twice
    mine = [
        p
        for p in recording.problems
        if (p.camera is None or p.camera in cameras)
        and Path(p.source).suffix.lower()
        not in folders.UNREAD_IMAGE_SUFFIXES | folders.RAW_IMAGE_SUFFIXES
    ]
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
    path: Path,
    kind: InputKind,
    entries: list[tuple[Path, CameraName | None, int | None]],
    say_pages: bool,
) -> Iterator[InputFrame]:
    base = path.parent if kind == "image" else path
    for index, (file, camera, t_ns) in enumerate(entries):
        name = file.relative_to(base).as_posix()
        try:
            image, error = read_image(file, say_pages=say_pages), None
        except LenspairError as exc:
            image, error = None, str(exc)
        yield InputFrame(index, name, camera, t_ns, str(file), image, error)
