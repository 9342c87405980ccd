"""Where restored frames go: files (same names, bit depth, channels) or a bag copy.

A sink receives every item of the input in order, each with restored pixels
or with None (copy the original unchanged: a frame judged clean, a frame that
failed, a bag message that is not an image of a chosen camera).

* :class:`FileSink` (image, folder, EuRoC/ASL recording): ``OUT/<name>``
  with the input's relative name, written atomically. For a recording every
  other file (``data.csv``, ``sensor.yaml``, other cameras, ``rig.yaml``,
  IMU, ...) is copied first, so OUT is the same recording with the chosen
  cameras restored. ``done`` tells ``--resume`` which frames are written.
* :class:`BagSink`: a copy of the bag (:mod:`lenspair.capture.bagwrite`),
  written aside and moved to its name when complete, with a cache of
  restored frames so ``--resume`` need not run them again.
"""

import errno
import io
import json
import logging
import os
import shutil
import sqlite3
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from lenspair.capture.bagwrite import BagCopy, output_bag_path
from lenspair.capture.errors import CaptureError
from lenspair.capture.folders import IMAGE_SUFFIXES
from lenspair.capture.frames import BagMessage, InputFrame
from lenspair.capture.rosbag import ROS2_STORAGE_SUFFIXES, is_bag_name
from lenspair.core.errors import ImageIOError
from lenspair.core.fsutil import (
    atomic_write,
    atomic_write_json,
    atomic_write_text,
    naming_errors,
    read_json_field,
    remove_path,
)
from lenspair.core.imageio import (
    FAST_PNG,
    Attribute,
    alpha_is_associated,
    image_layout,
    image_metadata,
    read_alpha,
    write_image,
)
from lenspair.core.sourcefiles import source_fingerprint

log = logging.getLogger(__name__)

PARTIAL_DIR = ".restore-partial"
"""Under OUT: the bag being written, moved to its name when complete (see :class:`BagSink`)."""

CACHE_DIR = ".restore-cache"
"""Under OUT: restored bag frames kept until the bag is complete (see :class:`BagSink`)."""

SOURCE_STAMP = "source.json"
"""In a bag's cache folder: the files the cached frames were restored from."""

COPIES_NAME = ".restore-copies"
"""Under OUT: the frames written as copies of the input (see :class:`FileSink`)."""

STALE_DIR = ".restore-stale"
"""Under OUT: a resumed run's outputs whose input is gone (:meth:`FileSink.set_aside_stale`)."""

DEPTHS_NAME = ".restore-depths"
"""Under OUT: the bit depth each 16-bit frame was restored at (see :class:`FrameDepths`)."""


OWN_NAMES = (COPIES_NAME, DEPTHS_NAME, CACHE_DIR, PARTIAL_DIR, STALE_DIR)
"""restore's own names at the top of OUT: never an input's file."""


class FrameDepths:
    """The depth (:class:`~lenspair.core.bitdepth.RunningDepth`) each 16-bit frame was restored at.

    A frame's depth depends on the frames before it: a frame added before
    finished ones (or one removed) changes it, and ``--resume`` must restore
    those again rather than keep them at the old scale. One JSON line per
    restored 16-bit frame, appended before its output is handed on (a kill
    leaves a line for a frame without output: it is redone, the later line wins).
    """

    def __init__(self, out_dir: Path) -> None:
        self.path = Path(out_dir) / DEPTHS_NAME
        self.bits: dict[str, int] = {}
        self.redone = 0  # finished frames whose depth changed: restored again
        if self.path.is_file():
            for line in self.path.read_text(encoding="utf-8").splitlines():
                try:
                    name, bits = json.loads(line)
                    self.bits[str(name)] = int(bits)
                except (ValueError, TypeError):  # a line cut by a kill
                    continue

    def same(self, frame: InputFrame, bits: int) -> bool:
        """Whether a finished ``frame`` was restored at ``bits`` (frames of before: assumed)."""
        if frame.image is None or frame.image.dtype != np.uint16:
            return True
        if self.bits.get(frame.name, bits) == bits:
            return True
        self.redone += 1
        return False

    def record(self, frames: Iterable[InputFrame], bits: int) -> None:
        """Note that the 16-bit ones of ``frames`` are being restored at ``bits``."""
        names = [
            frame.name
            for frame in frames
            if frame.image is not None and frame.image.dtype == np.uint16
        ]
        if not names:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with naming_errors(self.path), self.path.open("a", encoding="utf-8") as journal:
            journal.write("".join(json.dumps([name, bits]) + "\n" for name in names))
        self.bits.update(dict.fromkeys(names, bits))


def _alpha_of(source: Path, shape: tuple[int, ...]) -> np.ndarray | None:
    """The input's alpha channel, carried to its restored image (``None``: it has none).

    The network restores colour only; a file's transparency is not the
    glass's business and is written back unchanged.

    Raises:
        CaptureError: the input has an alpha channel that cannot be read again.
    """
    try:
        alpha = read_alpha(source)
    except ImageIOError as exc:
        raise CaptureError(str(exc)) from None
    return alpha if alpha is not None and alpha.shape == shape else None


def _layout_of(source: Path) -> tuple[int, tuple[Attribute, ...]]:
    """The input's EXIF/TIFF orientation and descriptive metadata, kept on its restored image.

    The metadata: ICC profile, EXIF (camera, capture time), GPS
    (:func:`~lenspair.core.imageio.image_metadata`); a restored frame
    is the same picture, only cleaner.

    Raises:
        CaptureError: a file of several pages (a multi-page TIFF): the network
            restores one image, and writing it in the file's place would drop
            the others, so the file is copied unchanged and listed instead.
    """
    try:
        orientation, pages = image_layout(source)
        metadata = image_metadata(source)
    except ImageIOError as exc:
        raise CaptureError(str(exc)) from None
    if pages > 1:
        raise CaptureError(f"{source}: a file of several pages; only single images are restored")
    return orientation, metadata


def copy_file(source: Path, destination: Path) -> None:
    """Copy bytes atomically (a killed run never leaves half a file)."""
    destination.parent.mkdir(parents=True, exist_ok=True)

    def _copy(tmp: Path) -> None:
        shutil.copyfile(source, tmp)

    atomic_write(destination, _copy, suffix=destination.suffix, sync=False)  # as frames are


def _changed_since(source: Path, written_ns: int) -> bool:
    """Whether ``source`` changed after ``written_ns``, by its inode's change time.

    A copy with preserved times (``cp -p``) still counts. An input that cannot be
    read now has not changed as far as its output is concerned.
    """
    try:
        return source.stat().st_ctime_ns > written_ns
    except OSError:
        return False


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


class FileSink:
    """Writes frames of file inputs under ``out_dir`` with their relative names.

    A frame written as a copy of its input (it failed, or was judged clean)
    is named in ``OUT/.restore-copies`` before it is copied, so that
    ``--resume`` does it again instead of taking the copy for a finished
    frame: a frame that failed on a truncated file is restored once the file
    is whole. The list is rewritten when the run finishes (and removed when
    no copy is left).

    Args:
        out_dir: the output folder.
    """

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = Path(out_dir)
        self.state_dir = self.out_dir  # where a resume's bookkeeping lives (FrameDepths)
        self.copies_file = self.out_dir / COPIES_NAME
        self.copies: set[str] = set()
        self.changed = 0  # outputs found older than their input's last change: redone
        if self.copies_file.is_file():
            text = self.copies_file.read_text(encoding="utf-8")
            for line in text.splitlines():
                try:
                    self.copies.add(json.loads(line))
                except ValueError:  # cut by a kill while being named: its copy never began
                    continue
            if text and not text.endswith("\n"):  # the next name must not join the cut line
                self._rewrite_copies()

    @property
    def output(self) -> Path:
        """Where the output is."""
        return self.out_dir

    def copy_others(
        self,
        root: Path,
        restored: Iterable[Path],
        reserved: Iterable[str] = (),
        follow_links: bool = True,
    ) -> list[str]:
        """Copy every file under ``root`` except ``restored`` ones.

        A file at the top of ``root`` named like one of restore's own files
        (``reserved``, and :data:`COPIES_NAME`) would be overwritten by it:
        it is not copied, and one line per such file is returned; so is one
        per copied file that holds frames left unrestored (:func:`unrestored_note`).
        """
        skip = {Path(p).resolve() for p in restored}
        own = {*reserved, *OWN_NAMES}
        clashes = []
        for relative in files_under(root, follow_links):
            source = Path(root) / relative
            if source.resolve() in skip:
                continue
            if relative.parts[0] in own:
                clashes.append(
                    f"{source}: not copied: OUT/{relative.parts[0]} is restore's own "
                    "(rename the file to keep it beside the restored frames)"
                )
                continue
            copy_file(source, self.out_dir / relative)
            if (note := unrestored_note(source)) is not None:
                clashes.append(note)
        return clashes

    def set_aside_stale(
        self, root: Path, reserved: Iterable[str] = (), follow_links: bool = True
    ) -> tuple[list[str], list[str]]:
        """Move the images in OUT whose input under ``root`` is gone into ``OUT/.restore-stale``.

        A resumed run whose input lost frames since would otherwise keep
        their outputs (a restored recording with an image its ``data.csv``
        no longer lists); they are moved, not deleted. Other files without an
        input (a note or calibration of the user's put into OUT) stay where
        they are, and are named. Folders behind links are walked as the
        frames are listed, through the link.

        Returns:
            ``(moved, left)``: names relative to OUT.
        """
        own = {*reserved, *OWN_NAMES}
        inputs = set(files_under(root, follow_links))
        moved, left = [], []
        for relative in files_under(self.out_dir, follow_links):
            if relative.parts[0] in own or relative in inputs:
                continue
            if relative.suffix.lower() not in IMAGE_SUFFIXES:
                left.append(relative.as_posix())
                continue
            target = self.out_dir / STALE_DIR / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.out_dir / relative, target)
            moved.append(relative.as_posix())
        return moved, left

    def done(self, frame: InputFrame) -> bool:
        """True when ``frame``'s output already exists (written atomically: complete).

        Neither does a copy of the input (``OUT/.restore-copies``). An empty
        file does not count either: outputs are renamed into place without
        ``fsync`` (one per frame would cost more than the frame on slow
        storage), and after a power cut a file system may keep the new name
        with no data, which is what that looks like. Nor does an output older
        than its input's last change (the input was edited or replaced after
        a killed run wrote it).
        """
        path = self.out_dir / frame.name
        if frame.name in self.copies or not path.is_file():
            return False
        written = path.stat()
        if written.st_size == 0:
            return False
        if _changed_since(Path(frame.source), written.st_mtime_ns):
            self.changed += 1
            return False
        return True

    def write(self, item: InputFrame, restored: np.ndarray | None) -> None:
        """Write ``restored`` under the frame's name, or copy the original file.

        Raises:
            CaptureError: the original cannot be read to copy it (this frame
                only; a failure to write OUT stays an ``OSError``).
        """
        destination = self.out_dir / item.name
        if os.path.isabs(item.name) or ".." in Path(item.name).parts:
            # readers name frames inside their input; one that did not must not write elsewhere
            raise CaptureError(f"{item.source}: its name {item.name!r} leaves OUT; not written")
        if restored is None:
            try:
                with open(item.source, "rb"):  # reading the original is this frame's problem
                    pass
            except OSError as exc:
                raise CaptureError(
                    f"{item.source}: cannot read ({exc.strerror or exc}); not copied to OUT"
                ) from exc
            if item.name not in self.copies:  # named first: a kill after the copy keeps it listed
                self.copies.add(item.name)
                self.copies_file.parent.mkdir(parents=True, exist_ok=True)
                with (
                    naming_errors(self.copies_file),
                    self.copies_file.open("a", encoding="utf-8") as journal,
                ):
                    journal.write(json.dumps(item.name) + "\n")  # one line, any name
            copy_file(Path(item.source), destination)
        else:
            destination.parent.mkdir(parents=True, exist_ok=True)
            alpha = _alpha_of(Path(item.source), restored.shape[:2])
            orientation, metadata = _layout_of(Path(item.source))
            # a premultiplied TIFF stays marked so: its colour values mean that
            associated = alpha is not None and alpha_is_associated(Path(item.source))
            # FAST_PNG: a robot's stream wants speed
            write_image(
                destination, restored, png_level=FAST_PNG, alpha=alpha, orientation=orientation,
                associated=associated, metadata=metadata,
            )  # fmt: skip
            self.copies.discard(item.name)

    def cached(self, frame: InputFrame) -> np.ndarray | None:
        """Files need no cache: a finished frame is its output file."""
        return None

    def close(self) -> None:
        """Nothing to close for files."""
        return

    def finish(self) -> None:
        """Rewrite ``OUT/.restore-copies`` with the copies left (remove it when none)."""
        self._rewrite_copies()

    def _rewrite_copies(self) -> None:
        if self.copies:
            lines = "".join(json.dumps(name) + "\n" for name in sorted(self.copies))
            atomic_write_text(self.copies_file, lines)
        else:
            self.copies_file.unlink(missing_ok=True)


VIDEO_SUFFIXES = frozenset(
    {".avi", ".mp4", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg", ".ogv"}
    | {".ts", ".m2ts", ".mts", ".flv", ".wmv", ".3gp"}
)
"""Video files: their frames are not read (split them into images first)."""
RAW_IMAGE_SUFFIXES = frozenset(
    {".dng", ".cr2", ".cr3", ".nef", ".arw", ".orf", ".rw2", ".raf", ".pef", ".srw"}
)
"""Camera raw files: the sensor's mosaic, not an image until the camera's software
demosaics it (a DNG is a TIFF container, which OpenImageIO may open all the same)."""
UNREAD_IMAGE_SUFFIXES = frozenset({".webp", ".gif", ".heic", ".heif", ".jp2", ".exr", ".avif"})
"""Images in formats that are not read (convert them to PNG or TIFF)."""

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


class BagSink:
    """Writes a copy of a bag; restored images replace (or sit beside) the originals.

    A bag cannot be appended to, so it is written in one pass. To let
    ``--resume`` continue a killed run without running the network again,
    each restored frame is also kept in ``OUT/.restore-cache/<bag>/<index>.npy``
    (written atomically after its message); a resumed run takes cached frames
    from there, writes the whole bag again (byte-identical: the same pixels,
    messages and order) and removes the cache when the bag is complete.

    Args:
        source: the input bag.
        out_dir: the output folder; the bag keeps its name inside it.
        suffix: see :class:`~lenspair.capture.bagwrite.BagCopy`.
        resume: keep the cache of an earlier run (else it is cleared).
    """

    def __init__(self, source: Path, out_dir: Path, suffix: str = "", resume: bool = False) -> None:
        self.source = Path(source)
        self.path = output_bag_path(source, out_dir)
        self.cache = Path(out_dir) / CACHE_DIR / self.path.name
        self.state_dir = self.cache  # dropped with the cache once the bag is complete
        self.partial = Path(out_dir) / PARTIAL_DIR / self.path.name
        remove_path(self.partial)  # a killed run's unfinished bag: this run writes it anew
        fingerprint = source_fingerprint(self.source)
        stamped = read_json_field(self.cache / SOURCE_STAMP, "files")
        # a cache without a stamp (an earlier version's) is trusted, as it was then
        if resume and stamped is not None and stamped != fingerprint:
            log.warning("%s changed since the run being resumed: restoring it anew", source)
            resume = False
        if not resume and self.cache.exists():
            shutil.rmtree(self.cache)
        self.fingerprint = fingerprint
        self.copy = BagCopy(source, self.partial, suffix)
        self.opened = False

    @property
    def output(self) -> Path:
        """The bag written."""
        return self.path

    def finished(self, recorded: object, written: object) -> bool:
        """Whether a complete earlier run wrote this bag from the files it reads now.

        Args:
            recorded: the source files that run's report kept (its
                ``source_files``; :meth:`finish` drops the cache and its stamp).
            written: the output bag's files as that run left them (its
                ``output_files``): a bag deleted, cut or replaced since is written again.
        """
        # a missing output states as [name, None, None]: unlike any recorded one
        return (
            bool(recorded)
            and recorded == self.fingerprint
            and bool(written)
            and written == self.written()
        )

    def written(self) -> list[list[Any]]:
        """Name, size and modification time of the output bag's files (after :meth:`finish`)."""
        return source_fingerprint(self.path)

    def _cached_path(self, frame: InputFrame) -> Path:
        return self.cache / f"{frame.index}.npy"

    def done(self, frame: InputFrame) -> bool:
        """True when an earlier run restored ``frame`` (it is in the cache)."""
        return self._cached_path(frame).is_file()

    def cached(self, frame: InputFrame) -> np.ndarray | None:
        """The restored pixels an earlier run kept for ``frame``."""
        return np.asarray(np.load(self._cached_path(frame), allow_pickle=False))

    def write(self, item: BagMessage, restored: np.ndarray | None) -> None:
        """Copy the message, with ``restored`` pixels when given (then cache them)."""
        with self._writing():
            self._open()
            self.copy.write(item, restored)
        if restored is not None and item.frame is not None and not self.done(item.frame):

            def _save(tmp: Path) -> None:
                # serialised first: np.save's own short write names no errno and no file
                buffer = io.BytesIO()
                np.save(buffer, restored, allow_pickle=False)
                tmp.write_bytes(buffer.getbuffer())

            # synced, unlike the image frames: done() trusts a cached frame that exists
            atomic_write(self._cached_path(item.frame), _save, suffix=".npy")

    def _open(self) -> None:
        # SQLite handles belong to the thread that made them: open in the writer
        # thread, on the first message (a run refused at its first frame leaves OUT empty).
        if not self.opened:
            self.cache.mkdir(parents=True, exist_ok=True)
            # what the cached frames were restored from: a resume checks it
            atomic_write_json(self.cache / SOURCE_STAMP, {"files": self.fingerprint})
            self.partial.parent.mkdir(parents=True, exist_ok=True)
            self.copy.__enter__()
            self.opened = True

    def close(self) -> None:
        """Close the bag (index, metadata); call from the thread that wrote."""
        if self.opened:
            with self._writing():
                self.copy.__exit__(None, None, None)

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """The bag writers' refusals as the file system's, naming the bag being written.

        rosbags' writers pass on a full disk as an ``OSError`` naming no file, and
        SQLite's (db3) as its own ``disk I/O error``: the CLI said "File too large"
        with no path, or printed a traceback.
        """
        try:
            with naming_errors(self.partial):
                yield
        except sqlite3.OperationalError as exc:
            if "disk" not in str(exc):
                raise
            raise OSError(errno.EIO, f"cannot write the bag ({exc})", str(self.partial)) from exc

    def finish(self) -> None:
        """After a complete run: put the bag in place, copy its folder's files, drop the cache.

        The bag is written under ``OUT/.restore-partial/`` and moved to its
        name only now, so a killed run never leaves a bag that reads cleanly
        but lacks its last messages. A ROS 2 bag folder may hold files of the
        recording beside its storage (``rig.yaml``, a calibration): they are
        copied; its storage files and ``metadata.yaml`` are not (the new bag
        has its own).
        """
        if self.partial.exists():
            remove_path(self.path)  # an earlier complete run's bag, replaced by this one
            self.partial.rename(self.path)
        if self.partial.parent.is_dir() and not any(self.partial.parent.iterdir()):
            self.partial.parent.rmdir()
        if self.source.is_dir() and self.path.is_dir():
            for extra in sorted(self.source.iterdir()):
                # run.db3, run.db3-wal, run.mcap: the storage and its SQLite side files; a
                # ROS 1 bag kept there (.bag or .bag.active) is a file of the recording
                suffix = extra.suffix.lower().split("-")[0]
                storage = extra.name == "metadata.yaml" or suffix in ROS2_STORAGE_SUFFIXES
                if extra.is_file() and not storage and not (self.path / extra.name).exists():
                    copy_file(extra, self.path / extra.name)
        if self.cache.exists():
            shutil.rmtree(self.cache)
        if self.cache.parent.is_dir() and not any(self.cache.parent.iterdir()):
            self.cache.parent.rmdir()
