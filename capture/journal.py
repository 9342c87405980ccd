"""Resume bookkeeping of ``capture-ingest``: the journal of finished frames.

Each finished frame is appended to ``.journal.jsonl`` in the recording's
output folder, one JSON line ``{"key": ..., "record": ...}``, where the key
hashes everything the frame's outputs depend on (see :func:`fingerprint`).
A rerun skips frames whose key matches and whose files still have the
recorded checksums (:func:`still_valid`), so an interrupted run (even
``kill -9``) finishes the work and a full rerun leaves every file
byte-identical. Half-written temporaries of killed runs and frame images no
kept record lists are deleted (:func:`remove_temporaries`,
:func:`remove_stale_outputs`); files a user put there are left alone.

One run at a time writes an output folder: :func:`hold_output` locks
``.capture-ingest.lock`` in it for the whole run and refuses a second run.
"""

import errno
import fcntl
import json
import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest_frames import OUTPUT_KINDS
from lenspair.capture.ingested import PairRecord
from lenspair.core.config import load_dataclass, to_plain
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import naming_errors, sha256_bytes, sha256_file
from lenspair.core.leftovers import remove_leftovers

logger = logging.getLogger(__name__)

JOURNAL_FILE = ".journal.jsonl"
LOCK_FILE = ".capture-ingest.lock"
"""Locked by the run writing the folder (:func:`hold_output`); empty, and left in place.

A hidden name: ``dataset-build OUT/*`` does not take it for a recording, the
stale-output clean-up skips it, and it matches no temporary's pattern
(:mod:`lenspair.core.leftovers`), so no clean-up removes it while it is held.
"""


def fingerprint(obj: Any) -> str:
    """A stable hash of a JSON-able value, for resume and cache keys.

    Args:
        obj: nested dicts, lists and scalars; keys are sorted and anything
            JSON cannot hold is hashed as its ``str``.

    Returns:
        The SHA-256 hex digest of the canonical JSON text.

    """
    return sha256_bytes(json.dumps(obj, sort_keys=True, default=str).encode("utf-8"))


def read_journal(path: Path) -> dict[int, tuple[str, PairRecord]]:
    """The frames a journal records as finished.

    Args:
        path: the journal file; a missing file is an empty journal.

    Returns:
        ``{t_ns: (key, record)}``; for a timestamp listed twice the last line
        wins. Lines that do not parse (cut by a crash) are skipped, so their
        frames are simply redone.

    """
    entries: dict[int, tuple[str, PairRecord]] = {}
    if not path.is_file():
        return entries
    for line in path.read_text(encoding="utf-8").splitlines():
        try:  # a line cut by a crash is ignored: that frame is simply redone
            data = json.loads(line)
            record = load_dataclass(PairRecord, data["record"])
            entries[record.t_ns] = (str(data["key"]), record)
        except (ValueError, KeyError, TypeError, LenspairError):
            continue
    return entries


def journal_line(key: str, record: PairRecord) -> str:
    """One journal line (newline included) recording ``record`` as done under ``key``."""
    return json.dumps({"key": key, "record": to_plain(record)}, sort_keys=True) + "\n"


@contextmanager
def hold_output(out_dir: Path) -> Iterator[None]:
    """Hold the lock of ``out_dir`` (an existing folder) meanwhile; refuse it if taken.

    Two runs writing one output at once removed each other's frames and left
    a ``pairs.jsonl`` naming files of neither. The lock is ``flock`` on
    :data:`LOCK_FILE`: the kernel releases it when its holder dies, however
    it dies (``kill -9`` too), so a killed run never blocks its rerun, and
    there is no stale lock to remove. The file stays (removing it while
    another run waits to open it would let two runs hold two files). Pool
    workers (``spawn``) do not inherit it. On a file system without locks
    the run goes on, with a warning.

    Raises:
        CaptureError: another process holds the lock (one line naming ``out_dir``).
        OSError: the lock file cannot be created (a read-only folder: named).
    """
    path = out_dir / LOCK_FILE
    with naming_errors(path):
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise CaptureError(
                f"{out_dir}: another capture-ingest is writing it; run this one when that "
                "one has finished, or with another --out"
            ) from None
        except OSError as exc:
            if exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.EINVAL):
                raise
            logger.warning(
                "%s: cannot be locked (%s): nothing stops a second capture-ingest from writing "
                "it at the same time; run one at a time",
                out_dir,
                exc.strerror or exc,
            )
        yield
    finally:
        os.close(descriptor)  # releases the lock


def remove_temporaries(out_dir: Path) -> None:
    """Delete half-written temporaries that killed runs left (their writer process is gone)."""
    for folder in (out_dir, *(out_dir / kind for kind in OUTPUT_KINDS)):
        remove_leftovers(folder)


def remove_stale_outputs(
    out_dir: Path, records: list[PairRecord], own_frames: set[int] | None = None
) -> None:
    """Delete frame images of earlier runs that no kept record lists; never a user's file.

    Only ``<t_ns>.png`` files named after a frame of this recording are ingest's
    own: a frame of ``records`` or of ``own_frames`` (every frame of both
    cameras, so that the outputs of a run with the other side declared
    obstructed go too). Each deletion is logged. Any other file under
    ``input/``, ``target/``, ``mask/`` was not written by ``capture-ingest``:
    it is left in place with a warning.
    """
    listed = {out_dir / name for record in records for name in record.files.values()}
    frames = {str(record.t_ns) for record in records} | {str(t) for t in own_frames or ()}
    for kind in OUTPUT_KINDS:
        folder = out_dir / kind
        if not folder.is_dir():
            continue
        for path in sorted(folder.iterdir()):
            if path in listed or path.name.startswith("."):
                continue
            if path.suffix == ".png" and path.stem in frames and path.is_file():
                path.unlink()
                logger.info("removed %s: written by an earlier run, not kept now", path)
            else:
                logger.warning("%s: not written by capture-ingest; left in place", path)


def still_valid(out_dir: Path, record: PairRecord) -> bool:
    """Whether every file ``record`` lists exists under ``out_dir`` with its recorded SHA-256."""
    for kind, relative in record.files.items():
        path = out_dir / relative
        if not path.is_file() or sha256_file(path) != record.sha256.get(kind):
            return False
    return True
