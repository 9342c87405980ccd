"""Ingesting a recording: registered (obstructed, clean) pairs, cropped, verified, on disk.

:func:`ingest_recording` is the library entry point of ``lenspair capture-ingest``.
It writes the ingested-recording layout of :mod:`lenspair.capture.ingested` under
``OUT/<recording_id>/``:

1. list both cameras (:mod:`lenspair.capture.recording`), pair them by timestamp
   (:mod:`lenspair.capture.pairing`): every frame ends up paired or unpaired;
2. load the calibration (:mod:`lenspair.capture.calibration_source`: ``--calib``, else
   ``rig.yaml``'s ``calibration``, else ``camchain.yaml`` beside the
   recording) and rectify (once);
3. estimate the clean -> obstructed homography from features pooled over up
   to 30 frames (:func:`lenspair.rectify.registration.estimate_homography`), cached in
   ``registration.json`` with a fingerprint of what it was computed from;
4. choose the crop (:func:`lenspair.rectify.crop.choose_crop`) and compose one map per
   view (:mod:`lenspair.rectify.remap`);
5. check the declared obstructed side against the images
   (:func:`lenspair.capture.side_check.check_obstructed_side`);
6. per frame (:mod:`lenspair.capture.ingest_frames`, in a process pool with ``workers > 1``):
   remap, verify, refine, write ``input/``, ``target/``, ``mask/``;
7. write ``pairs.jsonl``, ``report.json`` (:mod:`lenspair.capture.ingest_report`) and ``qa.png``.

Resuming (:mod:`lenspair.capture.journal`): each finished frame is appended to
``.journal.jsonl`` with a key that hashes everything its outputs depend on;
a rerun skips frames whose key matches and whose files still have the
recorded checksums, so an interrupted run (even ``kill -9``) finishes the
work and a full rerun leaves every file byte-identical (``report.json`` is
only rewritten when something other than its timings changed). One run at a
time writes ``OUT/<recording_id>``: from before its first write to its end a
run holds the folder's lock (:func:`lenspair.capture.journal.hold_output`), and
a second run is refused at once.
"""

import contextlib
import json
import logging
import os
import shutil
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from lenspair import __version__
from lenspair.capture import ingest_frames as frame_work
from lenspair.capture.calibration_source import find_calibration
from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest_report import (
    STALE_REPORT,
    frame_counts,
    in_output_pixels,
    rejection_reasons,
    set_report_aside,
    unlisted_records,
    untimed_frames,
    write_report_if_changed,
)
from lenspair.capture.ingested import PAIRS_FILE, REPORT_FILE, IngestReport, PairRecord, write_pairs
from lenspair.capture.journal import (
    JOURNAL_FILE,
    fingerprint,
    hold_output,
    journal_line,
    read_journal,
    redo_reasons,
    remove_stale_outputs,
    remove_temporaries,
    still_valid,
)
from lenspair.capture.pairing import (
    PairingResult,
    check_frame_period,
    clock_offset_warning,
    estimate_period_ns,
    pair_frames,
)
from lenspair.capture.qa import QA_FILE, write_qa_sheet
from lenspair.capture.recording import (
    FrameRef,
    Recording,
    load_frame,
    open_recording,
    resolve_obstructed,
)
from lenspair.capture.rigfile import CameraName, RigFile
from lenspair.capture.side_check import check_obstructed_side
from lenspair.capture.side_detector import ObstructedProbability, check_side_with_detector
from lenspair.core.bitdepth import significant_bits, widen
from lenspair.core.config import to_plain
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import (
    atomic_write_json,
    atomic_write_text,
    naming_errors,
    read_json_field,
)
from lenspair.core.progress import progress
from lenspair.core.quality import is_blank
from lenspair.rectify.crop import choose_crop
from lenspair.rectify.errors import CropError, RectifyError
from lenspair.rectify.rectification import StereoRectification
from lenspair.rectify.registration import (
    EstimationParams,
    VerifyParams,
    estimate_homography,
    implausible_turn,
)
from lenspair.rectify.remap import target_map, valid_region
from lenspair.rectify.rig import StereoRig, rig_to_kalibr

log = logging.getLogger(__name__)

REGISTRATION_FILE = "registration.json"
SIDE_CHECK_FRAMES = 8
BIT_DEPTH_FRAMES = 32  # frame pairs read to tell the bits 16-bit frames use (~0.3 s)
MAX_LOGGED_PROBLEMS = 10
MIN_INLIER_SHARE = 0.5
"""Below this share of feature matches agreeing with the homography, registration is doubted.

Scenes registered right: 78-91 % (the sample rain, heavy rain, dust and
parallax recordings); a far wall of a perfect checkerboard registered one
period off: 32 %.
"""
SINGLE_FRAME_TOLERANCE_NS = 10_000_000
"""Pairing tolerance when the frame period cannot be estimated (one frame per camera)."""


def _sample(count: int, limit: int) -> list[int]:
    """Up to ``limit`` indices spread evenly over ``range(count)``."""
    if count <= limit:
        return list(range(count))
    return sorted({round(i * (count - 1) / (limit - 1)) for i in range(limit)})


def _map_tasks(
    function: Any, tasks: list[Any], workers: int, context: frame_work.Context, desc: str
) -> Iterator[Any]:
    """Run ``function`` over ``tasks`` in order, in a process pool when ``workers > 1``."""
    if workers <= 1 or len(tasks) <= 1:
        frame_work.set_context(context)
        yield from progress((function(t) for t in tasks), desc=desc, total=len(tasks))
        return
    with ProcessPoolExecutor(
        max_workers=workers,
        mp_context=get_context("spawn"),
        initializer=frame_work.init_worker,
        initargs=(context, os.getpid()),
    ) as pool:
        results = pool.map(function, tasks, chunksize=max(1, min(8, len(tasks) // (4 * workers))))
        try:
            yield from progress(results, desc=desc, total=len(tasks))
        except BaseException:  # Ctrl-C, or a task's error: stop handing out work, now
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _side_check_images(
    pairs: list[tuple[FrameRef, FrameRef]], context: frame_work.Context, count: int
) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """Raw cam0 and cam1 images of the first ``count`` readable pairs among ``pairs``.

    A pair with a blank view (:func:`lenspair.core.quality.is_blank`: lens cap,
    exposure fault) is left out: it says nothing about the glass, and a black
    frame has less detail than any other. The third value counts those pairs.
    """
    images: dict[str, list[np.ndarray]] = {"cam0": [], "cam1": []}
    blank = 0
    for pair in pairs:
        if len(images["cam0"]) == count:
            break
        try:
            loaded = [widen(load_frame(frame), context.bits) for frame in pair]
        except LenspairError:
            continue
        sizes = [(image.shape[1], image.shape[0]) for image in loaded]
        if sizes != [context.raw_size(frame.camera) for frame in pair]:
            continue
        if any(is_blank(image) for image in loaded):
            blank += 1
            continue
        for frame, image in zip(pair, loaded, strict=True):
            images[frame.camera].append(image)
    return images["cam0"], images["cam1"], blank


SampledPair = list[tuple[FrameRef, np.ndarray]]
"""The readable frames of one sampled frame pair, obstructed first, each with its raw image."""


def _sampled_pairs(pairs: list[tuple[FrameRef, FrameRef]]) -> list[SampledPair]:
    """The readable frames of up to 32 frame pairs spread over the recording, read as stored.

    Unreadable frames are passed over: the frame stage reports them.
    """
    sampled = []
    for index in _sample(len(pairs), BIT_DEPTH_FRAMES):
        loaded = []
        for frame in pairs[index]:
            with contextlib.suppress(LenspairError):
                loaded.append((frame, load_frame(frame)))
        sampled.append(loaded)
    return sampled


def _recording_bits(recording: Recording, sampled: list[SampledPair]) -> int:
    """:func:`significant_bits` of the sampled frame pairs (:func:`_sampled_pairs`).

    A recording that uses fewer than 16 bits is said in the log. A frame the
    sample missed that holds more is rejected with that reason, not clipped.
    """
    images = [image for pair in sampled for _, image in pair]
    bits = significant_bits(images)
    if bits < 16:
        log.warning(
            "%s: its 16-bit frames hold %d-bit values (none above %d in %d sampled frames): "
            "they are scaled to the full 16-bit range",
            recording.path,
            bits,
            (1 << bits) - 1,
            len(images),
        )
    return bits


def _size_mismatch(sampled: list[SampledPair], rig: StereoRig) -> str | None:
    """The first size mismatch when no sampled pair has the calibration's image sizes, else None.

    Checked before the calibration is used: rectifying with a calibration
    stated for another size can fail first, with a message about the
    calibration's edges (1280x720 stated for 720x540 frames) instead of the
    sizes. The rule is the registration stage's: a pair of other sizes among
    usable ones is only rejected, with its reason, by the frame stage; when no
    pair whose two frames are readable has both sizes right, nothing can be
    registered. A sample without a readable pair is left to the registration
    stage, which says why.

    Returns:
        ``size mismatch: <frame> is WxH px, the calibration says WxH`` (the
        registration stage's words), or None.
    """
    first = None
    for pair in sampled:
        if len(pair) < 2:
            continue
        problems = [
            frame_work.size_problem(image, frame, rig.camera(frame.camera).resolution)
            for frame, image in pair
        ]
        mismatch = next((p for p in problems if p is not None), None)
        if mismatch is None:
            return None
        first = first or mismatch
    return first


def _cached_registration(cache: Path, key: str) -> dict[str, Any] | None:
    """The registration ``cache`` holds when it was computed from ``key``'s inputs, else None.

    A file that is not a registration record (not JSON, not an object, a
    field missing or of another kind: damaged, or edited) is said in the log
    and computed again; one of other inputs (its fingerprint differs) is
    simply computed again.
    """
    try:
        cached = json.loads(cache.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        log.warning("%s: cannot be read (%s); computing the registration again", cache, exc)
        return None
    if isinstance(cached, dict) and cached.get("fingerprint") != key:
        return None
    problem = _registration_problem(cached)
    if problem is not None:
        log.warning("%s: %s; computing the registration again", cache, problem)
        return None
    return dict(cached)


def _registration_problem(cached: Any) -> str | None:
    """What makes ``cached`` (parsed JSON) not a registration record, or None."""
    if not isinstance(cached, dict):
        kinds = {list: "a list", str: "a string", bool: "true or false", type(None): "null"}
        kind = kinds.get(type(cached), "a number")
        return f"holds {kind}, not a registration record (a JSON object)"

    def number(value: Any) -> bool:
        return isinstance(value, int | float) and not isinstance(value, bool)

    def count(value: Any) -> bool:
        return number(value) and isinstance(value, int) and value >= 0

    rows = cached.get("matrix")
    if not (
        isinstance(rows, list)
        and len(rows) == 3
        and all(isinstance(row, list) and len(row) == 3 and all(map(number, row)) for row in rows)
        and np.isfinite(np.asarray(rows, dtype=np.float64)).all()
    ):
        return "its 'matrix' is not a 3x3 matrix of numbers"
    for name in ("inliers", "matches"):
        if not count(cached.get(name)):
            return f"its {name!r} is not a count"
    frames = cached.get("frames")
    if not isinstance(frames, dict) or not all(count(n) for n in frames.values()):
        return "its 'frames' is not a table of counts"
    return None


def _homography(
    recording: Recording,
    pairs: list[tuple[FrameRef, FrameRef]],
    context: frame_work.Context,
    estimation: EstimationParams,
    workers: int,
    out_dir: Path,
    setup: dict[str, Any],
) -> dict[str, Any]:
    """The recording's homography, from the cache when its fingerprint matches.

    The fingerprint hashes the setup (calibration, side, thresholds,
    version) and the content of the sampled frames, so a rerun reuses the
    exact same matrix and a changed input recomputes it.

    Returns:
        The registration record, as written to ``registration.json``.

    """
    chosen = [pairs[i] for i in _sample(len(pairs), estimation.max_frames)]
    contents = [(frame_work.content_id(o), frame_work.content_id(c)) for o, c in chosen]
    identity = [[o.t_ns, *content] for (o, _), content in zip(chosen, contents, strict=True)]
    if chosen and all(o == c and not o.startswith("unreadable") for o, c in contents):
        # two cameras never take the same bytes: one camera's images stored twice
        log.warning(
            "%s: the two cameras' files are byte for byte the same in all %d pairs sampled: "
            "one camera's images recorded twice (a driver or topic mix-up)? The pairs show no "
            "anomaly to learn",
            recording.path,
            len(chosen),
        )
    cache_key = fingerprint(
        {"setup": setup, "estimation": to_plain(estimation), "frames": identity}
    )
    cache = out_dir / REGISTRATION_FILE
    cached = _cached_registration(cache, cache_key)
    if cached is not None:
        return cached
    tasks = [frame_work.SampleTask(o, c, estimation) for o, c in chosen]
    samples = list(_map_tasks(frame_work.sample, tasks, workers, context, "features"))
    usable = [s for s in samples if s.problem is None]
    if not usable:
        first = samples[0].problem if samples else "no frame of the two cameras could be paired"
        raise CaptureError(f"{recording.path}: no usable frame pair to register: {first}")
    scale = np.float32(1.0 / 255.0)
    views = [
        (s.obstructed * scale, s.clean * scale, context.valid_obstructed, context.valid_clean)
        for s in usable
    ]
    estimate = estimate_homography(views, estimation, context.verify, [s.matches for s in usable])
    registration = {
        "fingerprint": cache_key,
        "matrix": estimate.matrix.tolist(),
        "inliers": estimate.inliers,
        "matches": estimate.matches,
        "rms_px": estimate.rms_px,
        "frames": {str(s.t_ns): n for s, n in zip(usable, estimate.inliers_per_frame, strict=True)},
    }
    atomic_write_json(cache, registration)
    return registration


def _frame_stage(
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
    warnings = {  # the reason alone: the record names its frame, and the path as typed
        p.t_ns: p.reason  # must not change a finished frame's key (a resume from elsewhere)
        for p in recording.problems
        if not p.dropped and p.camera == rig_file.obstructed and p.t_ns is not None
    }
    journal_path = out_dir / JOURNAL_FILE
    journal = read_journal(journal_path)
    records: dict[int, PairRecord] = {}
    tasks = []
    redone = []
    for obstructed_frame, clean_frame in frame_pairs:
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
            redo_reasons(journal_path, redone, settings),
        )
    made_with = fingerprint(settings)  # the settings themselves on a run's first line only
    keys = {t.obstructed.t_ns: t.key for t in tasks}
    keys.update({t: journal[t][0] for t in records})
    with journal_path.open("a", encoding="utf-8") as handle:
        results = _map_tasks(frame_work.process, tasks, workers, context, "pairs")
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


def _time(record: PairRecord) -> int:
    return record.t_ns


def _root(recording: Recording) -> Path:
    """The recording's own folder or file, absolute: ``rec`` for ``rec`` and ``rec/mav0``."""
    path = Path(recording.path).resolve()
    if path.name != recording.recording_id and path.parent.name == recording.recording_id:
        return path.parent
    return path


def _topics_reversed(recording: Recording, rig: StereoRig) -> bool:
    """A bag read with cam0's and cam1's topics the other way round from the calibration's.

    A Kalibr camchain names each camera's ``rostopic``. Reading the two topics
    swapped would rectify each camera's frames with the other's calibration
    and make the clean camera's frames the input, without any error. Topics
    the calibration does not state (the conventional ``/cam0/image_raw`` and
    ``/cam1/image_raw`` it is read with) decide nothing.
    """
    read = recording.topics
    reversed_ = read is not None and read != rig.topics and read == rig.topics[::-1]
    return rig.topics_stated and reversed_


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


def ingest_recording(
    recording_path: Path,
    out: Path,
    *,
    calibration: tuple[Path, ...] = (),
    obstructed: str | None = None,
    topics: tuple[str, str] | None = None,
    size: tuple[int, int] = (540, 360),
    workers: int = 1,
    estimation: EstimationParams | None = None,
    verify: VerifyParams | None = None,
    side_detector: ObstructedProbability | None = None,
    time_offset_ns: int = 0,
) -> IngestReport:
    """Turn one stereo recording into registered, verified pairs under ``out/<recording_id>/``.

    Args:
        recording_path: EuRoC/ASL folder, bag, or left/right folders.
        out: output root; the recording goes to ``out/<recording_id>/``.
        calibration: calibration files (``--calib``); empty: rig.yaml / camchain.yaml.
        obstructed: ``cam0``/``cam1`` overriding ``rig.yaml``.
        topics: bag topics ``(cam0, cam1)``; None picks them.
        size: crop ``(width, height)``, pixels.
        workers: processes for the per-frame work (1: in this process).
        estimation: homography estimation thresholds.
        verify: per-frame verification thresholds (see :mod:`lenspair.rectify.registration`).
        side_detector: a trained detector as a function (``--detector``); when
            given, the side check uses it (:mod:`lenspair.capture.side_detector`)
            instead of the detail ratio.
        time_offset_ns: how far cam1's clock runs ahead of cam0's: cam1's
            stamps less this are paired with cam0's (``--time-offset``); the
            pairs keep the recorded stamps, and report.json the offset.

    Returns:
        The report also written to ``report.json``.

    Raises:
        CaptureError: unreadable recording, no calibration, or no usable pair
            at all (``pairs.jsonl`` and ``report.json`` are still written);
            another run writing ``out/<recording_id>`` now (nothing written).
        RectifyError: bad calibration, registration impossible, crop too large
            (named with the recording and the calibration; nothing can be
            paired, so nothing is written, and an ``OUT/<recording_id>`` this
            run made is removed). A ``CaptureError`` because no sampled pair
            can be registered (sizes unlike the calibration's, undecodable
            frames) is treated the same way.

    """
    estimation = estimation or EstimationParams()
    verify = verify or VerifyParams()
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = round(now - clock, 3)
        clock = now

    start = clock
    recording = open_recording(Path(recording_path), topics)
    rig_file = resolve_obstructed(recording.path, obstructed)
    clean: CameraName = rig_file.clean
    rig, calibration_source = find_calibration(recording, rig_file, tuple(calibration))
    if _topics_reversed(recording, rig):
        if topics is not None:
            raise CaptureError(
                f"{recording.path}: --topics {topics[0]} {topics[1]} gives cam0 and cam1 the "
                f"other way round from the calibration ({calibration_source}: cam0 "
                f"{rig.topics[0]}, cam1 {rig.topics[1]}); the frames would be rectified with "
                "the other camera's calibration and the obstructed and clean sides swapped: "
                "pass --topics in cam0, cam1 order, or fix the calibration's rostopic"
            )
        recording = recording.swapped()  # the calibration's order
    for problem in recording.problems[:MAX_LOGGED_PROBLEMS]:
        log.warning("%s", problem)
    if len(recording.problems) > MAX_LOGGED_PROBLEMS:
        more = len(recording.problems) - MAX_LOGGED_PROBLEMS
        log.warning("%s: %d more problems (counted in report.json)", recording.path, more)
    stamps0, stamps1 = recording.timestamps("cam0"), recording.timestamps("cam1")
    period = estimate_period_ns(stamps0, stamps1)
    check_frame_period(period, recording.path)
    shifted1 = [t - time_offset_ns for t in stamps1]  # on cam0's clock
    pairing = pair_frames(stamps0, shifted1, None if period else SINGLE_FRAME_TOLERANCE_NS)
    said_of_recording = [str(p) for p in recording.problems if p.camera is None]
    # pairs.jsonl names frames by time: one without a time is named here, with its file
    said_of_recording += untimed_frames(recording, rig_file.obstructed)
    if offset := clock_offset_warning(pairing.pairs, period):
        log.warning("%s: %s", recording.path, offset)
        said_of_recording.append(offset)  # report.json keeps it
    frame_pairs = []  # (obstructed frame, clean frame)
    for pair in pairing.pairs:
        both = (recording.frames["cam0"][pair.index0], recording.frames["cam1"][pair.index1])
        frame_pairs.append(both if rig_file.obstructed == "cam0" else (both[1], both[0]))
    out_dir = Path(out) / recording.recording_id
    source = _root(recording)
    if out_dir.resolve() == source:  # --out = the recording's parent folder
        raise CaptureError(
            f"--out {out}: the recording goes to {out_dir}, which is the recording "
            f"{source} itself; the ingest writes input/ and target/ there and removes "
            "files it did not write, so choose another --out"
        )
    _check_same_source(out_dir, source)
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    with hold_output(out_dir):  # the whole run: one run at a time writes out_dir
        remove_temporaries(out_dir)
        lap("open")

        sampled = _sampled_pairs(frame_pairs)
        bits = _recording_bits(recording, sampled)
        mismatch = _size_mismatch(sampled, rig)
        del sampled  # up to 64 frames, not needed from here on
        try:
            if mismatch is not None:  # before the calibration is used (_size_mismatch)
                raise CaptureError(
                    f"{recording.path}: no usable frame pair to register: {mismatch}"
                )
            rectification = StereoRectification.from_rig(rig)
            context = frame_work.Context.build(
                out_dir, rig_file.obstructed, rectification, verify, bits
            )
            setup = {
                "calibration": rig_to_kalibr(rig),
                "obstructed": rig_file.obstructed,
                "verify": to_plain(verify),
                "version": __version__,
            }
            if bits < 16:  # only then: the outputs of other recordings keep their fingerprint
                setup["significant_bits"] = bits
            registration = _homography(
                recording, frame_pairs, context, estimation, workers, out_dir, setup
            )
        except (RectifyError, CaptureError) as exc:
            # the views cannot be registered at all (no sampled pair is usable): no pair to write
            if created:  # an empty OUT/<rec> would stop `dataset-build OUT/*` (no pairs.jsonl)
                shutil.rmtree(out_dir, ignore_errors=True)
            message = str(exc).removeprefix(f"{recording.path}: ")
            # the calibration is named: registration that fails everywhere is
            # as often a wrong or stale calibration as a scene that cannot be registered
            earlier = _earlier(out_dir, created)
            raise type(exc)(
                f"{recording.path}: {message} (with {calibration_source}){earlier}"
            ) from None
        lap("homography")
        share = registration["inliers"] / max(int(registration["matches"]), 1)
        if share < MIN_INLIER_SHARE:
            log.warning(
                "%s: only %.0f%% of the %d feature matches agree with the homography: a "
                "repetitive scene (a checkerboard, a fence, tiles) can register a whole period "
                "off, which the per-frame checks cannot see; look at %s",
                recording.path,
                100 * share,
                registration["matches"],
                out_dir / QA_FILE,
            )

        matrix = np.asarray(registration["matrix"], dtype=np.float64)
        if (turned := implausible_turn(matrix)) is not None:
            log.warning(
                "%s: the homography from the clean to the obstructed view %s, where rectified "
                "views of one rig differ by a shift: the calibration (%s) is likely not this "
                "rig's (another rig's, or a camera remounted since); check it, or calibrate again",
                recording.path,
                turned,
                calibration_source,
            )
        valid = valid_region(
            context.rectified_to_raw_obstructed,
            context.rectified_to_raw_clean,
            matrix,
            rectification.size,
            rig.camera(rig_file.obstructed).resolution,
            rig.camera(clean).resolution,
        )
        try:
            crop = choose_crop(valid, size)
        except CropError as exc:
            if created:
                shutil.rmtree(out_dir, ignore_errors=True)
            raise CropError(
                f"{recording.path}: cannot crop {size[0]}x{size[1]}: {exc} (with "
                f"{calibration_source}){_earlier(out_dir, created)}"
            ) from None
        margin = int(np.ceil(verify.max_shift_px)) + 2
        context = context.with_maps(
            crop, target_map(context.rectified_to_raw_clean, matrix, crop, margin)
        )
        lap("maps")

        chosen = [frame_pairs[i] for i in _sample(len(frame_pairs), estimation.max_frames)]
        images0, images1, blank = _side_check_images(chosen, context, SIDE_CHECK_FRAMES)
        nothing = "no readable frame pair to check"
        if blank:
            nothing = (
                f"every readable frame pair checked ({blank}) has a blank view; side not checked"
            )
        side_check: dict[str, Any] = {"message": nothing, "mismatch": False}
        if images0:
            side: Any = (
                check_obstructed_side(images0, images1, rig_file.obstructed)
                if side_detector is None
                else check_side_with_detector(images0, images1, rig_file.obstructed, side_detector)
            )
            side_check = to_plain(side)
            if side.mismatch:
                log.warning("%s: %s", recording.path, side.message)
        elif blank:
            log.warning("%s: %s (a camera or exposure fault?)", recording.path, nothing)
        side_check["blank_pairs_left_out"] = blank
        lap("side_check")

        set_report_aside(out_dir)  # until this run's report is written (its docstring)
        state = fingerprint({**setup, "matrix": registration["matrix"], "crop": crop.as_tuple()})
        settings = {  # what `state` hashes, readable, and what pairs the frames
            **setup,
            "significant_bits": bits,
            "calibration_source": calibration_source,
            "size": list(size),
            "time_offset_ns": time_offset_ns,
            "matrix": registration["matrix"],
            "crop": crop.as_tuple(),
        }
        ordered = _frame_stage(
            recording, pairing, rig_file, frame_pairs, context, state, workers, settings
        )
        lap("frames")

        kept = [r for r in ordered if r.status == "kept"]
        if kept:
            write_qa_sheet(out_dir / QA_FILE, out_dir, ordered)
        lap("qa")
        timings["total"] = round(time.perf_counter() - start, 3)

        counts = frame_counts(recording, pairing, rig_file, ordered)
        counts["homography_frames"] = len(registration["frames"])
        counts["homography_matches"] = int(registration["matches"])
        counts["homography_inliers"] = int(registration["inliers"])
        counts["recording_problems"] = len(said_of_recording)  # the clock warning too
        reasons = rejection_reasons(recording, ordered, rig_file.obstructed)
        homography_out = in_output_pixels(matrix, crop.x, crop.y)
        report = IngestReport(
            recording_id=recording.recording_id,
            source=str(source),  # absolute: tells a namesake apart
            obstructed=rig_file.obstructed,
            anomaly=rig_file.anomaly,
            calibration_source=calibration_source,
            calibration=rig_to_kalibr(rig),
            homography=homography_out.tolist(),
            crop=crop.as_tuple(),
            counts=counts,
            rejection_reasons=dict(sorted(reasons.items())),
            timings_s=timings,
            side_check=side_check,
            lenspair_version=__version__,
            significant_bits=bits if bits < 16 else None,
            recording_problems=said_of_recording,
            time_offset_ns=time_offset_ns,
        )
        write_report_if_changed(out_dir / REPORT_FILE, report)
        if not kept:
            raise CaptureError(
                f"{recording.path}: no usable pairs: all {len(ordered)} {rig_file.obstructed} "
                f"frames rejected ({', '.join(f'{k}: {v}' for k, v in sorted(reasons.items()))}); "
                f"see {out_dir / PAIRS_FILE}"
            )
        return report
