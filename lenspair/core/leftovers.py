"""Temporary names that say who made them, and removal of what killed runs left.

Every temporary file or folder lenspair creates beside an output is named
``.<name>.<pid>.<random><suffix>`` where ``<pid>`` is the creating process,
and ``<suffix>`` ends in ``.tmp`` (files), ``.building`` or ``.old`` (dataset
folders). A run that is killed (``kill -9``, power loss) cannot remove them;
the next run of the same output calls :func:`remove_leftovers`, which deletes
exactly those whose creating process no longer exists, so a concurrent run
writing beside it keeps its own temporaries. Files of other outputs, and
files whose names do not follow the pattern, are never touched.

A process that has ended but was never reaped (a zombie) counts as gone. A
process id that the system has reused for an unrelated process keeps its
leftover alive until a later rerun: the safe direction.
"""

import hashlib
import logging
import os
import re
import shutil
from pathlib import Path

logger = logging.getLogger(__name__)

LEFTOVER_SUFFIXES = (".tmp", ".building", ".old")


LONG_NAME = 120
"""Bytes of an output's name above which its temporaries carry a shortened one."""


def _stem(name: str) -> str:
    """``name`` as its temporaries carry it: itself, or a long one cut, with its hash.

    A file system refuses names over 255 bytes, and a temporary adds about 25
    to its output's: a valid name of 230 bytes could not be written at all.
    """
    if len(os.fsencode(name)) <= LONG_NAME:
        return name
    digest = hashlib.sha256(os.fsencode(name)).hexdigest()[:12]
    cut = name
    while len(os.fsencode(cut)) > LONG_NAME - len(digest) - 1:
        cut = cut[:-1]
    return f"{cut}~{digest}"


def temporary_prefix(name: str) -> str:
    """The prefix of this process's temporaries for output ``name`` (``.name.<pid>.``)."""
    return f".{_stem(name)}.{os.getpid()}."


def _zombie(pid: int) -> bool:
    """Whether ``pid`` has ended but not been reaped (Linux ``/proc``; elsewhere ``False``).

    A killed worker whose parent was killed too is re-parented to PID 1; in a
    container whose PID 1 never calls ``wait()`` it stays a zombie for good, and
    ``os.kill(pid, 0)`` still succeeds on it.
    """
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    state = stat[stat.rindex(")") + 2 :].split(maxsplit=1)[0]  # the name may hold spaces
    return state in ("Z", "X")


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` still runs: it may still be writing its temporaries."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        pass
    return not _zombie(pid)


RANDOM = r"[a-z0-9_]{8}"
"""The random part ``tempfile`` puts into a temporary's name: 8 of its 37 characters."""


def _pattern(name: str | None) -> re.Pattern[str]:
    """Temporaries of output ``name`` (None: of any): ``.<name>.<pid>.<random>[.<ext>]<ending>``.

    The random part is exactly ``tempfile``'s: with any text allowed there, a
    sibling output ``rain.2024`` had its live build ``.rain.2024.<pid>.<random>
    .building`` read as ``rain``'s, made by process 2024, and removed.
    """
    stem = re.escape(_stem(name)) if name is not None else r"[^/]+?"
    endings = "|".join(re.escape(s) for s in LEFTOVER_SUFFIXES)
    return re.compile(rf"^\.{stem}\.(?P<pid>[0-9]+)\.{RANDOM}(?:\.[^./]+)?(?:{endings})$")


def leftovers(folder: Path, name: str | None = None) -> list[Path]:
    """Temporaries in ``folder`` (of output ``name``, or of any output) whose creator is gone.

    Args:
        folder: folder to look in (not recursively); a missing folder has none.
        name: the output's file or folder name; ``None`` matches every output.

    Returns:
        Sorted paths of files and folders safe to delete.

    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    pattern = _pattern(name)
    found = []
    for entry in folder.iterdir():
        match = pattern.match(entry.name)
        if match is not None and not process_alive(int(match["pid"])):
            found.append(entry)
    return sorted(found)


def remove_leftovers(folder: Path, name: str | None = None) -> int:
    """Delete :func:`leftovers` of ``folder`` (logged); returns how many were removed."""
    removed = 0
    for path in leftovers(folder, name):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
        logger.info("removed %s, left by an interrupted run", path)
        removed += 1
    return removed


def remove_leftovers_under(root: Path) -> int:
    """:func:`remove_leftovers` in ``root`` and every folder below it; returns the count.

    For outputs that mirror an input tree (``restore`` of a folder), where a
    killed run leaves temporaries beside files at any depth.
    """
    root = Path(root)
    if not root.is_dir():
        return 0
    folders = [root, *(p for p in sorted(root.rglob("*")) if p.is_dir() and not p.is_symlink())]
    return sum(remove_leftovers(folder) for folder in folders if folder.is_dir())
