"""The frame stage of an ingest: every frame pair processed or resumed, ``pairs.jsonl`` written.

:func:`run_frame_stage` hands each frame pair to the per-frame work of
:mod:`lenspair.capture.ingest_frames` unless the journal
(:mod:`lenspair.capture.journal`) shows it finished with the same key and its
files intact, records the unpaired frames as rejected, removes outputs no
frame owns any more, compacts the journal and writes one ``pairs.jsonl`` line
per obstructed frame, in time order. :func:`map_tasks` is the process pool
both per-frame stages (the homography's feature samples and this one) run in.
"""

import logging
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from lenspair.capture import ingest_frames as frame_work
from lenspair.capture.ingest_report import unlisted_records
from lenspair.capture.ingested import PAIRS_FILE, PairRecord, write_pairs
from lenspair.capture.journal import (
    JOURNAL_FILE,
    fingerprint,
    journal_line,
    read_journal,
    redo_reasons,
    remove_stale_outputs,
    side_change,
    still_valid,
)
from lenspair.capture.pairing import PairingResult
from lenspair.capture.recording import FrameRef, Recording
from lenspair.capture.rigfile import RigFile
from lenspair.core.fsutil import atomic_write_text, naming_errors
from lenspair.core.progress import progress
from lenspair.core.workers import spawn_pool

log = logging.getLogger(__name__)


def map_tasks(
    function: Any, tasks: list[Any], workers: int, context: frame_work.Context, desc: str
) -> Iterator[Any]:
    """Run ``function`` over ``tasks`` in order, in a process pool when ``workers > 1``."""
    if workers <= 1 or len(tasks) <= 1:
        frame_work.set_context(context)
        yield from progress((function(t) for t in tasks), desc=desc, total=len(tasks), unit="pair")
        return
    # Ctrl-C, or a task's error: the pool stops handing out work and ends its workers
    with spawn_pool(workers, frame_work.init_worker, (context, os.getpid())) as pool_map:
        results = pool_map(function, tasks, chunksize=max(1, min(8, len(tasks) // (4 * workers))))
        yield from progress(results, desc=desc, total=len(tasks), unit="pair")


def run_frame_stage(
    recording: Recording,
    pairing: PairingResult,
    rig_file: RigFile,
    frame_pairs: list[tuple[FrameRef, FrameRef]],
    context: frame_work.Context,
    state: str,
    workers: int,
    settings: dict[str, Any],
) -> list[PairRecord]:
    """Process every pair not already done (journal), record unpaired frames; in time order.

    ``settings`` (what the outputs are made with, readable) goes in the journal,
    so that a rerun processing finished frames again names the setting that
    differs (:func:`lenspair.capture.journal.redo_reasons`).
    """
    out_dir = context.out_dir
    journal_path = out_dir / JOURNAL_FILE
    journal = read_journal(journal_path)
    records, tasks = _resume(recording, rig_file, frame_pairs, state, journal, settings, out_dir)
    made_with = fingerprint(settings)  # the settings themselves on a run's first line only
    keys = {t.obstructed.t_ns: t.key for t in tasks}
    keys.update({t: journal[t][0] for t in records})
    with journal_path.open("a", encoding="utf-8") as handle:
        results = map_tasks(frame_work.process, tasks, workers, context, "pairs")
        for index, (task, record) in enumerate(zip(tasks, results, strict=True)):
            records[record.t_ns] = record
            line = journal_line(task.key, record, made_with, None if index else settings)
            with naming_errors(journal_path):  # a full disk: the journal named, not the frames
                handle.write(line)
                handle.flush()  # a crash loses at most the frames in flight
    for unpaired in pairing.unpaired_of(rig_file.obstructed):
        frame = recording.frames[rig_file.obstructed][unpaired.index]
        records[frame.t_ns] = PairRecord(t_ns=frame.t_ns, status="rejected", reason=unpaired.reason)
    ordered = [records[t] for t in sorted(records)]
    every_frame = {frame.t_ns for frames in recording.frames.values() for frame in frames}
    # and the frames it could not list, or no longer lists (a file deleted since an
    # earlier run; without data.csv that leaves no problem, only the journal knows it)
    every_frame |= {p.t_ns for p in recording.problems if p.t_ns is not None}
    every_frame |= set(journal)
    remove_stale_outputs(out_dir, ordered, every_frame)
    # the frames kept from the journal have this run's key: made as this run makes them
    journaled = [r for r in ordered if r.t_ns in keys]
    lines = (
        journal_line(keys[r.t_ns], r, made_with, None if index else settings)
        for index, r in enumerate(journaled)
    )
    atomic_write_text(journal_path, "".join(lines))  # compacted: one line per frame
    # One line per obstructed frame, also for those the recording could not list
    # (a second file with an earlier frame's timestamp, a missing file): rejected.
    ordered = sorted(ordered + unlisted_records(recording, rig_file.obstructed), key=_time)
    write_pairs(out_dir / PAIRS_FILE, ordered)
    return ordered


def _resume(
    recording: Recording,
    rig_file: RigFile,
    frame_pairs: list[tuple[FrameRef, FrameRef]],
    state: str,
    journal: dict[int, tuple[str, PairRecord]],
    settings: dict[str, Any],
    out_dir: Path,
) -> tuple[dict[int, PairRecord], list[frame_work.FrameTask]]:
    """The records of frames the journal shows finished, and the tasks of all others.

    A frame is finished when its journal key is this run's and its files
    still have the recorded checksums. Finished frames processed again because
    their key changed (another calibration, side or thresholds) are said in
    the log, with the setting that differs.

    Returns:
        ``(records by t_ns, tasks to run)``.
    """
    warnings = {  # the reason alone: the record names its frame, and the path as typed
        p.t_ns: p.reason  # must not change a finished frame's key (a resume from elsewhere)
        for p in recording.problems
        if not p.dropped and p.camera == rig_file.obstructed and p.t_ns is not None
    }
    records: dict[int, PairRecord] = {}
    tasks = []
    redone = []
    # a rerun checks every finished pair's files by SHA-256 before the pairs bar: tens of GB
    # of a long recording, read without a word
    listed: Iterable[tuple[FrameRef, FrameRef]] = frame_pairs
    if journal:
        listed = progress(frame_pairs, desc="checking finished pairs", unit="pair")
    for obstructed_frame, clean_frame in listed:
        task = frame_work.FrameTask(
            obstructed_frame, clean_frame, state, warnings.get(obstructed_frame.t_ns)
        )
        done = journal.get(obstructed_frame.t_ns)
        if done and done[0] == task.key and still_valid(out_dir, done[1]):
            records[obstructed_frame.t_ns] = done[1]
        else:
            if done is not None and done[0] != task.key:
                redone.append(obstructed_frame.t_ns)
            tasks.append(task)
    if redone:  # a rerun with another calibration, side or thresholds replaces them: said
        log.warning(
            "%s: %d finished frames are processed again: %s",
            out_dir,
            len(redone),
            redo_reasons(out_dir / JOURNAL_FILE, redone, settings),
        )
    current = {obstructed_frame.t_ns for obstructed_frame, _ in frame_pairs}
    gone = [t_ns for t_ns in journal if t_ns not in current]
    if gone and (side := side_change(out_dir / JOURNAL_FILE, gone, settings)):
        log.warning("%s: %d finished frames are replaced: %s", out_dir, len(gone), side)
    return records, tasks


def _time(record: PairRecord) -> int:
    return record.t_ns
