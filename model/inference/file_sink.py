"""The sink of file inputs: restored frames written under OUT with the input's names.

:class:`FileSink` serves an image, a folder of images and an EuRoC/ASL
recording: ``OUT/<name>`` keeps the input's relative name, bit depth and
channels, written atomically. For a recording every other file
(``data.csv``, ``sensor.yaml``, other cameras, ``rig.yaml``, IMU, ...) is
copied too, so OUT is the same recording with the chosen cameras restored.
``done`` tells ``--resume`` which frames are written. A sink receives every
item of the input in order, each with restored pixels or with None (copy the
original unchanged: a frame judged clean, a frame that failed).
"""

import json
import logging
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from lenspair.capture.errors import CaptureError
from lenspair.capture.folders import IMAGE_SUFFIXES
from lenspair.capture.frame_types import InputFrame
from lenspair.core.errors import ImageIOError
from lenspair.core.fsutil import atomic_write_text, naming_errors
from lenspair.core.imageio import (
    Attribute,
    alpha_is_associated,
    image_layout,
    image_metadata,
    read_alpha,
)
from lenspair.core.imagewrite import FAST_PNG, write_image
from lenspair.core.progress import progress
from lenspair.model.inference.options import DEFAULT_JPEG_QUALITY
from lenspair.model.inference.out_layout import (
    COPIES_NAME,
    OWN_NAMES,
    STALE_DIR,
    copied_already,
    copy_file,
    files_under,
)
from lenspair.model.inference.report import is_restore_output
from lenspair.model.inference.unread_files import unrestored_note

logger = logging.getLogger(__name__)


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


def _changed_since(source: Path, written_ns: int) -> bool:
    """Whether ``source`` changed after ``written_ns``, by its inode's change time.

    A copy with preserved times (``cp -p``) still counts. An input that cannot be
    read now has not changed as far as its output is concerned.
    """
    try:
        return source.stat().st_ctime_ns > written_ns
    except OSError:
        return False


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
        jpeg_quality: the quality 1-100 of every restored JPEG (other formats
            are unaffected); see :data:`~lenspair.model.inference.options.DEFAULT_JPEG_QUALITY`.
    """

    def __init__(self, out_dir: Path, jpeg_quality: int = DEFAULT_JPEG_QUALITY) -> None:
        self.out_dir = Path(out_dir)
        self.jpeg_quality = jpeg_quality
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
        (``reserved``, and :data:`~lenspair.model.inference.out_layout.OWN_NAMES`)
        would be overwritten by it: it is not copied, and one line per such
        file is returned; so is one per copied file that holds frames left
        unrestored (:func:`~lenspair.model.inference.unread_files.unrestored_note`).
        When ``root`` is an earlier restore's OUT, those files are that run's
        report and bookkeeping: they are passed over in one logged line.
        """
        skip = {Path(p).resolve() for p in restored}
        own = {*reserved, *OWN_NAMES}
        earlier = is_restore_output(root)
        clashes, passed_over = [], set()
        # a recording's other camera and truth/: tens of GB of a long run, after the
        # restoring bar has closed
        others = list(files_under(root, follow_links))
        for relative in progress(others, desc="copying the rest", unit="file"):
            source = Path(root) / relative
            if source.resolve() in skip:
                continue
            if relative.parts[0] in own and earlier:
                passed_over.add(relative.parts[0])
                continue
            if relative.parts[0] in own:
                clashes.append(
                    f"{source}: not copied: OUT/{relative.parts[0]} is restore's own "
                    "(rename the file to keep it beside the restored frames)"
                )
                continue
            if not copied_already(source, self.out_dir / relative):  # a resumed run's
                copy_file(source, self.out_dir / relative)
            if (note := unrestored_note(source)) is not None:
                clashes.append(note)
        if passed_over:
            logger.info(
                "%s is an earlier restore's output: its %s not copied",
                root,
                ", ".join(sorted(passed_over)),
            )
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
                associated=associated, metadata=metadata, jpeg_quality=self.jpeg_quality,
            )  # fmt: skip
            self.copies.discard(item.name)

    def cached(self, frame: InputFrame) -> np.ndarray | None:
        """Files need no cache: a finished frame is its output file."""
        return None

    def close(self) -> None:
        """Nothing to close for files."""
        return

    def finish(self, failed: int = 0) -> None:
        """Rewrite ``OUT/.restore-copies`` with the copies left (remove it when none).

        ``failed`` is the bag sink's concern: a failed frame's file is its copy,
        which ``--resume`` restores again.
        """
        del failed
        self._rewrite_copies()

    def _rewrite_copies(self) -> None:
        if self.copies:
            lines = "".join(json.dumps(name) + "\n" for name in sorted(self.copies))
            atomic_write_text(self.copies_file, lines)
        else:
            self.copies_file.unlink(missing_ok=True)
