"""Where an ingest writes: ``OUT/<recording_id>``, whether it may, and what a failed run leaves.

:func:`output_folder` names the folder and refuses one that is the recording
itself or holds the ingest of another recording of the same name.
:func:`discard_new_output` removes a folder the failed run made (an empty
``OUT/<rec>`` would stop ``dataset-build OUT/*``) and otherwise says that the
earlier run's pairs are still there, untouched.
"""

import os
import shutil
from pathlib import Path

from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest_report import STALE_REPORT
from lenspair.capture.ingested import PAIRS_FILE, REPORT_FILE
from lenspair.capture.recording import Recording
from lenspair.core.fsutil import read_json_field


def output_folder(out: Path, recording: Recording) -> tuple[Path, Path]:
    """``(OUT/<recording_id>, the recording's own folder or file)``, once ``out`` may be used.

    Args:
        out: the output root (``--out``), named as typed in errors.
        recording: the recording to ingest.

    Raises:
        CaptureError: the folder is the recording itself, or holds another
            recording's ingest (:func:`_check_same_source`).
    """
    out_dir = Path(out) / recording.recording_id
    source = _root(recording)
    if out_dir.resolve() == source:  # --out = the recording's parent folder
        raise CaptureError(
            f"--out {out}: the recording goes to {out_dir}, which is the recording "
            f"{source} itself; the ingest writes input/ and target/ there and removes "
            "files it did not write, so choose another --out"
        )
    _check_same_source(out_dir, source)
    return out_dir, source


def discard_new_output(out_dir: Path, created: bool) -> str:
    """Remove ``out_dir`` when this failed run ``created`` it; the note its error ends with.

    Returns:
        ``""``, or for a rerun whose folder holds an earlier run's pairs, a note
        (``; <out_dir> still holds an earlier run's pairs, left as they were``).
    """
    if created:  # an empty OUT/<rec> would stop `dataset-build OUT/*` (no pairs.jsonl)
        shutil.rmtree(out_dir, ignore_errors=True)
    return _earlier(out_dir, created)


def _root(recording: Recording) -> Path:
    """The recording's own folder or file, absolute: ``rec`` for ``rec`` and ``rec/mav0``."""
    path = Path(recording.path).resolve()
    if path.name != recording.recording_id and path.parent.name == recording.recording_id:
        return path.parent
    return path


def _earlier(out_dir: Path, created: bool) -> str:
    """A failed rerun's note: the folder still holds the earlier run's pairs, untouched."""
    if created or not (out_dir / PAIRS_FILE).is_file():
        return ""
    return f"; {out_dir} still holds an earlier run's pairs, left as they were"


def _check_same_source(out_dir: Path, source: Path) -> None:
    """Refuse to ingest ``source`` (:func:`_root`) into a folder holding another recording's ingest.

    Recordings land in ``OUT/<folder name>``: two recordings of one name
    (``a/rec`` and ``b/rec``, or ``rec.bag`` beside a folder ``rec``) would
    overwrite each other's pairs. An earlier source that no longer exists was
    moved (or removed): its ingest is this one's to resume (frames are known by
    their place, size and time, not their folder) or to replace.

    Raises:
        CaptureError: naming both recordings and what to do.
    """
    before = read_json_field(out_dir / REPORT_FILE, "source")
    if before is None:  # a run stopped while its report was set aside
        before = read_json_field(out_dir / STALE_REPORT, "source")
    if not isinstance(before, str) or not Path(before).is_absolute():
        return  # written before sources were absolute: cannot tell
    if Path(before) != source and os.path.lexists(before):
        raise CaptureError(
            f"{out_dir}: holds the ingest of {before}, and {source} has the same name; "
            f"ingest it into another --out, rename one of the recordings, or remove {out_dir} "
            "to ingest it again"
        )
