"""Checks a dataset build makes before it measures any pair.

Each refuses, with a message naming the recording or the output folder, what
would otherwise fail (or build a wrong dataset) only after every pair had been
measured: an output folder that is a mount point (:func:`check_out`),
recordings whose images contradict their declared obstructed camera
(:func:`check_sides`), a recording given twice or overlapping the output
(:func:`check_paths`), and what the output's file system would refuse
(:func:`check_file_system`).
"""

import logging
import os
import re
from collections.abc import Sequence
from pathlib import Path

from lenspair.core.fsutil import check_writable
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.output import LinkMode
from lenspair.dataset.sources import Source

logger = logging.getLogger(__name__)
MOUNT_TABLE = Path("/proc/self/mountinfo")
"""Linux's list of the process's mount points (read by :func:`check_out`)."""
_OCTAL = re.compile(rb"\\([0-7]{3})")
"""An octal escape of ``/proc/self/mountinfo`` (``\\040``: a space)."""

SIDE_MISMATCH_CONFIDENCE = 0.5
"""Detector side-check confidence from which a mismatch refuses the build (below: a warning).

A detector sure of a swapped side says 0.99 against 0.09 (confidence 0.9).
The fine-detail check only warns, whatever its confidence: refracting drops
add detail, and on heavy rain it has named the clean camera with confidence
0.52 (:mod:`lenspair.capture.side_check`).
"""


def check_out(out: Path) -> None:
    """Refuse an ``out`` that is a mount point, before any recording is read.

    A build writes into a temporary sibling of ``out`` and renames it into
    place, so ``out`` never holds a half-written dataset and a rebuild sets
    the old one aside whole. A mount point (a Docker bind mount ``-v
    host/DS:/DS``, a freshly mounted disk) cannot be renamed: the build
    measured and copied every pair onto the parent's file system (which it
    could fill), then failed the swap with ``EBUSY`` and a traceback. Writing
    into the mount point instead would give up both guarantees; a folder
    inside it keeps them, and the dataset on the mounted disk, so the
    refusal names one.

    Args:
        out: the dataset folder, resolved.

    The same rename takes the folder away from a shell in it: ``--out .``
    (or a rebuild run from inside the dataset) left the shell in a deleted
    folder, where the next command found no dataset. That is refused too.

    Raises:
        DatasetError: ``out`` is a mount point, or the current folder or one above it.
    """
    here = Path.cwd().resolve()
    if here == out or out in here.parents:
        raise DatasetError(
            f"{out}: the current folder{' or one above it' if here != out else ''}; a build "
            "replaces the dataset folder by a rename, which would leave this shell in a "
            "deleted folder: run it from outside"
        )
    if _is_mount_point(out):
        raise DatasetError(
            f"{out}: a mount point, which a build cannot replace (it renames the finished "
            f"dataset into place): give a folder inside it, e.g. --out {out / 'dataset'}"
        )


def _is_mount_point(folder: Path) -> bool:
    """Whether ``folder`` is a mount point: :func:`os.path.ismount`, or in ``/proc/self/mountinfo``.

    ``ismount`` compares the device of the folder and of its parent, which a
    bind mount within one file system shares with its parent; Linux lists
    every mount point of the process's namespace (its fifth field, octal-escaped).
    """
    if os.path.ismount(folder):
        return True
    try:
        table = MOUNT_TABLE.read_bytes()
    except OSError:  # not Linux
        return False
    wanted = os.fsencode(folder)
    for line in table.splitlines():
        fields = line.split(b" ")
        if len(fields) > 4 and _OCTAL.sub(lambda m: bytes([int(m[1], 8)]), fields[4]) == wanted:
            return True
    return False


def check_sides(sources: Sequence[Source], accept: bool) -> None:
    """Refuse recordings whose images clearly contradict the declared obstructed camera.

    capture-ingest checks the declared side and records a mismatch in
    ``report.json``, but builds the pairs as declared: built into a dataset,
    their input is the clean view and their target the obstructed one, and a
    network trained on them learns to add the anomaly. A detector's mismatch
    of confidence :data:`SIDE_MISMATCH_CONFIDENCE` or more refuses; a weaker
    one, or the fine-detail check's (reports without a ``method`` are its),
    is a warning.

    Raises:
        DatasetError: naming each such recording and what its check said.
    """
    strong: list[str] = []
    weak: list[str] = []
    for source in sources:
        check = source.report.side_check  # validated on reading (side_check_problem)
        if not check or not check["mismatch"]:
            continue
        said = f"{source.path}: {check['message']}"
        confidence = check.get("confidence")
        sure = (
            check.get("method") == "detector"
            and confidence is not None
            and confidence >= SIDE_MISMATCH_CONFIDENCE
        )
        (strong if sure and not accept else weak).append(said)
    for said in weak:
        logger.warning("building as declared, although %s", said)
    if strong:
        raise DatasetError(
            f"{'; '.join(strong)}. Their pairs would have input and target swapped: fix "
            "rig.yaml (or --obstructed) and run capture-ingest again, or pass "
            "--accept-side-mismatch if the declared side is right"
        )


def check_paths(sources: Sequence[Source], out: Path) -> None:
    """Refuse a recording given twice, two with one recording id, or one overlapping ``out``.

    Raises:
        DatasetError: naming the recording (and the other one, or ``out``).
    """
    ids: dict[str, Path] = {}
    for source in sources:
        rid = source.report.recording_id
        if rid in ids:
            if ids[rid] == source.path:
                raise DatasetError(f"{source.path}: given twice")
            raise DatasetError(f"{source.path}: recording id {rid!r} is also that of {ids[rid]}")
        ids[rid] = source.path
        if out == source.path or out in source.path.parents or source.path in out.parents:
            raise DatasetError(f"{out}: the dataset folder overlaps source {source.path}")


def check_file_system(sources: Sequence[Source], out: Path, link: LinkMode) -> None:
    """What the file system of ``out`` would refuse, found before any pair is measured.

    A recording id near 255 bytes ingests (its frames are ``<t_ns>.png``) but
    its dataset files ``<id>_<t_ns>.png`` would not fit; ``--link hard`` cannot
    link across file systems. Both failed after every pair had been measured,
    naming the build's temporary folder. So did a read-only or another user's
    folder (:func:`~lenspair.core.fsutil.check_writable`).

    Raises:
        DatasetError: a file name too long, or ``--link hard`` across file systems.
        OSError: the file system refuses to write beside ``out``; it names ``out``.
    """
    check_writable(out)
    existing = next(folder for folder in (out, *out.parents) if folder.exists())
    try:
        limit = os.pathconf(existing, "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    for source in sources:
        rid = source.report.recording_id
        names = (  # a line without files: the default layout, <kind>/<t_ns>.png
            f"{rid}_{record.t_ns}{Path(file).suffix}"
            for record in source.records
            if record.status == "kept"
            for file in (record.files.values() or ["default.png"])
        )
        longest = max(names, key=lambda name: len(name.encode()), default="")
        if len(longest.encode()) > limit:
            raise DatasetError(
                f"{source.path}: its dataset file names <recording id>_<t_ns> would be "
                f"{len(longest.encode())} bytes, over the {limit} its file system allows "
                f"(recording id {rid[:40]!r}... of {len(rid.encode())} bytes); ingest it again "
                "from a folder or bag of a shorter name"
            )
        if link == "hard":
            _check_same_file_system(source, out, existing)


def _check_same_file_system(source: Source, out: Path, existing: Path) -> None:
    """Refuse ``--link hard`` when a folder of ``source``'s kept files is on another file system.

    The folders the files lie in, not the recording's alone: a recording
    whose ``input/`` is a link to another disk passed, and the build failed
    at the first link, after every pair had been measured.
    """
    device = os.stat(existing).st_dev
    folders = {source.path} | {
        (source.path / file).parent
        for record in source.records
        if record.status == "kept"
        for file in record.files.values()
    }
    for folder in sorted(folders):
        try:
            elsewhere = os.stat(folder).st_dev != device
        except OSError:  # missing: measuring names the pair
            continue
        if elsewhere:
            raise DatasetError(
                f"--link hard: {folder} and {out} are on different file systems, which cannot "
                "share files; leave --link out to copy"
            )
