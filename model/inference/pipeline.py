"""``restore_input``: a network over every frame of an input, the same format out.

Three stages overlap: a **reader thread** decodes frames
(:mod:`lenspair.capture.frames`), the calling thread batches them and runs
the network (:mod:`lenspair.model.inference.batching`), and a **writer thread**
encodes and writes them in input order (:mod:`lenspair.model.inference.file_sink`,
:mod:`lenspair.model.inference.bag_sink`).
Queues between the stages are bounded (a few batches), so memory stays flat.

Rules a robotics user can rely on:

* **Batches are aligned to frame index** (frames ``k*B .. k*B+B-1`` of the
  same size form a batch), so a frame is always computed in the same batch,
  and ``--resume`` (which skips batches whose outputs all exist and recomputes
  the others) writes the same bytes as an uninterrupted run. A bag is
  written in one pass, so ``--resume`` writes it again, taking the frames an
  earlier run restored from a cache (:class:`~lenspair.model.inference.bag_sink.BagSink`);
  a bag a complete run wrote is kept as it is while its files and the settings
  are unchanged (the report records both).
* **Channels**: a mono network on RGB images (or the reverse) is refused with
  a one-line error when none of the first frames match
  (:data:`~lenspair.model.inference.batching.REFUSE_AFTER`): no silent
  conversion. Any other frame whose channels differ is a failed frame.
* **Failures cost only their frames**: an unreadable image or undecodable
  message, or a batch the network cannot run (a frame too large for memory:
  the reason says which ``--tile`` would fit), is recorded in
  ``OUT/restore_report.json`` with its reason and copied unchanged, so the
  output stays complete and aligned with the input; a bag cut short ends the
  copy where reading stopped (recorded too).
* ``judge`` (``--only-obstructed``): frames judged clean are copied unchanged.
* **No silent tiles**: an ONNX model of a fixed size (exported before sizes
  were dynamic) runs frames of other sizes in tiles of its size, which differ
  from the checkpoint's output at the seams: the run warns once and records
  the tile (``forced_tile`` in the report).
"""

import contextlib
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from lenspair.capture.bag_frames import iter_bag_messages
from lenspair.capture.frames import InputKind, images_outside_cameras, iter_frames
from lenspair.capture.rigfile import CameraName
from lenspair.core.folderlock import holding
from lenspair.core.fsutil import atomic_write_json, make_folder, remove_made
from lenspair.core.leftovers import remove_leftovers_under
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import Backend
from lenspair.model.inference.bag_sink import BagSink
from lenspair.model.inference.batching import run_batches
from lenspair.model.inference.file_sink import FileSink
from lenspair.model.inference.input_checks import CheckedInput, check_input, holds_output
from lenspair.model.inference.judge import FrameJudge
from lenspair.model.inference.out_layout import STALE_DIR, files_under
from lenspair.model.inference.report import REPORT_NAME, RESTORE_LOCK, RestoreReport
from lenspair.model.inference.restore_options import RestoreOptions, check_options
from lenspair.model.inference.resume import check_same_settings, kept_bag_report, run_settings
from lenspair.model.inference.threads import Writer, threaded
from lenspair.model.inference.unread_files import unrestored_note

log = logging.getLogger(__name__)

_DEFAULT_OPTIONS = RestoreOptions()  # frozen, so one instance can be every call's default


def restore_input(
    input_path: Path,
    out_dir: Path,
    backend: Backend,
    options: RestoreOptions = _DEFAULT_OPTIONS,
    judge: FrameJudge | None = None,
    checked: CheckedInput | None = None,
) -> RestoreReport:
    """Restore every frame of an input into OUT in the input's format.

    Args:
        input_path: image, folder, EuRoC/ASL recording or bag.
        out_dir: output folder (refused when not empty unless ``options.resume``).
        backend: the network (:func:`~lenspair.model.inference.backends.open_backend`).
        options: see :class:`~lenspair.model.inference.restore_options.RestoreOptions`.
        judge: when given, only frames it calls obstructed are restored.
        checked: :func:`~lenspair.model.inference.input_checks.check_input` of these
            arguments, when already called.

    Returns:
        The report (also written to ``OUT/restore_report.json``).

    Raises:
        ModelError: bad options, non-empty OUT, OUT overlapping the input (see
            :func:`~lenspair.model.inference.input_checks.check_apart`), or a channel
            mismatch on every one of the first frames
            (OUT is then left as it was).
        CaptureError: the input cannot be opened at all.
    """
    started = time.perf_counter()
    input_path, out_dir = Path(input_path), Path(out_dir)
    check_options(options, backend)
    if checked is None:  # restore's CLI checked it before loading the model
        checked = check_input(input_path, out_dir, options)
    kind, cameras = checked.kind, checked.cameras
    if kind not in ("rosbag1", "rosbag2"):
        _say_unused(input_path, kind, options)
    options = checked.options
    bag = kind in ("rosbag1", "rosbag2")
    settings = run_settings(input_path, backend, options, cameras, judge)
    if options.resume:
        check_same_settings(out_dir, settings, bag)
    remove_leftovers_under(out_dir)  # of a killed run: its half-written temporaries
    made = make_folder(out_dir)
    with _one_writer(out_dir, options.resume, made) as made_lock:
        return _restore_locked(
            (input_path, out_dir, started),
            backend,
            options,
            judge,
            checked,
            settings,
            (made, made_lock),
        )


@contextlib.contextmanager
def _one_writer(out_dir: Path, resume: bool, made: list[Path]) -> Iterator[bool]:
    """Hold OUT's :data:`RESTORE_LOCK` meanwhile: one restore writes a folder at a time.

    Two runs started together both found OUT empty, then both wrote it (23
    images beside a 12-row ``data.csv``), and a ``--resume`` retry ran beside
    the live run. Without ``resume`` OUT is checked again once held: a run
    that finished meanwhile has filled it. Yields whether this run made the
    lock file (removed with OUT's folders when the run is refused at its first
    frames).

    Raises:
        ModelError: another restore holds OUT, or filled it meanwhile.
    """
    lock = out_dir / RESTORE_LOCK
    mine = not lock.exists()
    taken = ModelError(
        f"--out {out_dir}: another restore is writing it; wait for it to finish or choose "
        "another --out"
    )
    with holding(lock, "restore", taken):
        if not resume and holds_output(out_dir):
            _remove_made(out_dir, made, mine)
            raise ModelError(
                f"--out {out_dir}: another restore filled it meanwhile; pass --resume to "
                "continue that run or choose a new folder"
            )
        yield mine


def _restore_locked(
    paths: tuple[Path, Path, float],
    backend: Backend,
    options: RestoreOptions,
    judge: FrameJudge | None,
    checked: CheckedInput,
    settings: dict[str, Any],
    made: tuple[list[Path], bool],
) -> RestoreReport:
    """:func:`restore_input` once OUT is this run's: the frames, the files beside them.

    ``paths`` is ``(input_path, out_dir, started)``, ``started`` the run's start
    (``time.perf_counter``); ``made`` as :func:`_undo_refused` takes it.
    """
    input_path, out_dir, started = paths
    kind, cameras, files = checked.kind, checked.cameras, checked.files
    bag = kind in ("rosbag1", "rosbag2")
    started_report = not (out_dir / REPORT_NAME).exists()
    sink: FileSink | BagSink = (
        BagSink(input_path, out_dir, options.suffix, options.resume, options.jpeg_quality)
        if bag
        else FileSink(out_dir, options.jpeg_quality)
    )
    if isinstance(sink, BagSink) and options.resume:
        kept = kept_bag_report(out_dir, input_path, kind, sink, backend, cameras, settings)
        if kept is not None:
            kept.seconds = time.perf_counter() - started
            atomic_write_json(out_dir / REPORT_NAME, kept.as_dict())
            return kept
    # the settings go first, so that a killed run's --resume can check them
    atomic_write_json(out_dir / REPORT_NAME, {"settings": settings, "complete": False})
    source_problems: list[str] = []
    items, total = _open_items(input_path, sink, checked, source_problems)
    report = RestoreReport(
        str(input_path), kind, str(sink.output), backend.description, list(cameras)
    )
    report.settings = settings
    forced = backend.forced_tiles if backend.fixed_size is not None else None
    if forced is not None:
        forced.start()  # warned once per run
    writer = Writer(sink, report, size=4 * options.batch_size)
    try:
        refused = run_batches(
            threaded(items, 4 * options.batch_size), backend, options, judge, writer, total
        )
    finally:
        writer.close()
    if refused is not None:  # at the first frames, before any write: leave OUT as it was
        _undo_refused(out_dir, made, started_report)
        raise ModelError(refused)
    if kind in ("euroc", "folders", "folder"):  # after the frames: a refused run writes nothing
        assert isinstance(sink, FileSink)
        source_problems.extend(
            _finish_files(sink, input_path, kind, cameras, files, options, out_dir)
        )
    sink.finish(report.failed)
    if isinstance(sink, BagSink):
        report.source_files = sink.fingerprint
        report.output_files = sink.written()
        source_problems.extend(_undefined_types(sink))
        # a ROS 1 bag or a video kept in the bag's folder is copied with its frames as
        # they were: named, as a folder's are
        source_problems.extend(n for e in sink.extras if (n := unrestored_note(e)) is not None)
    report.problems.extend({"frame": "", "reason": reason} for reason in source_problems)
    if forced is not None and forced.frame_sizes:
        report.forced_tile = forced.tile_text
    report.seconds = time.perf_counter() - started
    atomic_write_json(out_dir / REPORT_NAME, report.as_dict())
    return report


_KIND_NAMES = {
    "image": "an image",
    "folder": "a folder of images",
    "euroc": "a EuRoC recording",
    "folders": "a left/right recording",
}


def _say_unused(input_path: Path, kind: InputKind, options: RestoreOptions) -> None:
    """Warn of options that mean nothing for this kind of input (not a bag).

    ``--suffix`` and ``--topics`` are for bags alone; ``--camera`` for
    recordings and bags.
    """
    unused: dict[str, list[str]] = {}  # scope -> the options given outside it
    for option, scope, given in (
        ("--camera", "recordings and bags", options.camera != "auto"),
        ("--suffix", "bags", bool(options.suffix)),
        ("--topics", "bags", options.topics is not None),
    ):
        if given and not (scope == "recordings and bags" and kind in ("euroc", "folders")):
            unused.setdefault(scope, []).append(option)
    for scope, said in unused.items():
        log.warning(
            "%s: %s %s only to %s; ignored for %s",
            input_path,
            " and ".join(said),
            "applies" if len(said) == 1 else "apply",
            scope,
            _KIND_NAMES.get(kind, kind),
        )


def _open_items(
    input_path: Path,
    sink: FileSink | BagSink,
    checked: CheckedInput,
    source_problems: list[str],
) -> tuple[Iterator[Any], int | None]:
    """The input's items, read as they are iterated, and how many frames (for the progress bar).

    Args:
        input_path: the input.
        sink: a :class:`BagSink` for a bag (its messages are read), else frames are.
        checked: the checked input: its cameras, files (a folder's or
            recording's frames), options (a bag's ``topics``) and a bag's overview.
        source_problems: extended with the input's problems: the bag's
            others at once, those met while reading as the items are read.
    """
    cameras = checked.cameras
    if isinstance(sink, BagSink):
        assert checked.overview is not None  # check_input reads a bag's
        source_problems.extend(checked.overview.others)
        items: Iterator[Any] = iter_bag_messages(
            input_path, cameras, source_problems, checked.options.topics
        )
        return items, checked.overview.frames
    # a file of several pages is copied whole and listed (file_sink): not "its first page"
    frames = iter_frames(input_path, cameras, source_problems, say_pages=False)
    return frames, len(checked.files)


def _undo_refused(out_dir: Path, made: tuple[list[Path], bool], started_report: bool) -> None:
    """Leave OUT as it was before a run refused at its first frame (nothing else was written).

    Args:
        out_dir: the output folder.
        made: the folders this run made, innermost first (removed while empty),
            and whether it made OUT's lock file.
        started_report: this run wrote the first report in OUT: removed.
    """
    if started_report:
        (out_dir / REPORT_NAME).unlink(missing_ok=True)
    _remove_made(out_dir, *made)


def _remove_made(out_dir: Path, folders: list[Path], lock: bool) -> None:
    """Remove the lock file this run made (``lock``), then its ``folders`` while empty."""
    if lock:
        (out_dir / RESTORE_LOCK).unlink(missing_ok=True)
    remove_made(folders)


def _finish_files(
    sink: FileSink,
    input_path: Path,
    kind: InputKind,
    cameras: tuple[CameraName, ...],
    files: list[Path],
    options: RestoreOptions,
    out_dir: Path,
) -> list[str]:
    """After a folder's or recording's frames: copy its other files, set aside stale outputs.

    Returns:
        The problems to report: files not copied or holding unread frames,
        a recording's images outside its cameras (copied unrestored, a line
        per folder of them), and with ``--resume`` the outputs whose input is
        gone or that have none.
    """
    problems: list[str] = []
    if sink.changed:
        log.warning(
            "%d frame(s) restored again: their input changed after the resumed run wrote "
            "them (or only its metadata: chmod, a copy with cp -a)",
            sink.changed,
        )
    follow = kind != "folder"  # a folder's frames are listed without following links
    problems.extend(sink.copy_others(input_path, files, (REPORT_NAME, RESTORE_LOCK), follow))
    if follow:  # a recording: its images that no camera of it holds were copied just now
        outside = images_outside_cameras(input_path, kind, cameras, files, files_under(input_path))
        problems.extend(group.note("restore", "copied unrestored") for group in outside)
    if options.resume:
        stale, left = sink.set_aside_stale(input_path, (REPORT_NAME, RESTORE_LOCK), follow)
        if stale:
            log.warning(
                "%d image(s) whose input is gone since the resumed run (the first: %s) moved to %s",
                len(stale),
                stale[0],
                out_dir / STALE_DIR,
            )
        if left:
            log.warning(
                "%d file(s) in OUT with no input (the first: %s) left in place",
                len(left),
                left[0],
            )
        problems.extend(f"{name}: its input is gone; moved to {STALE_DIR}/{name}" for name in stale)
        problems.extend(f"{name}: in OUT, not in the input; left in place" for name in left)
    return problems


def _undefined_types(sink: BagSink) -> list[str]:
    """A problem line per topic whose type the copied bag cannot define (after ``finish``)."""
    return [
        f"{topic}: a type neither the bag nor rosbags defines: its messages are copied "
        "byte for byte, under an empty definition whose hash is not the type's, so readers "
        "that decode by the bag's definitions (rosbags) cannot decode them from the copy; "
        "decode that topic from the original"
        for topic in sink.copy.undefined
    ]
