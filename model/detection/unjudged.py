"""The files of a folder input that ``detect`` does not judge but that may hold frames.

``detect`` judges the images a folder (or a recording) lists; a bag, a video
or an image in a format that is not read, lying among them, would pass
without a word, and dirty glass with it; so would a recording's images that
none of its cameras holds (a third camera's folder, :func:`unjudged_images`).
``restore`` names such files in its problems
(:func:`lenspair.model.inference.unread_files.unrestored_note`); this module
names them the same way, from the same walk of the folder
(:func:`~lenspair.model.inference.out_layout.files_under`) and the same note
(:func:`~lenspair.model.inference.unread_files.unread_frames_note`), in ``detect``'s
words: they are not judged, where ``restore`` copies them.
"""

from collections.abc import Iterable, Sequence
from pathlib import Path

from lenspair.capture.frames import InputKind, OutsideImages, images_outside_cameras
from lenspair.capture.rigfile import CameraName
from lenspair.model.inference.out_layout import files_under
from lenspair.model.inference.unread_files import unread_frames_note

FOLDER_KINDS: frozenset[InputKind] = frozenset({"euroc", "folders", "folder"})
"""Inputs that are folders, whose other files are looked through (as restore copies them)."""


def unjudged_note(source: Path) -> str | None:
    """A line for a file that may hold frames ``detect`` did not judge; None for other files.

    Notes, calibration files and listings hold no frame: they are passed over quietly.
    """
    return unread_frames_note(source, "detect", "not judged")


def unjudged_files(root: Path, kind: InputKind, judged: Iterable[Path]) -> list[str]:
    """One line per file under a folder input, other than ``judged``, that may hold frames.

    Args:
        root: the input.
        kind: its kind (:func:`lenspair.capture.frames.detect_input`); only
            :data:`FOLDER_KINDS` are looked through, an image or a bag has no
            other files.
        judged: the image files read as frames (:func:`lenspair.capture.frames.frame_files`).

    Returns:
        The lines of :func:`unjudged_note`, in path order. A plain folder is
        walked without following links to folders, as its images are listed;
        a recording's folders are followed, as its listing is.
    """
    if kind not in FOLDER_KINDS:
        return []
    read = {Path(path).resolve() for path in judged}
    notes = []
    for relative in files_under(Path(root), follow_links=kind != "folder"):
        source = Path(root) / relative
        if source.resolve() not in read and (note := unjudged_note(source)) is not None:
            notes.append(note)
    return notes


def unjudged_images(
    root: Path, kind: InputKind, cameras: Sequence[CameraName], judged: Iterable[Path]
) -> list[OutsideImages]:
    """A recording's images that no camera of it holds, not judged: a folder of them at a time.

    ``mav0/cam2`` beside ``cam0`` and ``cam1``, an overview image beside
    ``left/`` and ``right/``: named as ``restore`` names them
    (:func:`~lenspair.capture.frames.images_outside_cameras`), so that every
    image of the input is judged or named. Empty for inputs other than
    ``euroc`` and ``folders`` recordings.
    """
    if kind not in ("euroc", "folders"):
        return []
    return images_outside_cameras(root, kind, cameras, judged, files_under(Path(root)))
