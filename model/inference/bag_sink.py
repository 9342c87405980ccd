"""The sink of bag inputs: a copy of the bag with restored images in it.

:class:`BagSink` writes a copy of the bag (:mod:`lenspair.capture.bagwrite`)
aside and moves it to its name when complete, with a cache of restored
frames so ``--resume`` need not run them again. A sink receives every item of
the input in order, each with restored pixels or with None (copy the message
unchanged: a frame judged clean, a frame that failed, a message that is not
an image of a chosen camera).
"""

import errno
import io
import logging
import shutil
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from lenspair.capture.bagwrite import BagCopy, is_storage_file, output_bag_path
from lenspair.capture.frame_types import BagMessage, InputFrame
from lenspair.core.fsutil import (
    atomic_write,
    atomic_write_json,
    naming_errors,
    read_json_field,
    remove_path,
)
from lenspair.core.sourcefiles import source_fingerprint
from lenspair.model.inference.options import DEFAULT_JPEG_QUALITY
from lenspair.model.inference.out_layout import CACHE_DIR, PARTIAL_DIR, SOURCE_STAMP, copy_file

log = logging.getLogger(__name__)


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
        jpeg_quality: the quality 1-100 of restored JPEG ``CompressedImage``
            messages (PNG and raw images are unaffected).
    """

    def __init__(
        self,
        source: Path,
        out_dir: Path,
        suffix: str = "",
        resume: bool = False,
        jpeg_quality: int = DEFAULT_JPEG_QUALITY,
    ) -> None:
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
        self.copy = BagCopy(source, self.partial, suffix, jpeg_quality)
        self.opened = False
        self.extras: list[Path] = []
        """Files of a ROS 2 bag folder kept beside the new bag (set by :meth:`finish`)."""

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

    def finish(self, failed: int = 0) -> None:
        """After a complete run: put the bag in place, copy its folder's files, drop the cache.

        With ``failed`` frames the cache is kept: ``--resume`` then takes the
        frames restored here from it and tries only the failed ones again (a
        frame too large for memory, with ``--tile``), as in a folder, instead
        of restoring the whole bag anew; a run without failed frames drops it.

        The bag is written under ``OUT/.restore-partial/`` and moved to its
        name only now, so a killed run never leaves a bag that reads cleanly
        but lacks its last messages. A ROS 2 bag folder may hold files of the
        recording beside its storage (``rig.yaml``, a calibration): they are
        copied (and listed in :attr:`extras`); its storage files and
        ``metadata.yaml`` are not (the new bag has its own).
        """
        if self.partial.exists():
            remove_path(self.path)  # an earlier complete run's bag, replaced by this one
            self.partial.rename(self.path)
        if self.partial.parent.is_dir() and not any(self.partial.parent.iterdir()):
            self.partial.parent.rmdir()
        if self.source.is_dir() and self.path.is_dir():
            for extra in sorted(self.source.iterdir()):
                # a ROS 1 bag kept there (.bag or .bag.active) is a file of the recording
                if extra.is_file() and not is_storage_file(extra):
                    self.extras.append(extra)
                    if not (self.path / extra.name).exists():
                        copy_file(extra, self.path / extra.name)
        if self.cache.exists() and not failed:
            shutil.rmtree(self.cache)
        if self.cache.parent.is_dir() and not any(self.cache.parent.iterdir()):
            self.cache.parent.rmdir()
