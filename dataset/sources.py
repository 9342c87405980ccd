"""Ingested recordings as a dataset build reads them, and the measuring of their pairs.

:func:`load_source` reads a ``capture-ingest`` folder (its ``report.json`` and
``pairs.jsonl``) into a :class:`Source`; :func:`measure_record` reads, checks
and measures the images of one of its lines for curation. A problem with a
pair's files removes that pair (counted under its rule), it is never raised.
"""

import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from lenspair.capture.ingested import (
    PAIRS_FILE,
    REPORT_FILE,
    IngestReport,
    PairRecord,
    read_numbered_pairs,
    read_report,
)
from lenspair.capture.journal import JOURNAL_FILE, LOCK_FILE
from lenspair.core.errors import ImageIOError, listed
from lenspair.core.folderlock import lock_shared
from lenspair.core.fsutil import sha256_bytes
from lenspair.core.imageio import read_image
from lenspair.dataset import curation
from lenspair.dataset.curation import Measured
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.layouts import Layout, detect_layout, is_lenspair_dataset
from lenspair.dataset.stats_cache import StatsCache

_PAIRED_AS_IS = (
    "train, eval and tradeoff read it as it is; dataset-build takes recordings ingested by "
    "capture-ingest"
)
_ALREADY_PAIRED: dict[Layout, str] = {
    "lenspair": f"already a split of a dataset built by dataset-build: {_PAIRED_AS_IS}",
    "paired": f"already a paired folder (input/ + target/ or lq/ + gt/): {_PAIRED_AS_IS}",
    "raindrop": f"already a paired folder (Raindrop data/ + gt/): {_PAIRED_AS_IS}",
}
"""What :func:`load_source` says of a folder :func:`detect_layout` recognises, by layout."""
_A_DATASET = (
    "a dataset built by dataset-build, not an ingested recording: leave it out of the sources "
    "(a glob over the recordings' folder catches a dataset built in it: build into another "
    "folder); train, eval and tradeoff read it as it is"
)


@dataclass(frozen=True)
class Source:
    """One ingested recording, as read from disk.

    Attributes:
        path: the ingested folder (absolute).
        report: its ``report.json``.
        records: its ``pairs.jsonl`` lines, in file order.
        lines: the line number in ``pairs.jsonl`` of each record (blank lines
            counted), for messages; empty: ``index + 1``.
    """

    path: Path
    report: IngestReport
    records: tuple[PairRecord, ...]
    lines: tuple[int, ...] = ()

    def line(self, index: int) -> int:
        """Line number in ``pairs.jsonl`` of record ``index``."""
        return self.lines[index] if self.lines else index + 1

    @property
    def clean(self) -> str:
        """The ground-truth camera (the one that is not obstructed)."""
        return "cam0" if self.report.obstructed == "cam1" else "cam1"


def _ingested_inside(path: Path) -> list[str]:
    """Names of the ingested recordings directly inside ``path`` (capture-ingest's ``--out``)."""
    try:
        children = sorted(path.iterdir())
    except OSError:
        return []
    return [child.name for child in children if (child / PAIRS_FILE).is_file()]


def load_source(path: Path) -> Source:
    """Read an ingested recording's ``report.json`` and ``pairs.jsonl``.

    Raises:
        DatasetError: the folder or one of the two files is missing (a
            folder of pairs already, which train reads as it is, said so), the
            obstructed camera or recording id is invalid, or a timestamp
            repeats; the message names the file.
        ConfigError: a malformed line or key (names the file and line).
    """
    path = Path(path).resolve()
    if not path.is_dir():
        raise DatasetError(f"{path}: not a folder (expected an ingested recording)")
    if (said := _not_a_recording(path)) is not None:
        raise DatasetError(f"{path}: {said}")
    for name in (PAIRS_FILE, REPORT_FILE):
        if not (path / name).is_file():
            if recordings := _ingested_inside(path):
                raise DatasetError(
                    f"{path}: holds ingested recordings ({listed(recordings, 3, ', ')}), not "
                    f"one: give those as sources, e.g. {path}/*"
                )
            raise DatasetError(
                f"{path}: missing {name} (not an ingested recording, or capture-ingest was "
                "stopped before it finished: run it again)"
            )
    report = read_report(path / REPORT_FILE)
    if report.obstructed not in ("cam0", "cam1"):
        raise DatasetError(
            f"{path / REPORT_FILE}: obstructed must be cam0 or cam1, got {report.obstructed!r}"
        )
    rid = report.recording_id
    if not rid or rid.startswith(".") or any(c in rid for c in "/\\\0"):
        raise DatasetError(f"{path / REPORT_FILE}: recording_id {rid!r} is not a file name")
    numbered = read_numbered_pairs(path / PAIRS_FILE)
    records = tuple(record for _, record in numbered)
    seen: set[int] = set()
    for number, record in numbered:  # the file's own line numbers, blank lines counted
        if record.status != "kept":
            continue  # a rejected frame may repeat a kept one's timestamp (another file)
        if record.t_ns in seen:
            raise DatasetError(f"{path / PAIRS_FILE}:{number}: timestamp {record.t_ns} repeats")
        seen.add(record.t_ns)
    return Source(path, report, records, tuple(number for number, _ in numbered))


def _not_a_recording(path: Path) -> str | None:
    """What a folder with no trace of ``capture-ingest`` is instead, or None.

    A dataset root (``dataset-build --out``, caught by a glob such as
    ``ingested/*``) or a folder of pairs (:func:`detect_layout`): both were
    told that they lacked ``pairs.jsonl`` and to run capture-ingest again. An
    ingested recording holds ``input/`` + ``target/`` too; one whose ingest
    was stopped before it finished still holds its lock or journal, and is
    told to run it again.
    """
    traces = (PAIRS_FILE, REPORT_FILE, JOURNAL_FILE, LOCK_FILE)
    if any((path / name).exists() for name in traces):
        return None
    if is_lenspair_dataset(path):
        return _A_DATASET
    layout = detect_layout(path)
    return None if layout is None else _ALREADY_PAIRED[layout]


def measure_record(
    source: Source,
    position: int,
    index: int,
    anomaly_delta: float,
    cache: StatsCache | None = None,
) -> Measured:
    """Read, check and measure the images of line ``index`` of ``source``.

    A problem with the pair's files removes the pair (rules ``missing_file``,
    ``checksum``, ``bad_image``); it is not raised. A ``files`` entry that
    points outside the recording folder is a ``bad_image``, its reason naming
    the ``pairs.jsonl`` line: a dataset must not copy files it was not given.

    Args:
        source: the recording.
        position: its index in the list of sources.
        index: line index in ``pairs.jsonl``.
        anomaly_delta: see :class:`lenspair.dataset.config.CurationConfig`.
        cache: figures measured before, by the files' checksums
            (:mod:`lenspair.dataset.stats_cache`): a pair found there is not
            decoded again; one measured here is added.
    """
    record = source.records[index]
    files = _source_files(source.path, record)
    base = Measured(position, index, record, files, {})
    if record.status == "rejected":
        return _removed(base, "ingest_rejected", record.reason or "unspecified")
    for kind, relative in sorted(record.files.items()):
        if _escapes(relative):
            reason = (
                f"{source.path / PAIRS_FILE}:{source.line(index)}: files.{kind} {relative!r} "
                "points outside the recording folder"
            )
            return _removed(base, "bad_image", reason)
    hashes: dict[str, str] = {}
    before: dict[str, tuple[int, ...]] = {}
    for kind, file in files.items():
        try:
            before[kind] = _identity(file)
            hashes[kind] = sha256_bytes(file.read_bytes())
        except FileNotFoundError:
            return _removed(base, "missing_file", f"{file}: file missing (named in {PAIRS_FILE})")
        except OSError as exc:  # a folder in its place, no permission, a failing disk
            why = exc.strerror or type(exc).__name__
            return _removed(base, "bad_image", f"{file}: cannot be read ({why})")
        except ValueError as exc:  # a NUL in the name pairs.jsonl gives
            where = f"{source.path / PAIRS_FILE}:{source.line(index)}"
            return _removed(base, "bad_image", f"{where}: files.{kind}: not a file name ({exc})")
        expected = record.sha256.get(kind)
        if expected is not None and expected != hashes[kind]:
            found = hashes[kind][:12]
            reason = f"{file}: sha256 {found}... differs from {PAIRS_FILE} ({expected[:12]}...)"
            return _removed(base, "checksum", reason)
    if files["input"].suffix != files["target"].suffix:
        return _removed(base, "bad_image", f"{files['input']}: input and target file types differ")
    key = "" if cache is None else cache.key(hashes, anomaly_delta)
    if cache is not None and (kept := cache.get(key)) is not None:
        return Measured(position, index, record, files, hashes, kept)
    try:
        images = {kind: read_image(file) for kind, file in files.items()}
        stats = curation.measure_pair(
            images["input"], images["target"], images.get("mask"), anomaly_delta
        )
    except ImageIOError as exc:
        return _removed(base, "bad_image", str(exc))
    except ValueError as exc:
        return _removed(base, "bad_image", f"{files['input']}: {exc}")
    if cache is not None and _unchanged(files, before):
        # a file replaced between hashing and decoding (a re-ingest meanwhile) would keep
        # the new pixels' figures under the old bytes' key, for every later build
        cache.put(key, stats)
    return Measured(position, index, record, files, hashes, stats)


def _unchanged(files: dict[str, Path], before: dict[str, tuple[int, ...]]) -> bool:
    """Whether every file is still the one whose identity ``before`` holds."""
    try:
        return all(_identity(files[kind]) == identity for kind, identity in before.items())
    except OSError:  # gone meanwhile
        return False


def _identity(file: Path) -> tuple[int, ...]:
    """What changes when a file is rewritten or replaced: inode, size, modification time."""
    status = file.stat()
    return status.st_ino, status.st_size, status.st_mtime_ns


def _source_files(folder: Path, record: PairRecord) -> dict[str, Path]:
    """Image paths of a line: from its ``files``, else the default layout."""
    files = {
        kind: folder / record.files.get(kind, f"{kind}/{record.t_ns}.png")
        for kind in ("input", "target")
    }
    default_mask = folder / "mask" / f"{record.t_ns}.png"
    if "mask" in record.files:
        files["mask"] = folder / record.files["mask"]
    elif not record.files and default_mask.is_file():
        files["mask"] = default_mask
    return files


def _escapes(relative: str) -> bool:
    """True when a ``files`` entry of ``pairs.jsonl`` names a path outside its folder."""
    normal = os.path.normpath(relative)
    return os.path.isabs(normal) or normal == os.pardir or normal.startswith(os.pardir + os.sep)


def _removed(measured: Measured, rule: str, reason: str) -> Measured:
    m = measured
    return Measured(m.source, m.index, m.record, m.files, {}, None, rule, reason)


@contextmanager
def reading_sources(paths: Iterable[Path]) -> Iterator[None]:
    """Hold a shared lock on each ingested folder meanwhile; refuse one a capture-ingest writes.

    A capture-ingest rerun (another ``--size``) writing a recording while it
    was built from gave a dataset of its new images under a manifest of the
    old ones' hashes, with exit 0. The lock is the one ``capture-ingest``
    holds (:data:`~lenspair.capture.journal.LOCK_FILE`), taken shared: builds
    read side by side, and a capture-ingest started meanwhile is refused.

    Raises:
        DatasetError: a capture-ingest is writing one of them (names it).
    """
    descriptors: list[int] = []
    try:
        for path in paths:
            if not Path(path).is_dir():  # load_source says what it is
                continue
            try:
                descriptor = lock_shared(Path(path) / LOCK_FILE)
            except BlockingIOError:
                raise DatasetError(
                    f"{path}: a capture-ingest is writing it; build when it has finished"
                ) from None
            if descriptor is not None:
                descriptors.append(descriptor)
        yield
    finally:
        for descriptor in descriptors:
            os.close(descriptor)  # releases the lock
