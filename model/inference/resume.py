"""What ``--resume`` relies on: the settings a run records, the depth of each frame, a kept bag.

A resumed run keeps the frames an earlier run wrote, so it must be the same
run: :func:`run_settings` records what decides the output bytes and
:func:`check_same_settings` refuses others (but another tiling: a frame too
large for memory is redone with the ``--tile`` its error named); :class:`FrameDepths` notes the
bit depth each 16-bit frame was restored at, since frames added before it
change it; and :func:`kept_bag_report` keeps the bag a complete run wrote,
which would otherwise be restored again frame by frame (a bag is written in
one pass, and its cache is gone once complete).
"""

import json
import logging
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from lenspair.capture.frame_types import InputFrame
from lenspair.capture.frames import InputKind
from lenspair.capture.rigfile import CameraName
from lenspair.core.fsutil import naming_errors, read_json_field, sha256_file
from lenspair.core.leftovers import leftovers
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import Backend
from lenspair.model.inference.bag_sink import BagSink
from lenspair.model.inference.judge import FrameJudge
from lenspair.model.inference.out_layout import DEPTHS_NAME
from lenspair.model.inference.report import REPORT_NAME, RESTORE_LOCK, RestoreReport
from lenspair.model.inference.restore_options import RestoreOptions

log = logging.getLogger(__name__)


def run_settings(
    input_path: Path,
    backend: Backend,
    options: RestoreOptions,
    cameras: tuple[CameraName, ...],
    judge: FrameJudge | None,
) -> dict[str, Any]:
    """What decides a run's output bytes: input, model (and its file's hash), batching, tiles.

    ``jpeg_quality`` too (a report without it: :data:`EARLIER_JPEG_QUALITY`).
    """
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
        "jpeg_quality": options.jpeg_quality,
        "topics": list(options.topics) if options.topics else None,
        "only_obstructed": judge is not None,
        # which detector judged: another one keeps other frames unrestored
        "detector_sha256": _file_digest(getattr(judge, "path", None)),
    }


def _file_digest(path: Path | None) -> str | None:
    """SHA-256 of a file, or None when there is none."""
    return sha256_file(Path(path)) if path and Path(path).is_file() else None


EARLIER_JPEG_QUALITY = {"files": 98, "bag": 95}
"""The JPEG quality of a run whose report records none (lenspair before ``--jpeg-quality``):
image files were written at OpenImageIO's default, 98 (the same bytes as ``jpeg:98``), and
bags' ``CompressedImage`` messages at OpenCV's, 95. So such a run resumes at exactly its
own quality: by default for a bag, with ``--jpeg-quality 98`` for files (the refusal says so)."""


def check_same_settings(out_dir: Path, settings: dict[str, Any], bag: bool = False) -> None:
    """``--resume``: refuse an OUT that a restore run with other settings wrote, or none did.

    A resumed run keeps the frames already written, so resuming with another
    model or batch size would mix outputs of two different runs (another
    tiling is allowed and recorded: :func:`_retiled`); and
    in a folder no restore run wrote (no report: every run writes its
    settings there first), files that happen to bear an input's name would
    be taken for finished frames.

    Raises:
        ModelError: naming OUT and each setting that differs, or the missing report.
    """
    if not (out_dir / REPORT_NAME).is_file():
        stale = set(leftovers(out_dir))  # a run killed while writing its first report
        stale.add(out_dir / RESTORE_LOCK)  # and the lock it held
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
    # A key the report lacks (an earlier lenspair's run) counts as None: so a setting
    # that came with None for what those runs did (topics, detector_sha256) still
    # resumes; the JPEG quality they wrote at is known
    before = {"jpeg_quality": EARLIER_JPEG_QUALITY["bag" if bag else "files"], **before}
    changed = [
        f"{key}: {before.get(key)!r} -> {value!r}"
        for key, value in settings.items()
        if key not in (*TILING, EARLIER_TILING)
        and before.get(key) != value
        and not (key == "model" and _same_model(before, settings))
    ]
    if changed:
        quality = before["jpeg_quality"]
        hint = f" (--jpeg-quality {quality})" if quality != settings.get("jpeg_quality") else ""
        raise ModelError(
            f"--resume: {out_dir} was written with other settings ({'; '.join(changed)}); "
            f"resume with the same ones{hint}, or choose a new --out"
        )
    _retiled(before, settings)


TILING = ("tile", "overlap")
"""Settings ``--resume`` may change: how frames are cut into tiles (:func:`_retiled`)."""
EARLIER_TILING = "earlier_tiling"
"""The settings' record of the tilings a resumed run's earlier frames ran with."""


def _retiled(before: dict[str, Any], settings: dict[str, Any]) -> None:
    """Record in ``settings`` (and say once) a resume that tiles otherwise.

    A frame too large for memory fails alone, and its error says which
    ``--tile`` fits; so ``--resume --tile N`` must be allowed, or the advice
    cost a rerun of everything. The frames already written keep the tiling
    they ran with (whole, mostly: the better output), those not yet written
    get the new one, and ``settings[EARLIER_TILING]`` lists the earlier ones.
    """
    earlier = list(before.get(EARLIER_TILING) or [])
    then = {key: before.get(key) for key in TILING}
    if _tiling(then) != _tiling(settings):
        earlier.append(then)
        log.warning(
            "--resume with %s (before: %s): the frames already written keep the tiling "
            "they ran with, the others run with the new one (%s in the report)",
            _tiling_text(settings),
            _tiling_text(then),
            EARLIER_TILING,
        )
    if earlier:
        settings[EARLIER_TILING] = earlier


def _tiling(settings: dict[str, Any]) -> tuple[Any, Any]:
    """``(tile, overlap)``; the overlap means nothing without tiles."""
    tile = settings.get("tile")
    return tile, settings.get("overlap") if tile else None


def _tiling_text(settings: dict[str, Any]) -> str:
    tile, overlap = _tiling(settings)
    return f"--tile {tile} --overlap {overlap}" if tile else "whole frames"


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


class FrameDepths:
    """The depth (:class:`~lenspair.core.bitdepth.RunningDepth`) each 16-bit frame was restored at.

    A frame's depth depends on the frames before it: a frame added before
    finished ones (or one removed) changes it, and ``--resume`` must restore
    those again rather than keep them at the old scale. One JSON line per
    restored 16-bit frame, appended before its output is handed on (a kill
    leaves a line for a frame without output: it is redone, the later line wins).
    """

    def __init__(self, out_dir: Path) -> None:
        self.path = Path(out_dir) / DEPTHS_NAME
        self.bits: dict[str, int] = {}
        self.redone = 0  # finished frames whose depth changed: restored again
        if self.path.is_file():
            for line in self.path.read_text(encoding="utf-8").splitlines():
                try:
                    name, bits = json.loads(line)
                    self.bits[str(name)] = int(bits)
                except (ValueError, TypeError):  # a line cut by a kill
                    continue

    def same(self, frame: InputFrame, bits: int) -> bool:
        """Whether a finished ``frame`` was restored at ``bits`` (frames of before: assumed)."""
        if frame.image is None or frame.image.dtype != np.uint16:
            return True
        if self.bits.get(frame.name, bits) == bits:
            return True
        self.redone += 1
        return False

    def record(self, frames: Iterable[InputFrame], bits: int) -> None:
        """Note that the 16-bit ones of ``frames`` are being restored at ``bits``."""
        names = [
            frame.name
            for frame in frames
            if frame.image is not None and frame.image.dtype == np.uint16
        ]
        if not names:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with naming_errors(self.path), self.path.open("a", encoding="utf-8") as journal:
            journal.write("".join(json.dumps([name, bits]) + "\n" for name in names))
        self.bits.update(dict.fromkeys(names, bits))


def kept_bag_report(
    out_dir: Path,
    input_path: Path,
    kind: InputKind,
    sink: BagSink,
    backend: Backend,
    cameras: tuple[CameraName, ...],
    settings: dict[str, Any],
) -> RestoreReport | None:
    """``--resume``: the report that keeps the bag a complete run wrote, or None to write it.

    A bag is written in one pass, and its cache is gone once complete:
    without this, resuming a finished run restored every frame again. The
    bag is kept while the files it was read from and the bag written are
    unchanged (:meth:`~lenspair.model.inference.bag_sink.BagSink.finished`).
    """
    finished = _finished_report(out_dir)
    if finished is None or not sink.finished(
        finished.get("source_files"), finished.get("output_files")
    ):
        return None
    return _kept(finished, input_path, kind, sink, backend, cameras, settings)


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
    tile = finished.get("forced_tile")  # the kept bag's frames ran on those tiles
    report.forced_tile = tile if isinstance(tile, str) else None
    report.settings = settings
    report.source_files = sink.fingerprint
    report.output_files = sink.written()
    return report
