"""Resume bookkeeping of ``capture-ingest``: the journal of finished frames.

Each finished frame is appended to ``.journal.jsonl`` in the recording's
output folder, one JSON line ``{"key": ..., "record": ...}``, where the key
hashes everything the frame's outputs depend on (see :func:`fingerprint`).
A rerun skips frames whose key matches and whose files still have the
recorded checksums (:func:`still_valid`), so an interrupted run (even
``kill -9``) finishes the work and a full rerun leaves every file
byte-identical. Half-written temporaries and images no kept record lists are
deleted (:func:`remove_temporaries`, :func:`remove_stale_outputs`).
"""

import json
from pathlib import Path
from typing import Any

from lenspair.capture.ingest_frames import OUTPUT_KINDS
from lenspair.capture.ingested import PairRecord
from lenspair.core.config import load_dataclass, to_plain
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import sha256_bytes, sha256_file

JOURNAL_FILE = ".journal.jsonl"


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


def remove_temporaries(out_dir: Path) -> None:
    """Delete half-written temporary files a killed run left (atomic writes never finished)."""
    for folder in (out_dir, *(out_dir / kind for kind in OUTPUT_KINDS)):
        for path in sorted(folder.glob(".*.tmp")):
            path.unlink(missing_ok=True)


def remove_stale_outputs(out_dir: Path, records: list[PairRecord]) -> None:
    """Delete images under input/, target/, mask/ that no kept record lists (earlier runs)."""
    listed = {out_dir / name for record in records for name in record.files.values()}
    for kind in OUTPUT_KINDS:
        for path in sorted((out_dir / kind).glob("*.png")):
            if path not in listed:
                path.unlink()


def still_valid(out_dir: Path, record: PairRecord) -> bool:
    """Whether every file ``record`` lists exists under ``out_dir`` with its recorded SHA-256."""
    for kind, relative in record.files.items():
        path = out_dir / relative
        if not path.is_file() or sha256_file(path) != record.sha256.get(kind):
            return False
    return True
