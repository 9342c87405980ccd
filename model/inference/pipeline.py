"""``restore_input``: a network over every frame of an input, the same format out.

Three stages overlap: a **reader thread** decodes frames
(:mod:`lenspair.capture.frames`), the calling thread batches them and runs
the network (:mod:`lenspair.model.inference.tiling`), and a **writer thread**
encodes and writes them in input order (:mod:`lenspair.model.inference.sinks`).
Queues between the stages are bounded (a few batches), so memory stays flat.

Rules a robotics user can rely on:

* **Batches are aligned to frame index** (frames ``k*B .. k*B+B-1`` of the
  same size form a batch), so a frame is always computed in the same batch,
  and ``--resume`` (which skips batches whose outputs all exist and recomputes
  the others) writes the same bytes as an uninterrupted run. A bag is
  written in one pass, so ``--resume`` writes it again, taking the frames an
  earlier run restored from a cache (:class:`~lenspair.model.inference.sinks.BagSink`);
  a bag a complete run wrote is kept as it is while its files and the settings
  are unchanged (the report records both).
* **Channels**: a mono network on RGB images (or the reverse) is refused with
  a one-line error on the first frame: no silent conversion. A later frame
  whose channels differ is a failed frame.
* **Failures cost only their frames**: an unreadable image or undecodable
  message, or a batch the network cannot run (a frame too large for memory:
  the reason says which ``--tile`` would fit), is recorded in
  ``OUT/restore_report.json`` with its reason and copied unchanged, so the
  output stays complete and aligned with the input; a bag cut short ends the
  copy where reading stopped (recorded too).
* ``judge`` (``--only-obstructed``): frames judged clean are copied unchanged.
"""

import contextlib
import json
import logging
import os
import re
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from lenspair.capture.bagwrite import output_bag_path
from lenspair.capture.frames import (
    InputFrame,
    InputKind,
    bag_camera_topics,
    bag_overview,
    bag_topics,
    detect_input,
    frame_files,
    iter_bag_messages,
    iter_frames,
)
from lenspair.capture.recording import CAMERAS, find_rig_file, present_cameras
from lenspair.capture.rigfile import CameraName, read_rig_file
from lenspair.core.bitdepth import RunningDepth, widen
from lenspair.core.fsutil import atomic_write_json, inside_refusal, read_json_field, sha256_file
from lenspair.core.leftovers import leftovers, remove_leftovers_under
from lenspair.core.wording import counted
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import Backend
from lenspair.model.inference.judge import FrameJudge
from lenspair.model.inference.options import CAMERA_CHOICES, DEFAULT_BATCH_SIZE, DEFAULT_OVERLAP
from lenspair.model.inference.sinks import STALE_DIR, BagSink, FileSink, FrameDepths
from lenspair.model.inference.threads import Writer, threaded
from lenspair.model.inference.tiling import check_tile, restore_images
from lenspair.model.networks.padding import MIN_SIDE

log = logging.getLogger(__name__)

REPORT_NAME = "restore_report.json"


@dataclass(frozen=True)
class RestoreOptions:
    """How to restore.

    Attributes:
        camera: ``auto`` (the obstructed camera named by ``rig.yaml``, else
            every camera the recording holds: both, or the one of a
            recording of one camera), ``cam0``, ``cam1`` or ``both``;
            recordings and bags only.
        batch_size: frames per network call (>= 1).
        tile: square tile side in pixels, or None for whole images.
        overlap: pixels shared by neighbouring tiles.
        suffix: bags only: write restored images to ``<topic><suffix>``
            beside the originals instead of replacing them.
        resume: continue a killed run in a non-empty OUT.
        topics: bags only: the ``(cam0, cam1)`` image topics; None picks
            them from their names (:func:`lenspair.capture.frames.bag_camera_topics`).
    """

    camera: str = "auto"
    batch_size: int = DEFAULT_BATCH_SIZE
    tile: int | None = None
    overlap: int = DEFAULT_OVERLAP
    suffix: str = ""
    resume: bool = False
    topics: tuple[str, str] | None = None


@dataclass
class RestoreReport:
    """What a run did; written to ``OUT/restore_report.json``.

    Attributes:
        input: the input path.
        kind: ``image``, ``folder``, ``euroc``, ``folders``, ``rosbag1`` or ``rosbag2``.
        output: the folder, or the bag written.
        model: the backend's description.
        cameras: cameras restored (recordings and bags).
        frames_read: frames met (decoded or not).
        restored: frames the network restored and wrote in this run.
        resumed: frames already written by an earlier run (``--resume``).
        skipped: frames judged clean and copied unchanged.
        skipped_frames: their names, in input order.
        failed: frames that could not be restored (copied unchanged).
        problems: ``{"frame", "reason"}`` per failed frame, plus input-level ones.
        seconds: wall time of the run.
        settings: what decides the output bytes (:func:`run_settings`);
            ``--resume`` refuses an OUT written with other ones.
        source_files: bags: ``[name, size, mtime_ns]`` of the files the bag
            was read from; ``--resume`` of a complete run keeps its bag while
            they are unchanged (:meth:`~lenspair.model.inference.sinks.BagSink.finished`).
        output_files: bags: the same of the bag written, which must be unchanged too.
    """

    input: str
    kind: str
    output: str
    model: str
    cameras: list[str]
    frames_read: int = 0
    restored: int = 0
    resumed: int = 0
    skipped: int = 0
    skipped_frames: list[str] = field(default_factory=list)
    failed: int = 0
    problems: list[dict[str, str]] = field(default_factory=list)
    seconds: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)
    source_files: list[list[Any]] = field(default_factory=list)
    output_files: list[list[Any]] = field(default_factory=list)

    @property
    def frames_per_second(self) -> float:
        """Frames read per second of wall time."""
        return self.frames_read / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """The final line: frames, time, frames/s, where the output is, problems if any."""
        return (
            f"restore: {counted(self.frames_read, 'frame')} ({self.restored} restored, "
            f"{self.resumed} resumed, {self.skipped} skipped, {self.failed} failed) "
            f"in {self.seconds:.1f} s, "
            f"{self.frames_per_second:.1f} frames/s -> {self.output}"
            + (f"; {len(self.problems)} problem(s) in {REPORT_NAME}" if self.problems else "")
        )

    def as_dict(self) -> dict[str, Any]:
        """Plain data for JSON (``complete``: the run finished)."""
        return {
            **asdict(self),
            "frames_per_second": round(self.frames_per_second, 3),
            "complete": True,
        }


def resolve_cameras(
    path: Path, kind: InputKind, choice: str, topics: tuple[str, str] | None = None
) -> tuple[CameraName, ...]:
    """The cameras to restore for ``--camera`` (see :class:`RestoreOptions`).

    A bag with a single image topic has one camera (``cam0``), restored
    whatever ``rig.yaml`` says.

    Raises:
        ModelError: an unknown choice.
    """
    if choice not in CAMERA_CHOICES:
        raise ModelError(f"--camera: expected one of {', '.join(CAMERA_CHOICES)}, got {choice!r}")
    if kind in ("rosbag1", "rosbag2") and len(bag_camera_topics(path, topics)) == 1:
        return ("cam0",)
    if choice == "both":
        return CAMERAS
    if choice in CAMERAS:
        return ("cam0",) if choice == "cam0" else ("cam1",)
    rig = find_rig_file(path)
    if rig is not None:
        return (read_rig_file(rig).obstructed,)
    return present_cameras(path)  # a recording of one camera: that one


def _say_unused(input_path: Path, kind: InputKind, options: RestoreOptions) -> None:
    """Warn of options that mean nothing for an image or a folder of images."""
    unused = [
        option
        for option, given in (
            ("--camera", options.camera != "auto"),
            ("--suffix", bool(options.suffix)),
            ("--topics", options.topics is not None),
        )
        if given
    ]
    if unused:
        log.warning(
            "%s: %s apply to recordings and bags; ignored for %s",
            input_path,
            " and ".join(unused),
            "an image" if kind == "image" else "a folder of images",
        )


def frame_problem(name: str, image: np.ndarray, channels: int) -> str | None:
    """Why the network cannot take ``image`` (``name`` leads the line), or None.

    Channels other than the network's ``channels`` (no silent conversion), or
    a side under the network's minimum.
    """
    if _channels(image) != channels:
        return (
            f"{name}: {_channels(image)} channel(s) but the network takes {channels}; "
            "convert the images or use a network trained on them"
        )
    if min(image.shape[:2]) < MIN_SIDE:
        return (
            f"{name}: {image.shape[1]}x{image.shape[0]} pixels, smaller than the network's "
            f"{MIN_SIDE}x{MIN_SIDE} minimum"
        )
    return None


def check_options(options: RestoreOptions, backend: Backend | None = None) -> None:
    """Refuse option values no input can use, before anything is read or written.

    Raises:
        ModelError: naming the option (``--batch-size``, ``--overlap``, ``--tile``);
            ``--tile`` for a model exported at a fixed size, which always runs
            on tiles of that size (the option was ignored without a word).
    """
    fixed = backend.fixed_size if backend is not None else None
    if options.tile is not None and fixed is not None:
        model = getattr(backend, "path", "the model")
        raise ModelError(
            f"--tile: {model} was exported at {fixed[1]}x{fixed[0]} and runs on tiles of "
            "that size; leave --tile out (export at another --size to change it)"
        )
    check_tile(options.tile)
    if options.batch_size < 1:
        raise ModelError(f"--batch-size: expected at least 1, got {options.batch_size}")
    if options.overlap < 0:
        raise ModelError(f"--overlap: expected at least 0 pixels, got {options.overlap}")
    if options.tile is not None and options.tile <= options.overlap:
        raise ModelError(
            f"--tile: expected more than --overlap ({options.overlap}) pixels, got {options.tile}"
        )


def check_out_dir(out_dir: Path, resume: bool) -> None:
    """Refuse a non-empty OUT unless resuming.

    Raises:
        ModelError: OUT is a file, or holds files and ``resume`` is False.
    """
    if out_dir.exists() and not out_dir.is_dir():
        raise ModelError(f"--out {out_dir}: exists and is not a folder")
    if not resume and out_dir.is_dir() and any(out_dir.iterdir()):
        raise ModelError(
            f"--out {out_dir}: not empty; pass --resume to continue a run or choose a new folder"
        )


def run_settings(
    input_path: Path,
    backend: Backend,
    options: RestoreOptions,
    cameras: tuple[CameraName, ...],
    judge: FrameJudge | None,
) -> dict[str, Any]:
    """What decides a run's output bytes: input, model (and its file's hash), batching, tiles."""
    model_file = getattr(backend, "path", None)
    digest = _file_digest(model_file)
    model = backend.description
    if model_file:  # as for the input: the same file, however the path was typed
        model = model.replace(str(model_file), str(Path(model_file).resolve()), 1)
    return {
        "input": str(input_path.resolve()),
        "model": model,
        "model_sha256": digest,
        "cameras": list(cameras),
        "batch_size": options.batch_size,
        "tile": options.tile,
        "overlap": options.overlap,
        "suffix": options.suffix,
        "topics": list(options.topics) if options.topics else None,
        "only_obstructed": judge is not None,
        # which detector judged: another one keeps other frames unrestored
        "detector_sha256": _file_digest(getattr(judge, "path", None)),
    }


def _file_digest(path: Path | None) -> str | None:
    """SHA-256 of a file, or None when there is none."""
    return sha256_file(Path(path)) if path and Path(path).is_file() else None


def check_same_settings(out_dir: Path, settings: dict[str, Any]) -> None:
    """``--resume``: refuse an OUT that a restore run with other settings wrote, or none did.

    A resumed run keeps the frames already written, so resuming with another
    model, batch size or tiling would mix outputs of two different runs; and
    in a folder no restore run wrote (no report: every run writes its
    settings there first), files that happen to bear an input's name would
    be taken for finished frames.

    Raises:
        ModelError: naming OUT and each setting that differs, or the missing report.
    """
    if not (out_dir / REPORT_NAME).is_file():
        stale = set(leftovers(out_dir))  # a run killed while writing its first report
        if out_dir.is_dir() and any(entry not in stale for entry in out_dir.iterdir()):
            # its files would pass for finished frames (a name, a newer time)
            raise ModelError(
                f"--resume: {out_dir} holds files but no {REPORT_NAME}, so no restore run "
                "wrote it; choose a new --out"
            )
        return
    before = read_json_field(out_dir / REPORT_NAME, "settings")
    if not isinstance(before, dict) or not before:
        return  # written before settings were recorded: nothing to compare with
    changed = [
        f"{key}: {before.get(key)!r} -> {value!r}"
        for key, value in settings.items()
        if before.get(key) != value and not (key == "model" and _same_model(before, settings))
    ]
    if changed:
        raise ModelError(
            f"--resume: {out_dir} was written with other settings ({'; '.join(changed)}); "
            "resume with the same ones, or choose a new --out"
        )


def _same_model(before: dict[str, Any], settings: dict[str, Any]) -> bool:
    """The same model file (by hash) on the same backend, device and precision.

    Runs recorded before the model's path was resolved hold it as typed; the
    descriptions are compared without their paths (``<kind> PATH on <device>
    (<precision>)``).
    """
    digest = settings.get("model_sha256")
    if digest is None or before.get("model_sha256") != digest:
        return False
    pattern = re.compile(r"^(?P<kind>.+?) (?P<path>.+) on (?P<where>[^ ]+ \([^)]+\))$")
    old, new = pattern.match(str(before.get("model"))), pattern.match(str(settings["model"]))
    return bool(old and new and (old["kind"], old["where"]) == (new["kind"], new["where"]))


def check_apart(input_path: Path, kind: InputKind, out_dir: Path) -> None:
    """Refuse an OUT that would overwrite the input or be read back as input.

    Outputs keep the input's names, so OUT may not be an input folder (a
    folder of images, a recording, a ROS 2 bag folder) or lie inside it (a
    rerun would restore its own outputs, or write into the bag), and the
    output of a single image or bag may not land on the input itself (OUT =
    the folder that holds it: a bag is written afresh, which would delete the
    input).

    Raises:
        ModelError: naming OUT and the input.
    """
    # a folder, a recording, a ROS 2 bag
    why = "outputs keep the input's names"
    if (problem := inside_refusal(out_dir, input_path, "the input", why)) is not None:
        raise ModelError(problem)
    if kind in ("folder", "euroc", "folders"):
        return
    bag = kind in ("rosbag1", "rosbag2")
    written = output_bag_path(input_path, out_dir) if bag else out_dir / input_path.name
    if written.resolve() == input_path.resolve():
        raise ModelError(
            f"--out {out_dir}: the folder that holds {input_path}; the output keeps its name "
            "and would replace it, so choose another folder"
        )
    if input_path.resolve().is_relative_to(written.resolve()):  # a bare .db3/.mcap
        raise ModelError(
            f"--out {out_dir}: the restored bag is written as the folder {written}, which "
            f"holds the input {input_path} and would replace it, so choose another folder"
        )


@dataclass(frozen=True)
class CheckedInput:
    """What :func:`check_input` found: the kind, the options that apply, the frames.

    Attributes:
        kind: image, folder, EuRoC/ASL recording or bag.
        options: the options, with those meaning nothing for images reset.
        cameras: the cameras to restore (none for images).
        files: the image files (none for bags, read as they stream).
    """

    kind: InputKind
    options: RestoreOptions
    cameras: tuple[CameraName, ...]
    files: list[Path]


def check_input(input_path: Path, out_dir: Path, options: RestoreOptions) -> CheckedInput:
    """Everything about the input and OUT that can be refused without the model.

    ``restore`` calls it before it loads the model, so that a mistyped path,
    a topic the bag lacks, a folder without images or a non-empty OUT is the
    only line said.

    Raises:
        CaptureError: no such input, not one lenspair reads, a topic or camera it lacks.
        ModelError: no images, ``out_dir`` inside the input (:func:`check_apart`) or
            not empty without ``options.resume``.
    """
    kind = detect_input(input_path)
    check_apart(input_path, kind, out_dir)
    cameras = resolve_cameras(input_path, kind, options.camera, options.topics)
    if kind in ("image", "folder"):
        # an image or a folder of them has no cameras nor topics: none decides its bytes
        options = replace(options, camera="auto", suffix="", topics=None)
        cameras = ()
    bag = kind in ("rosbag1", "rosbag2")
    if bag and options.suffix:
        check_suffix_free(input_path, cameras, options)
    files = [] if bag else frame_files(input_path, kind, cameras)
    if not bag and not files:
        # Refused before OUT is made: an empty run is a mistyped path, not a result.
        raise ModelError(f"{input_path}: no images to restore")
    check_out_dir(out_dir, options.resume)
    return CheckedInput(kind, options, cameras, files)


def check_suffix_free(bag: Path, cameras: tuple[CameraName, ...], options: RestoreOptions) -> None:
    """Refuse ``--suffix`` where ``<topic><suffix>`` is already one of the bag's topics.

    A bag restored before with the same suffix (or recorded from a robot that
    publishes restored frames) holds that topic already; writing the restored
    frames into it would mix two runs' frames on one topic.

    Raises:
        ModelError: names the bag, the topic and what to do.
    """
    existing, named = bag_topics(bag, options.topics)
    taken = sorted(
        topic + options.suffix
        for topic, camera in named.items()
        if camera in cameras and topic + options.suffix in existing
    )
    if taken:
        raise ModelError(
            f"{bag}: topic {taken[0]} is in the bag already; --suffix {options.suffix} would "
            "write restored frames into it: choose another --suffix, or restore without one "
            "to replace the camera's frames"
        )


def restore_input(
    input_path: Path,
    out_dir: Path,
    backend: Backend,
    options: RestoreOptions = RestoreOptions(),
    judge: FrameJudge | None = None,
    checked: CheckedInput | None = None,
) -> RestoreReport:
    """Restore every frame of an input into OUT in the input's format.

    Args:
        input_path: image, folder, EuRoC/ASL recording or bag.
        out_dir: output folder (refused when not empty unless ``options.resume``).
        backend: the network (:func:`~lenspair.model.inference.backends.open_backend`).
        options: see :class:`RestoreOptions`.
        judge: when given, only frames it calls obstructed are restored.
        checked: :func:`check_input` of these arguments, when already called.

    Returns:
        The report (also written to ``OUT/restore_report.json``).

    Raises:
        ModelError: bad options, non-empty OUT, OUT overlapping the input (see
            :func:`check_apart`), or a channel mismatch on the first frame
            (OUT is then left as it was).
        CaptureError: the input cannot be opened at all.
    """
    started = time.perf_counter()
    input_path, out_dir = Path(input_path), Path(out_dir)
    check_options(options, backend)
    if checked is None:  # restore's CLI checked it before loading the model
        checked = check_input(input_path, out_dir, options)
    kind, cameras, files = checked.kind, checked.cameras, checked.files
    if kind in ("image", "folder"):
        _say_unused(input_path, kind, options)
    options = checked.options
    bag = kind in ("rosbag1", "rosbag2")
    settings = run_settings(input_path, backend, options, cameras, judge)
    if options.resume:
        check_same_settings(out_dir, settings)
    remove_leftovers_under(out_dir)  # of a killed run: its half-written temporaries
    made = [folder for folder in (out_dir, *out_dir.parents) if not folder.exists()]
    out_dir.mkdir(parents=True, exist_ok=True)
    started_report = not (out_dir / REPORT_NAME).exists()
    sink: FileSink | BagSink = (
        BagSink(input_path, out_dir, options.suffix, options.resume) if bag else FileSink(out_dir)
    )
    if isinstance(sink, BagSink) and options.resume:
        # a bag is written in one pass, and its cache is gone once complete: without this,
        # resuming a finished run restored every frame again
        finished = _finished_report(out_dir)
        if finished is not None and sink.finished(
            finished.get("source_files"), finished.get("output_files")
        ):
            report = _kept(finished, input_path, kind, sink, backend, cameras, settings)
            report.seconds = time.perf_counter() - started
            atomic_write_json(out_dir / REPORT_NAME, report.as_dict())
            return report
    # the settings go first, so that a killed run's --resume can check them
    atomic_write_json(out_dir / REPORT_NAME, {"settings": settings, "complete": False})
    source_problems: list[str] = []
    total: int | None = None
    if isinstance(sink, BagSink):
        overview = bag_overview(input_path, cameras, options.topics)
        source_problems.extend(overview.others)
        total = overview.frames  # for the progress bar
        items: Iterator[Any] = iter_bag_messages(
            input_path, cameras, source_problems, options.topics
        )
    else:
        total = len(files)
        items = iter_frames(input_path, cameras, source_problems)
    report = RestoreReport(
        str(input_path), kind, str(sink.output), backend.description, list(cameras)
    )
    report.settings = settings
    writer = Writer(sink, report, size=4 * options.batch_size)
    try:
        refused = _run(
            threaded(items, 4 * options.batch_size), backend, options, judge, writer, total
        )
    finally:
        writer.close()
    if refused is not None:  # at the first frame, before any write: leave OUT as it was
        if started_report:
            (out_dir / REPORT_NAME).unlink(missing_ok=True)
        with contextlib.suppress(OSError):  # only the folders this run made, while empty
            for folder in made:
                folder.rmdir()
        raise ModelError(refused)
    if kind in ("euroc", "folders", "folder"):  # after the frames: a refused run writes nothing
        assert isinstance(sink, FileSink)
        if sink.changed:
            log.warning(
                "%d frame(s) restored again: their input changed after the resumed run wrote "
                "them (or only its metadata: chmod, a copy with cp -a)",
                sink.changed,
            )
        follow = kind != "folder"  # a folder's frames are listed without following links
        copied = sink.copy_others(input_path, files, (REPORT_NAME,), follow)
        source_problems.extend(copied)
        if options.resume:
            stale, left = sink.set_aside_stale(input_path, (REPORT_NAME,), follow)
            if stale:
                log.warning(
                    "%d image(s) whose input is gone since the resumed run (the first: %s) "
                    "moved to %s",
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
            source_problems.extend(
                f"{name}: its input is gone; moved to {STALE_DIR}/{name}" for name in stale
            )
            source_problems.extend(
                f"{name}: in OUT, not in the input; left in place" for name in left
            )
    sink.finish()
    if isinstance(sink, BagSink):
        report.source_files = sink.fingerprint
        report.output_files = sink.written()
        source_problems.extend(
            f"{topic}: a type neither the bag nor rosbags defines: its messages are copied "
            "byte for byte, under an empty definition whose hash is not the type's, so readers "
            "that decode by the bag's definitions (rosbags) cannot decode them from the copy; "
            "decode that topic from the original"
            for topic in sink.copy.undefined
        )
    report.problems.extend({"frame": "", "reason": reason} for reason in source_problems)
    report.seconds = time.perf_counter() - started
    atomic_write_json(out_dir / REPORT_NAME, report.as_dict())
    return report


def _finished_report(out_dir: Path) -> dict[str, Any] | None:
    """OUT's report when a complete run with recorded settings wrote it, else None.

    A run that failed frames is not taken as finished: ``--resume`` tries them
    again (a frame too large for memory, with ``--tile``), as in a folder.
    """
    try:
        data = json.loads((out_dir / REPORT_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):  # none, or cut: no run finished there
        return None
    if not isinstance(data, dict) or data.get("complete") is not True:
        return None
    if data.get("failed", 0) != 0:
        return None
    return data if isinstance(data.get("settings"), dict) and data["settings"] else None


def _kept(
    finished: dict[str, Any],
    input_path: Path,
    kind: InputKind,
    sink: BagSink,
    backend: Backend,
    cameras: tuple[CameraName, ...],
    settings: dict[str, Any],
) -> RestoreReport:
    """The report of a ``--resume`` that keeps the bag a complete run wrote (``finished``).

    Its frames count as resumed, as a resumed folder's finished frames do;
    what it skipped and found is said again, since the bag holds it (a run
    with failed frames is never kept: :func:`_finished_report`).
    """
    log.info("%s: written by the run being resumed, from the same bag: kept", sink.output)
    report = RestoreReport(
        str(input_path), kind, str(sink.output), backend.description, list(cameras)
    )
    report.frames_read = int(finished.get("frames_read", 0))
    report.resumed = int(finished.get("restored", 0)) + int(finished.get("resumed", 0))
    report.skipped = int(finished.get("skipped", 0))
    report.skipped_frames = list(finished.get("skipped_frames", []))
    report.problems = list(finished.get("problems", []))
    report.settings = settings
    report.source_files = sink.fingerprint
    report.output_files = sink.written()
    return report


def _run(
    items: Iterator[Any],
    backend: Backend,
    options: RestoreOptions,
    judge: FrameJudge | None,
    writer: Writer,
    total: int | None,
) -> str | None:
    """Batch frames and run the network; hands everything to ``writer`` in order.

    Returns:
        None; or, when the first readable frame's channels are not the
        network's, why, with nothing handed to ``writer`` (the run is refused;
        a later frame that does not match is a failed frame). A refusal is
        returned, not raised, so that no other error (a judge's) is taken for one.
    """
    report = writer.report
    pending: list[tuple[Any, InputFrame | None, int | None]] = []  # item, frame, batch slot
    batch: list[InputFrame] = []
    bar = tqdm(total=total, desc="restoring", unit="frame", leave=False, disable=_quiet())

    def flush(bits: int | None = None) -> None:
        """Restore ``batch`` at ``bits`` (default: the depth now) and hand on ``pending``."""
        outputs: list[np.ndarray | None] = [None] * len(batch)
        # 16-bit frames of 10- or 12-bit values are restored on the full scale, then
        # written back in the camera's words (lenspair.core.bitdepth)
        bits = depth.bits if bits is None else bits
        done = [writer.sink.done(frame) and depths.same(frame, bits) for frame in batch]
        failure = None
        if batch and not all(done):  # the whole batch: same batches as an uninterrupted run
            images = [frame.image for frame in batch if frame.image is not None]
            depths.record(batch, bits)
            try:
                outputs[:] = restore_images(backend, images, bits, options.tile, options.overlap)
            except ModelError as exc:  # a frame too large for memory: its batch fails, not the run
                failure = str(exc)
        for item, frame, slot in pending:
            if slot is None:
                writer.put(item, frame, None)
            elif done[slot]:  # written by an earlier run; a bag takes it from the cache
                report.resumed += 1
                cached = writer.sink.cached(batch[slot])
                if cached is not None:
                    writer.put(item, frame, cached)
            elif failure is not None:  # copied unchanged and listed; --resume tries it again
                assert frame is not None
                report.failed += 1
                report.problems.append({"frame": frame.name, "reason": failure})
                writer.put(item, frame, None)
            else:
                report.restored += 1
                writer.put(item, frame, outputs[slot])
        pending.clear()
        batch.clear()

    channels_checked = False
    depth = RunningDepth(writer.report.input)
    depths = FrameDepths(writer.sink.state_dir)
    for item in items:
        frame: InputFrame | None = item if isinstance(item, InputFrame) else item.frame
        if frame is None:
            pending.append((item, None, None))
            continue
        report.frames_read += 1
        bar.update(1)
        image = frame.image
        reason = frame.error
        if image is not None:
            reason = frame_problem(str(frame.source), image, backend.channels) or reason
            if reason is not None and _channels(image) != backend.channels and not channels_checked:
                bar.close()
                return reason
        if image is None or reason is not None:
            report.failed += 1
            report.problems.append({"frame": frame.name, "reason": reason or "unreadable"})
            pending.append((item, frame, None))
            continue
        channels_checked = True
        # every readable frame, finished ones too: a resume decides alike; the frames
        # batched so far are restored at the depth they were seen at, as one by one
        if (before := depth.rise(image)) is not None and batch:
            flush(before)
        if judge is not None and not judge(frame, widen(image, depth.bits)):
            report.skipped += 1
            report.skipped_frames.append(frame.name)
            pending.append((item, frame, None))
            continue
        if batch and _batch_key(batch[0], options) != _batch_key(frame, options):
            flush()
        batch.append(frame)
        pending.append((item, frame, len(batch) - 1))
        if len(batch) == options.batch_size:
            flush()
    flush()
    bar.close()
    if depths.redone:
        log.warning(
            "%d finished 16-bit frame(s) restored again: frames added or removed before them "
            "changed the bit depth they are taken at (lenspair.core.bitdepth.RunningDepth)",
            depths.redone,
        )
    return None


def _batch_key(frame: InputFrame, options: RestoreOptions) -> tuple[Any, ...]:
    assert frame.image is not None
    return (frame.index // options.batch_size, frame.image.shape, frame.image.dtype)


def _channels(image: np.ndarray) -> int:
    return 1 if image.ndim == 2 else int(image.shape[2])


def _quiet() -> bool:
    return os.environ.get("LENSPAIR_QUIET", "") == "1"
