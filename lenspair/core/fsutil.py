"""Atomic file writes and checksums.

Every output file lenspair writes goes through these helpers: data is written
to a temporary file in the destination folder, flushed to the disk (reports,
journals, configs, checkpoints; image frames are checked on a rerun instead)
and renamed into place, so an interrupted run (or a power cut) never leaves
a half-written file under its final name, and a rerun can trust any file
that exists. Files get the permissions a plain ``open()`` would give them
(``0o666`` less the umask), not the owner-only mode of the temporary file, so
a dataset built by one user can be read by a training job running as another.
"""

import errno
import fcntl
import hashlib
import json
import math
import os
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from lenspair.core.leftovers import temporary_prefix

# linux/fs.h FICLONE = _IOW(0x94, 9, int): share the source's blocks copy-on-write
_FICLONE = 0x40049409


def _umask() -> int:
    """The process umask (read once, at import, before any worker threads)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _umask()

FILE_MODE = 0o666 & ~_UMASK
"""The mode ``open()`` gives a new file."""

FOLDER_MODE = 0o777 & ~_UMASK
"""The mode ``mkdir()`` gives a new folder (less the set-group-ID bit it inherits)."""


def temporary_folder(parent: Path, name: str, suffix: str) -> Path:
    """A new folder in ``parent`` that becomes ``parent / name`` by a rename, when complete.

    Named as :func:`lenspair.core.leftovers.temporary_prefix` says (a killed
    run's leftovers are found by it), with the mode ``mkdir()`` would give,
    not ``mkdtemp``'s owner-only 0o700, which the rename would carry over.
    A refusal (a read-only file system, a folder of another user) names
    ``parent / name``, the folder the user asked for, not the temporary.
    """
    with naming_errors(Path(parent) / name):
        folder = Path(tempfile.mkdtemp(prefix=temporary_prefix(name), suffix=suffix, dir=parent))
        # the set-group-ID bit a shared group folder hands down (mkdir keeps it; chmod must too)
        os.chmod(folder, FOLDER_MODE | (folder.stat().st_mode & stat.S_ISGID))
    return folder


def atomic_write(
    path: Path, writer: Callable[[Path], None], suffix: str = "", sync: bool = True
) -> None:
    """Call ``writer(tmp_path)`` and rename the result to ``path`` atomically.

    Args:
        path: final destination; its parent folder is created when missing.
        writer: function that writes the complete file at the path it is given.
        suffix: extension for the temporary name (some writers pick the format
            from it, e.g. ``.png``).
        sync: flush the data to the disk before the rename (:func:`_sync`).
            Image frames skip it (:func:`lenspair.core.imagewrite.write_image`):
            one fsync per frame can cost more than the frame on a robot's
            SD card or eMMC, and the stages that write frames check them on a
            rerun instead (capture-ingest by SHA-256, restore by size).

    Raises:
        OSError: the file system refused (read-only, full, a file-size
            limit); it names ``path``, never the temporary (:func:`naming_errors`).

    """
    path = Path(path)
    tmp = _write_temporary(path, writer, suffix, sync)
    try:
        with naming_errors(path):
            os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _write_temporary(path: Path, writer: Callable[[Path], None], suffix: str, sync: bool) -> Path:
    """The complete file ``writer`` writes, in a temporary beside ``path`` (removed on failure)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with naming_errors(path):
        fd, tmp_name = tempfile.mkstemp(
            prefix=temporary_prefix(path.name), suffix=suffix + ".tmp", dir=path.parent
        )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        with naming_errors(path):
            writer(tmp)
            os.chmod(tmp, FILE_MODE)  # mkstemp creates 0o600
            if sync:
                _sync(tmp)  # where NFS and the like report a full disk
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


def _bytes_writer(data: bytes) -> Callable[[Path], None]:
    """A writer for :func:`atomic_write` that writes ``data``."""

    def _write(tmp: Path) -> None:
        tmp.write_bytes(data)

    return _write


def atomic_write_texts(files: dict[Path, str]) -> None:
    """Write several UTF-8 files that belong together: all of them, or none.

    As :func:`atomic_write_files`, for texts.
    """
    atomic_write_files({path: _utf8(text) for path, text in files.items()})


def atomic_write_files(files: dict[Path, bytes]) -> None:
    """Write several files that belong together: all of them, or none.

    Each is written and flushed to a temporary beside it; only once every one
    is complete, and no destination is a folder, are they renamed into place,
    in the order given. A refusal while writing (a full disk, a file-size
    limit) or a folder in a file's place leaves every earlier version as it
    was, so a product never sits beside a report of another run. The renames
    themselves (within each file's folder) are not undone if one of them
    fails after another succeeded; give the product last.

    Raises:
        OSError: as :func:`atomic_write`, naming the file refused.
    """
    for path in files:
        if Path(path).is_dir():
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
    temporaries: list[tuple[Path, Path]] = []
    try:
        for path, data in files.items():
            writer = _bytes_writer(data)
            temporaries.append((_write_temporary(Path(path), writer, "", True), path))
        for tmp, path in temporaries:
            with naming_errors(Path(path)):
                os.replace(tmp, path)
    except BaseException:
        for tmp, _ in temporaries:
            tmp.unlink(missing_ok=True)
        raise


@contextmanager
def naming_errors(path: Path) -> Iterator[None]:
    """Name ``path`` in a file-system error that names one of its temporaries, or no file.

    A refusal met while writing ``path`` through a temporary
    (:func:`atomic_write`'s file, a dataset's ``.building`` folder: any name
    :func:`~lenspair.core.leftovers.temporary_prefix` gives this process for
    ``path``) named that temporary, which the user never asked for and which
    is gone by the time the message is read: it is raised again naming the
    user's path instead, and a file inside a temporary folder by its final
    path under ``path``; ``errno`` and ``strerror`` are kept. A write or flush
    that fills the disk raises ``OSError(ENOSPC)`` naming no file, and the CLI
    could then only say "No space left on device": it names ``path`` too.
    Errors naming other files only, and other exceptions, pass unchanged.
    """
    try:
        yield
    except OSError as exc:
        if exc.errno is None:
            raise
        named = _user_path(exc, Path(path))
        if named is None:
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), str(named)) from exc


def _user_path(exc: OSError, path: Path) -> Path | None:
    """The path ``exc`` should name for a write of ``path``; ``None``: leave it as it is."""
    given = [n for n in (exc.filename, exc.filename2) if n is not None]
    if not given:
        return path
    # a file descriptor (an int) names no path: not one of ours
    names = [Path(os.fsdecode(n)) for n in given if isinstance(n, str | bytes | os.PathLike)]
    moved = [_final_path(name, path) for name in names]
    if all(final is None for final in moved):  # also when it named only a descriptor
        return None  # a source read, another file: its own name says it
    # a rename between a temporary and the user's path (put in place, set aside) names the latter
    for name, final in zip(names, moved, strict=True):
        if final is None and _absolute(name).is_relative_to(_absolute(path)):
            return name
    return next(final for final in moved if final is not None)


def _final_path(name: Path, path: Path) -> Path | None:
    """``name`` inside a temporary of ``path`` (or the temporary itself) as it will be named."""
    try:
        relative = _absolute(name).relative_to(_absolute(path.parent))
    except ValueError:
        return None
    if not relative.parts or not relative.parts[0].startswith(temporary_prefix(path.name)):
        return None
    return path.joinpath(*relative.parts[1:])


def _absolute(path: Path) -> Path:
    """``path`` made absolute without following links (a temporary may be gone)."""
    return Path(os.path.abspath(path))


def make_folder(folder: Path) -> list[Path]:
    """``folder.mkdir(parents=True, exist_ok=True)``; returns the folders it made, innermost first.

    For a command that makes its output folder before its work and must leave
    no folder of its own behind when that work fails (:func:`remove_made`).
    """
    made = [f for f in (folder, *folder.parents) if not f.exists()]
    folder.mkdir(parents=True, exist_ok=True)
    return made


def remove_made(made: list[Path]) -> None:
    """Remove the folders :func:`make_folder` made, innermost first, while they are empty.

    One that holds something now (another's file) is left, and so are those above it.
    """
    with suppress(OSError):
        for folder in made:
            folder.rmdir()


def check_writable(path: Path) -> None:
    """Raise now the refusal that writing ``path`` at the end of a long run would meet.

    For commands that write only once their work is done (calibrate after
    the calibration, dataset-build after measuring every pair): a read-only
    file system or another user's folder costs no minutes. An empty temporary
    is made and removed at once where ``path`` (a file, or a folder built
    beside it and renamed into place) would be written: in its folder, or,
    where folders are still to be made, in the nearest one above that exists.
    Nothing is left behind; space is not checked (a full disk is found as
    the files are written, and named then).

    Raises:
        OSError: the file system refused; it names ``path``.

    """
    path = Path(path)
    child, folder = path, path.parent
    while not folder.exists() and folder != folder.parent:
        child, folder = folder, folder.parent
    if not folder.is_dir():
        return  # a file where a folder goes: making the folders says so, naming it
    try:
        fd, name = tempfile.mkstemp(prefix=temporary_prefix(child.name), suffix=".tmp", dir=folder)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc
    try:
        os.close(fd)
    finally:  # also on Ctrl-C (a kill -9 here leaves it, named as a leftover of path)
        os.unlink(name)


def _sync(path: Path) -> None:
    """Flush ``path``'s data to the disk before it is renamed into place.

    Without it a power cut soon after the rename (a robot's battery) can leave
    the final name holding an empty file, which a rerun would trust. About
    0.3 ms a file on an SSD.
    """
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    atomic_write(path, _bytes_writer(data))


def atomic_write_text(path: Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically.

    A file name that is not UTF-8 (surrogate escapes, as Python reads it) is
    written with backslash escapes: the report stays UTF-8.
    """
    atomic_write_bytes(path, _utf8(text))


def _utf8(text: str) -> bytes:
    """``text`` as UTF-8, surrogate escapes (non-UTF-8 file names) as backslash escapes."""
    return text.encode("utf-8", "backslashreplace")


def json_safe(obj: Any) -> Any:
    """``obj`` with non-finite floats as strings (``"inf"``, ``"-inf"``, ``"nan"``): strict JSON.

    Text is never touched, so a path or a CPU name holding ``Infinity`` stays as it is.
    """
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def json_text(obj: Any) -> str:
    """``obj`` as stable, indented JSON (sorted keys, trailing newline)."""
    return json.dumps(obj, indent=2, sort_keys=True) + "\n"


def atomic_write_json(path: Path, obj: Any) -> None:
    """Write ``obj`` as stable, indented JSON (:func:`json_text`)."""
    atomic_write_text(path, json_text(obj))


def remove_path(path: Path) -> None:
    """Remove a file or a whole folder (a link itself, not what it points to); absent: nothing."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


def inside_refusal(out: Path, source: Path, what: str, why: str) -> str | None:
    """The one-line refusal of an ``--out`` folder that is ``source`` or lies inside it, else None.

    For commands that write beside what they read (restore, detect, eval): an
    output inside the input would be read back as input by the next run.
    ``source`` counts only when it is a folder; both are compared resolved, so
    a link to the input is the input. ``what`` names the input in the message
    ("the input", "the pairs scored"); ``why`` says what would go wrong.
    """
    source_resolved = source.resolve()
    if source_resolved.is_dir() and out.resolve().is_relative_to(source_resolved):
        return f"--out {out}: inside {what} {source}; {why}, so choose a folder outside it"
    return None


def read_json_field(path: Path, key: str) -> Any:
    """``key`` of the JSON object in ``path``; ``None`` when the file is absent or unreadable.

    For a rerun reading what an earlier run recorded (its source, its
    settings): a file it cannot parse tells nothing, and the rerun rewrites it.
    """
    data = read_json_object(path)
    return None if data is None else data.get(key)


def read_json_object(path: Path) -> dict[str, Any] | None:
    """The JSON object in ``path``; ``None`` when absent, unreadable or not an object.

    :func:`read_json_field` for a caller that needs several fields of one file.
    """
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def atomic_write_lines(path: Path, lines: Iterable[str]) -> None:
    """Write text lines (each without its newline) to ``path`` atomically."""
    atomic_write_text(path, "".join(line + "\n" for line in lines))


def clone_file(source: Path, destination: Path) -> str:
    """Make ``destination`` an independent copy of ``source``: a reflink where possible.

    Like ``cp --reflink=auto``: on file systems with copy-on-write clones
    (Btrfs, XFS, bcachefs, ...) the copy shares blocks and costs no space until
    either side is changed; elsewhere the bytes are copied. Either way,
    editing one file never changes the other (unlike a hard link).

    Returns:
        ``"reflink"`` or ``"copy"``: what was done.

    """
    with open(source, "rb") as src, open(destination, "wb") as dst:
        try:
            fcntl.ioctl(dst.fileno(), _FICLONE, src.fileno())
            return "reflink"
        except OSError:  # not supported here, or across file systems
            pass
    shutil.copyfile(source, destination)
    return "copy"


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path, chunk_size: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's content, read in chunks."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        while chunk := handle.read(chunk_size):
            digest.update(chunk)
    return digest.hexdigest()
