"""Resume bookkeeping of ``capture-ingest``: the journal of finished frames.

Each finished frame is appended to ``.journal.jsonl`` in the recording's
output folder, one JSON line ``{"key": ..., "record": ...}``, where the key
hashes everything the frame's outputs depend on (see :func:`fingerprint`).
Each line also names the settings its frame was made with (``made_with``,
their fingerprint; the first line a run writes holds the settings
themselves), so a rerun that processes finished frames again can say which
setting differs (:func:`redo_reasons`).
A rerun skips frames whose key matches and whose files still have the
recorded checksums (:func:`still_valid`), so an interrupted run (even
``kill -9``) finishes the work and a full rerun leaves every file
byte-identical. Half-written temporaries of killed runs and frame images no
kept record lists are deleted (:func:`remove_temporaries`,
:func:`remove_stale_outputs`); files a user put there are left alone.

One run at a time writes an output folder: :func:`hold_output` locks
``.capture-ingest.lock`` in it for the whole run and refuses a second run.
"""

import contextlib
import json
import logging
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest_frames import OUTPUT_KINDS
from lenspair.capture.ingested import PairRecord
from lenspair.core.config import load_dataclass, to_plain
from lenspair.core.errors import LenspairError
from lenspair.core.folderlock import holding
from lenspair.core.fsutil import sha256_bytes, sha256_file
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


def journal_line(
    key: str,
    record: PairRecord,
    made_with: str | None = None,
    settings: dict[str, Any] | None = None,
) -> str:
    """One journal line (newline included) recording ``record`` as done under ``key``.

    Args:
        key: the frame's key (:attr:`lenspair.capture.ingest_frames.FrameTask.key`).
        record: the frame's record.
        made_with: the fingerprint of the settings of the run that made the frame.
        settings: those settings (JSON-able; :func:`redo_reasons` names their
            keys), given on the first line a run writes: later lines name them.
    """
    line: dict[str, Any] = {"key": key, "record": to_plain(record)}
    if made_with is not None:
        line["made_with"] = made_with
    if settings is not None:
        line["settings"] = settings
    return json.dumps(line, sort_keys=True) + "\n"


def _made_with(path: Path) -> tuple[dict[int, str], dict[str, dict[str, Any]]]:
    """``({t_ns: made_with}, {made_with: settings})`` of a journal's lines that have them."""
    frames: dict[int, str] = {}
    settings: dict[str, dict[str, Any]] = {}
    with contextlib.suppress(OSError):
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                data = json.loads(line)
                made_with = str(data["made_with"])
                frames[int(data["record"]["t_ns"])] = made_with
                if isinstance(data.get("settings"), dict):
                    settings[made_with] = data["settings"]
            except (ValueError, KeyError, TypeError, AttributeError):
                continue  # an earlier version's line, or one cut by a crash: reason unknown
    return frames, settings


def _first_difference(before: Any, now: Any, where: str = "") -> tuple[str, Any, Any] | None:
    """``(dotted key, before, now)`` of the first value that differs, in ``now``'s key order."""
    if isinstance(before, dict) and isinstance(now, dict):
        for key in [*now, *(k for k in before if k not in now)]:
            found = _first_difference(before.get(key), now.get(key), f"{where}.{key}".lstrip("."))
            if found is not None:
                return found
        return None
    return None if before == now else (where, before, now)


def _was_now(where: str, before: Any, now: Any) -> str:
    """``KEY was A, now B``; long values (a 4x4 transform) only named."""
    shown = [json.dumps(value) for value in (before, now)]
    if max(map(len, shown)) > 60:
        return f"{where} changed"
    return f"{where} was {shown[0]}, now {shown[1]}"


def changed_setting(before: dict[str, Any], now: dict[str, Any]) -> str | None:
    """The first setting of :func:`redo_reasons`'s list that differs, said; None: all equal.

    Args:
        before: the settings the finished frames were made with (read back from JSON).
        now: this run's.
    """
    now = json.loads(json.dumps(now))  # tuples as lists, as read back
    if before.get("obstructed") != now.get("obstructed"):
        return (
            f"the obstructed side differs (was {before.get('obstructed')}, now {now['obstructed']})"
        )
    calibration = _first_difference(before.get("calibration"), now.get("calibration"))
    if calibration is not None:
        source, source_now = before.get("calibration_source"), now.get("calibration_source")
        if source != source_now:
            return f"the calibration differs (was {source}, now {source_now})"
        return f"the calibration differs ({source_now} changed since: {_was_now(*calibration)})"
    if before.get("size") != now.get("size"):
        sizes = ["x".join(map(str, value or ("?",))) for value in (before.get("size"), now["size"])]
        return f"--size differs (was {sizes[0]}, now {sizes[1]})"
    if before.get("time_offset_ns") != now.get("time_offset_ns"):
        offsets = [
            f"{(value or 0) / 1e6:g} ms"
            for value in (before.get("time_offset_ns"), now["time_offset_ns"])
        ]
        return f"--time-offset differs (was {offsets[0]}, now {offsets[1]})"
    thresholds = _first_difference(before.get("verify"), now.get("verify"))
    if thresholds is not None:
        return f"the thresholds differ ({_was_now(*thresholds)})"
    for key, name in (
        ("significant_bits", "the frames' significant bits"),
        ("version", "the lenspair version"),
    ):
        if before.get(key) != now.get(key):
            return f"{name} differs (was {before.get(key)}, now {now[key]})"
    if before.get("matrix") != now.get("matrix") or before.get("crop") != now.get("crop"):
        return (
            "the homography or crop differs (registered again: other frames sampled, or "
            "other estimation thresholds)"
        )
    return None


UNKNOWN_REASON = (
    "the calibration, obstructed side, --size, --time-offset, thresholds or input frames "
    "differ from the run that wrote them"
)
"""Said of redone frames whose journal line names no settings (an earlier version's)."""


def redo_reasons(path: Path, redone: list[int], now: dict[str, Any]) -> str:
    """Why finished frames are processed again: the first setting that differs, per frame.

    Compares the settings each frame was made with (its journal line's
    ``made_with``) against this run's, in the order: obstructed side,
    calibration, ``--size``, ``--time-offset``, thresholds, significant bits,
    lenspair version, homography and crop; a frame made with this run's very
    settings is processed again because its input frames differ.

    Args:
        path: the journal.
        redone: timestamps of the finished frames processed again.
        now: this run's settings (as given to :func:`journal_line`).

    Returns:
        One reason, or several with their counts (``REASON for N frames; ...``).
    """
    made_with, settings = _made_with(path)
    reasons: Counter[str] = Counter()
    for t_ns in redone:
        before = settings.get(made_with.get(t_ns, ""))
        if before is None:
            reasons[UNKNOWN_REASON] += 1
        else:
            reasons[changed_setting(before, now) or "their input frames differ"] += 1
    if len(reasons) == 1:
        return next(iter(reasons))
    return "; ".join(f"{reason} for {count}" for reason, count in reasons.most_common())


def side_change(path: Path, gone: list[int], now: dict[str, Any]) -> str | None:
    """The change of obstructed side that left these finished frames out of this run, or None.

    The journal is keyed by the obstructed camera's timestamps: after a swap of
    sides this run's frames are the other camera's, so none of the earlier
    ones is "processed again" and nothing said why they all went.

    Args:
        path: the journal.
        gone: timestamps of finished frames that are not among this run's.
        now: this run's settings (as given to :func:`journal_line`).
    """
    made_with, settings = _made_with(path)
    for t_ns in gone:
        before = settings.get(made_with.get(t_ns, ""))
        if before is not None and before.get("obstructed") != now.get("obstructed"):
            return changed_setting(before, now)
    return None


@contextmanager
def hold_output(out_dir: Path) -> Iterator[None]:
    """Hold the lock of ``out_dir`` (an existing folder) meanwhile; refuse it if taken.

    Two runs writing one output at once removed each other's frames and left
    a ``pairs.jsonl`` naming files of neither. The lock is ``flock`` on
    :data:`LOCK_FILE` (:func:`~lenspair.core.folderlock.lock_file`). Pool
    workers (``spawn``) do not inherit it. On a file system without locks
    the run goes on, with a warning.

    Raises:
        CaptureError: another process holds the lock (one line naming ``out_dir``).
        OSError: the lock file cannot be created (a read-only folder: named).
    """
    taken = CaptureError(
        f"{out_dir}: another capture-ingest is writing it (or a dataset-build is reading it); "
        "run this one when that one has finished, or with another --out"
    )
    with holding(out_dir / LOCK_FILE, "capture-ingest", taken):
        yield


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
    obstructed go too). The deletions are counted in one line (each file at
    debug level). Any other file under ``input/``, ``target/``, ``mask/`` was
    not written by ``capture-ingest``: it is left in place with a warning.
    """
    listed = {out_dir / name for record in records for name in record.files.values()}
    frames = {str(record.t_ns) for record in records} | {str(t) for t in own_frames or ()}
    removed: dict[str, int] = {}
    for kind in OUTPUT_KINDS:
        folder = out_dir / kind
        if not folder.is_dir():
            continue
        for path in sorted(folder.iterdir()):
            if path in listed or path.name.startswith("."):
                continue
            if path.suffix == ".png" and path.stem in frames and path.is_file():
                path.unlink()
                removed[kind] = removed.get(kind, 0) + 1
                logger.debug("removed %s: written by an earlier run, not kept now", path)
            else:
                logger.warning("%s: not written by capture-ingest; left in place", path)
    if removed:  # one line: a file each buried the warning that said why, on long recordings
        counts = ", ".join(f"{count} from {kind}/" for kind, count in removed.items())
        logger.info("%s: removed %s, written by an earlier run and not kept now", out_dir, counts)


def still_valid(out_dir: Path, record: PairRecord) -> bool:
    """Whether every file ``record`` lists exists under ``out_dir`` with its recorded SHA-256."""
    for kind, relative in record.files.items():
        path = out_dir / relative
        if not path.is_file() or sha256_file(path) != record.sha256.get(kind):
            return False
    return True
