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
   to 30 frames (:mod:`lenspair.capture.ingest_registration`), cached in
   ``registration.json`` with a fingerprint of what it was computed from;
4. choose the crop (:func:`lenspair.rectify.crop.choose_crop`) and compose one map per
   view (:mod:`lenspair.rectify.remap`);
5. check the declared obstructed side against the images
   (:mod:`lenspair.capture.ingest_side_check`);
6. per frame (:mod:`lenspair.capture.ingest_pairs` running
   :mod:`lenspair.capture.ingest_frames`, in a process pool with ``workers > 1``):
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
a second run is refused at once. Where the run may write, and what a failed
run leaves there, is :mod:`lenspair.capture.ingest_output`'s.
"""

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lenspair import __version__
from lenspair.capture import ingest_frames as frame_work
from lenspair.capture.errors import CaptureError
from lenspair.capture.exposure import summarise_exposure
from lenspair.capture.ingest_input import PairedRecording, open_and_pair
from lenspair.capture.ingest_output import discard_new_output, output_folder
from lenspair.capture.ingest_pairs import run_frame_stage
from lenspair.capture.ingest_registration import (
    recording_bits,
    recording_homography,
    sampled_pairs,
    size_mismatch,
    warn_if_doubtful,
    warn_if_enlarged,
)
from lenspair.capture.ingest_report import (
    camera_problems,
    frame_counts,
    in_output_pixels,
    rejection_reasons,
    set_report_aside,
    write_report_if_changed,
)
from lenspair.capture.ingest_side_check import check_side
from lenspair.capture.ingested import PAIRS_FILE, REPORT_FILE, IngestReport, PairRecord
from lenspair.capture.journal import fingerprint, hold_output, remove_temporaries
from lenspair.capture.qa import QA_FILE, write_qa_sheet
from lenspair.capture.rigfile import CameraName
from lenspair.capture.side_detector import ObstructedProbability
from lenspair.core.config import to_plain
from lenspair.rectify.crop import Crop, choose_crop
from lenspair.rectify.errors import CropError, RectifyError
from lenspair.rectify.rectification import on_camera
from lenspair.rectify.registration import EstimationParams, VerifyParams
from lenspair.rectify.remap import target_map, valid_region
from lenspair.rectify.rig import rig_to_kalibr

CAMERAS = ("cam0", "cam1")


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
    timings = _Timings()
    paired = open_and_pair(Path(recording_path), topics, obstructed, calibration, time_offset_ns)
    recording, rig_file = paired.recording, paired.rig_file
    out_dir, source = output_folder(out, recording)
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    with hold_output(out_dir):  # the whole run: one run at a time writes out_dir
        remove_temporaries(out_dir)
        timings.lap("open")

        registered = _register(paired, out_dir, created, estimation, verify, workers)
        timings.lap("homography")
        qa_sheet = out_dir / QA_FILE
        warn_if_doubtful(recording, registered.registration, paired.calibration_source, qa_sheet)
        crop, context = _crop_and_maps(paired, registered, size, verify, created)
        timings.lap("maps")
        side_check = check_side(
            recording,
            paired.frame_pairs,
            context,
            rig_file.obstructed,
            estimation.max_frames,
            side_detector,
        )
        timings.lap("side_check")

        set_report_aside(out_dir)  # until this run's report is written (its docstring)
        state, settings = _frame_settings(paired, registered, crop, size, time_offset_ns)
        ordered = run_frame_stage(
            recording,
            paired.pairing,
            rig_file,
            paired.frame_pairs,
            context,
            state,
            workers,
            settings,
        )
        timings.lap("frames")

        kept = [r for r in ordered if r.status == "kept"]
        if kept:
            write_qa_sheet(qa_sheet, out_dir, ordered)
        else:  # an earlier run's sheet would show pairs whose files this run removed
            qa_sheet.unlink(missing_ok=True)
        timings.lap("qa")
        timings.stop()

        report = _report(
            paired, source, registered, crop, ordered, side_check, timings.seconds, time_offset_ns
        )
        write_report_if_changed(out_dir / REPORT_FILE, report)
        if not kept:
            reasons = report.rejection_reasons
            raise CaptureError(
                f"{recording.path}: no usable pairs: all {len(ordered)} {rig_file.obstructed} "
                f"frames rejected ({', '.join(f'{k}: {v}' for k, v in sorted(reasons.items()))}); "
                f"see {out_dir / PAIRS_FILE}"
            )
        return report


class _Timings:
    """Seconds each stage of a run took, rounded to ms, as ``report.json`` keeps them."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.start = self.clock = time.perf_counter()

    def lap(self, stage: str) -> None:
        """Record the time since the last lap (or the start) as ``stage``'s."""
        now = time.perf_counter()
        self.seconds[stage] = round(now - self.clock, 3)
        self.clock = now

    def stop(self) -> None:
        """Record the time since the start as ``total``."""
        self.seconds["total"] = round(time.perf_counter() - self.start, 3)


@dataclass(frozen=True)
class _Registered:
    """What registering the two views gives the rest of the run.

    Attributes:
        context: the per-frame work's context (rectification, no crop yet).
        registration: the record of ``registration.json`` (matrix, counts).
        setup: what the registration and every frame's outputs are made with
            (calibration, side, thresholds, version; bits when under 16).
        bits: the bits each camera's 16-bit frames use.
    """

    context: frame_work.Context
    registration: dict[str, Any]
    setup: dict[str, Any]
    bits: dict[CameraName, int]


def _shared_bits(bits: dict[CameraName, int]) -> int | dict[CameraName, int]:
    """The bits both cameras' 16-bit frames use, or each camera's when they differ.

    One number where the two agree, as before depths were told per camera:
    the fingerprints of such recordings' outputs stay the same.
    """
    depths = set(bits.values())
    return depths.pop() if len(depths) == 1 else dict(sorted(bits.items()))


def _register(
    paired: PairedRecording,
    out_dir: Path,
    created: bool,
    estimation: EstimationParams,
    verify: VerifyParams,
    workers: int,
) -> _Registered:
    """Rectify, and estimate (or reuse) the recording's homography.

    Raises:
        RectifyError, CaptureError: the views cannot be registered at all,
            named with the calibration used (:func:`ingest_recording`).
    """
    recording, rig_file = paired.recording, paired.rig_file
    sampled = sampled_pairs(paired.frame_pairs)
    bits = recording_bits(recording, sampled)
    mismatch = size_mismatch(sampled, paired.rig)
    del sampled  # up to 64 frames, not needed from here on
    try:
        if mismatch is not None:  # before the calibration is used (size_mismatch)
            raise CaptureError(f"{recording.path}: no usable frame pair to register: {mismatch}")
        rectification = on_camera(paired.rig, rig_file.obstructed)
        context = frame_work.Context.build(
            out_dir, rig_file.obstructed, rectification, verify, bits
        )
        setup = {
            "calibration": rig_to_kalibr(paired.rig),
            "obstructed": rig_file.obstructed,
            "verify": to_plain(verify),
            "version": __version__,
        }
        shared = _shared_bits(bits)
        if shared != 16:  # only then: the outputs of other recordings keep their fingerprint
            setup["significant_bits"] = shared
        registration = recording_homography(
            recording, paired.frame_pairs, context, estimation, workers, out_dir, setup
        )
    except (RectifyError, CaptureError) as exc:
        # the views cannot be registered at all (no sampled pair is usable): no pair to write
        earlier = discard_new_output(out_dir, created)
        message = str(exc).removeprefix(f"{recording.path}: ")
        # the calibration is named: registration that fails everywhere is
        # as often a wrong or stale calibration as a scene that cannot be registered
        raise type(exc)(
            f"{recording.path}: {message} (with {paired.calibration_source}){earlier}"
        ) from None
    return _Registered(context, registration, setup, bits)


def _crop_and_maps(
    paired: PairedRecording,
    registered: _Registered,
    size: tuple[int, int],
    verify: VerifyParams,
    created: bool,
) -> tuple[Crop, frame_work.Context]:
    """The output crop, and the context with each view's composed map.

    Raises:
        CropError: no ``size`` crop fits where both views have data, named
            with the calibration used (:func:`ingest_recording`).
    """
    recording, rig, rig_file = paired.recording, paired.rig, paired.rig_file
    context = registered.context
    matrix = np.asarray(registered.registration["matrix"], dtype=np.float64)
    valid = valid_region(
        context.rectified_to_raw_obstructed,
        context.rectified_to_raw_clean,
        matrix,
        context.rectification.size,
        rig.camera(rig_file.obstructed).resolution,
        rig.camera(rig_file.clean).resolution,
    )
    try:
        crop = choose_crop(valid, size)
    except CropError as exc:
        earlier = discard_new_output(context.out_dir, created)
        raise CropError(
            f"{recording.path}: cannot crop {size[0]}x{size[1]}: {exc} (with "
            f"{paired.calibration_source}){earlier}"
        ) from None
    margin = int(np.ceil(verify.max_shift_px)) + 2
    target = target_map(context.rectified_to_raw_clean, matrix, crop, margin)
    warn_if_enlarged(recording, rig_file.clean, target)
    return crop, context.with_maps(crop, target)


def _frame_settings(
    paired: PairedRecording,
    registered: _Registered,
    crop: Crop,
    size: tuple[int, int],
    time_offset_ns: int,
) -> tuple[str, dict[str, Any]]:
    """``(state, settings)``: the hash every frame's key holds, and what it hashes, readable.

    ``settings`` also says what pairs the frames (the journal keeps it, to
    name what changed when a rerun processes finished frames again).
    """
    matrix = registered.registration["matrix"]
    setup = registered.setup
    state = fingerprint({**setup, "matrix": matrix, "crop": crop.as_tuple()})
    settings = {
        **setup,
        "significant_bits": _shared_bits(registered.bits),
        "calibration_source": paired.calibration_source,
        "size": list(size),
        "time_offset_ns": time_offset_ns,
        "matrix": matrix,
        "crop": crop.as_tuple(),
    }
    return state, settings


def _report(
    paired: PairedRecording,
    source: Path,
    registered: _Registered,
    crop: Crop,
    ordered: list[PairRecord],
    side_check: dict[str, Any],
    timings: dict[str, float],
    time_offset_ns: int,
) -> IngestReport:
    """The run's ``report.json``: counts, reasons, the homography in output pixels, timings."""
    recording, rig_file, registration = paired.recording, paired.rig_file, registered.registration
    counts = frame_counts(recording, paired.pairing, rig_file, ordered)
    counts["homography_frames"] = len(registration["frames"])
    counts["homography_matches"] = int(registration["matches"])
    counts["homography_inliers"] = int(registration["inliers"])
    counts["recording_problems"] = len(paired.problems)  # the clock warning too
    said_of_cameras = camera_problems(recording, rig_file.obstructed)
    counts["camera_problems"] = len(said_of_cameras)
    reasons = rejection_reasons(recording, ordered, rig_file.obstructed)
    matrix = np.asarray(registration["matrix"], dtype=np.float64)
    homography_out = in_output_pixels(matrix, crop.x, crop.y)
    shared = _shared_bits(registered.bits)
    return IngestReport(
        recording_id=recording.recording_id,
        source=str(source),  # absolute: tells a namesake apart
        obstructed=rig_file.obstructed,
        anomaly=rig_file.anomaly,
        calibration_source=paired.calibration_source,
        calibration=rig_to_kalibr(paired.rig),
        homography=homography_out.tolist(),
        crop=crop.as_tuple(),
        counts=counts,
        rejection_reasons=dict(sorted(reasons.items())),
        timings_s=timings,
        side_check=side_check,
        lenspair_version=__version__,
        significant_bits=shared if isinstance(shared, int) and shared < 16 else None,
        significant_bits_per_camera=dict(sorted(registered.bits.items())),
        topics={}
        if recording.topics is None
        else dict(zip(CAMERAS, recording.topics, strict=True)),
        recording_problems=paired.problems,
        camera_problems=said_of_cameras,
        time_offset_ns=time_offset_ns,
        exposure=summarise_exposure(recording.path, ordered),
    )
