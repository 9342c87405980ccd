"""The layout of restore's OUT: its own names there, and listing and copying files.

Restore writes its frames under the input's names, so its own bookkeeping
takes names no input holds (:data:`OWN_NAMES`), and both sinks
(:mod:`lenspair.model.inference.file_sink`, :mod:`lenspair.model.inference.bag_sink`)
list trees and copy files the same way.
"""

import os
import shutil
from pathlib import Path

from lenspair.core.fsutil import atomic_write

PARTIAL_DIR = ".restore-partial"
"""Under OUT: the bag being written, moved to its name when complete
(see :class:`~lenspair.model.inference.bag_sink.BagSink`)."""

CACHE_DIR = ".restore-cache"
"""Under OUT: restored bag frames kept until the bag is complete
(see :class:`~lenspair.model.inference.bag_sink.BagSink`)."""

SOURCE_STAMP = "source.json"
"""In a bag's cache folder: the files the cached frames were restored from."""

COPIES_NAME = ".restore-copies"
"""Under OUT: the frames written as copies of the input
(see :class:`~lenspair.model.inference.file_sink.FileSink`)."""

STALE_DIR = ".restore-stale"
"""Under OUT: a resumed run's outputs whose input is gone
(:meth:`~lenspair.model.inference.file_sink.FileSink.set_aside_stale`)."""

DEPTHS_NAME = ".restore-depths"
"""Under OUT: the bit depth each 16-bit frame was restored at
(see :class:`~lenspair.model.inference.resume.FrameDepths`)."""


OWN_NAMES = (COPIES_NAME, DEPTHS_NAME, CACHE_DIR, PARTIAL_DIR, STALE_DIR)
"""restore's own names at the top of OUT: never an input's file."""


def copy_file(source: Path, destination: Path) -> None:
    """Copy bytes atomically (a killed run never leaves half a file), with the source's mtime.

    The mtime lets a resumed run tell a finished copy from a file to copy
    again (:func:`copied_already`), as ``rsync -t`` does.
    """
    destination.parent.mkdir(parents=True, exist_ok=True)

    def _copy(tmp: Path) -> None:
        shutil.copyfile(source, tmp)
        info = os.stat(source)
        os.utime(tmp, ns=(info.st_atime_ns, info.st_mtime_ns))

    atomic_write(destination, _copy, suffix=destination.suffix, sync=False)  # as frames are


def copied_already(source: Path, destination: Path) -> bool:
    """Whether ``destination`` is :func:`copy_file`'s copy of ``source`` as it is now.

    Same size and same mtime (to the nanosecond), and the source unchanged
    since the copy was made (its ctime, which no tool sets back, not later
    than the copy's): a source changed since, even to the same size with
    its mtime put back (``touch -r``), or a destination written by anything
    else, is copied again.
    """
    try:
        have, want = os.stat(destination), os.stat(source)
    except FileNotFoundError:
        return False
    same = (have.st_size, have.st_mtime_ns) == (want.st_size, want.st_mtime_ns)
    return same and want.st_ctime_ns <= have.st_ctime_ns


def files_under(root: Path, follow_links: bool = True) -> list[Path]:
    """Every file below ``root``, relative to it, sorted; linked folders followed once each.

    A recording's frames are listed through its ``data.csv``, also through a
    linked folder (a camera's ``data/`` on another disk), which ``Path.rglob``
    does not enter; a folder of images is listed without following links
    (``follow_links=False``, :func:`lenspair.capture.frames.iter_frames`).
    """
    found: list[Path] = []
    seen: set[tuple[int, int]] = set()
    for folder, names, files in os.walk(root, followlinks=follow_links):
        info = os.stat(folder)
        if (info.st_dev, info.st_ino) in seen:  # a link back up the tree
            names[:] = []
            continue
        seen.add((info.st_dev, info.st_ino))
        here = Path(folder).relative_to(root)
        found += [here / name for name in files if (Path(folder) / name).is_file()]
    return sorted(found)
