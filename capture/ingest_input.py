"""What an ingest reads: the recording in its calibration's camera order, its frames paired.

:func:`open_and_pair` opens the recording (:mod:`lenspair.capture.recording`),
finds its ``rig.yaml`` and calibration (:mod:`lenspair.capture.calibration_source`),
turns a bag read with its topics the other way round from the calibration's
back, saying so in the log (or refuses ``--topics`` given so), says the
recording's problems in the log, and pairs the two cameras' frames by timestamp
(:mod:`lenspair.capture.pairing`), ``--time-offset`` applied.
"""

import logging
import re
import statistics
from dataclasses import dataclass
from pathlib import Path

from lenspair.capture.calibration_source import find_calibration, stated_topics
from lenspair.capture.errors import AmbiguousTopicsError, CaptureError
from lenspair.capture.ingest_report import untimed_frames
from lenspair.capture.pairing import (
    PairingResult,
    check_frame_period,
    clock_offset_warning,
    estimate_period_ns,
    pair_frames,
)
from lenspair.capture.recording import FrameRef, Recording, open_recording, resolve_obstructed
from lenspair.capture.rigfile import RigFile
from lenspair.rectify.rig import StereoRig

log = logging.getLogger(__name__)

MAX_LOGGED_PROBLEMS = 10
SINGLE_FRAME_TOLERANCE_NS = 10_000_000
"""Pairing tolerance when the frame period cannot be estimated (one frame per camera)."""


@dataclass(frozen=True)
class PairedRecording:
    """A recording in its calibration's camera order, its frames paired by time.

    Attributes:
        recording: the recording, cam0 and cam1 as the calibration has them.
        rig_file: its ``rig.yaml`` (the obstructed side as given).
        rig: the calibration.
        calibration_source: where the calibration came from, as reports name it.
        pairing: every frame paired or unpaired.
        frame_pairs: ``(obstructed frame, clean frame)`` of every pair, in time order.
        problems: what is said of the recording as a whole (``report.json``'s
            ``recording_problems``).
    """

    recording: Recording
    rig_file: RigFile
    rig: StereoRig
    calibration_source: str
    pairing: PairingResult
    frame_pairs: list[tuple[FrameRef, FrameRef]]
    problems: list[str]


def open_and_pair(
    recording_path: Path,
    topics: tuple[str, str] | None,
    obstructed: str | None,
    calibration: tuple[Path, ...],
    time_offset_ns: int,
) -> PairedRecording:
    """Open the recording and its calibration, say its problems, and pair its frames.

    Args:
        recording_path: EuRoC/ASL folder, bag, or left/right folders.
        topics: bag topics ``(cam0, cam1)`` (``--topics``); None picks them.
        obstructed: ``cam0``/``cam1`` overriding ``rig.yaml``.
        calibration: calibration files (``--calib``); empty: rig.yaml / camchain.yaml.
        time_offset_ns: how far cam1's clock runs ahead of cam0's, ns.

    Raises:
        CaptureError: unreadable recording, no calibration, a ``time_offset_ns``
            that leaves no pair where the stamps pair without it, a frame period
            that cannot be paired, or ``--topics`` the other way round from
            the calibration's.
    """
    try:
        recording = open_recording(recording_path, topics)
    except AmbiguousTopicsError as exc:
        try:
            rig_file = resolve_obstructed(Path(recording_path), obstructed)
        except CaptureError:  # said once the topics are named; the ambiguity first
            raise exc from None
        stated = stated_topics(Path(recording_path), rig_file, calibration)
        if stated is None:
            raise
        if not set(stated) <= set(exc.topics):
            raise AmbiguousTopicsError(
                f"{exc} (the calibration states {stated[0]} and {stated[1]}, not both in the bag)",
                exc.topics,
            ) from None
        recording = open_recording(recording_path, stated)  # the calibration's cameras
        log.info("%s: cam0 %s and cam1 %s, as the calibration states", recording.path, *stated)
    rig_file = resolve_obstructed(recording.path, obstructed)
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
        # which physical camera becomes the input changes here: said, and kept in report.json
        log.warning(
            "%s: topic %s is read as cam0 and %s as cam1, the other way round from the "
            "order they were picked in, because the calibration's rostopic states it (%s)",
            recording.path,
            rig.topics[0],
            rig.topics[1],
            calibration_source,
        )
    _say_problems(recording)
    stamps0, stamps1 = recording.timestamps("cam0"), recording.timestamps("cam1")
    period = estimate_period_ns(stamps0, stamps1)
    check_frame_period(period, recording.path)
    shifted1 = [t - time_offset_ns for t in stamps1]  # on cam0's clock
    pairing = pair_frames(stamps0, shifted1, None if period else SINGLE_FRAME_TOLERANCE_NS)
    if not pairing.pairs and time_offset_ns and pair_frames(stamps0, stamps1).pairs:
        # the offset moved every frame out of reach: the one cause worth naming
        raise CaptureError(
            f"{recording.path}: --time-offset {time_offset_ns / 1e6:g} ms leaves no cam0 frame "
            "within pairing tolerance of a cam1 frame (without it they pair): the offset is "
            "how far cam1's clock runs ahead of cam0's, in milliseconds"
        )
    if not pairing.pairs and stamps0 and stamps1:
        raise CaptureError(_nothing_paired(recording.path, stamps0, shifted1, time_offset_ns))
    said_of_recording = [str(p) for p in recording.problems if p.camera is None]
    # pairs.jsonl names frames by time: one without a time is named here, with its file
    said_of_recording += untimed_frames(recording, rig_file.obstructed)
    if offset := clock_offset_warning(pairing.pairs, period):
        log.warning("%s: %s", recording.path, offset)
        said_of_recording.append(offset)  # report.json keeps it
    if rectified := rectified_topics_note(recording.topics):
        log.warning("%s: %s", recording.path, rectified)
        said_of_recording.append(rectified)
    frame_pairs = []  # (obstructed frame, clean frame)
    for pair in pairing.pairs:
        both = (recording.frames["cam0"][pair.index0], recording.frames["cam1"][pair.index1])
        frame_pairs.append(both if rig_file.obstructed == "cam0" else (both[1], both[0]))
    return PairedRecording(
        recording, rig_file, rig, calibration_source, pairing, frame_pairs, said_of_recording
    )


def _nothing_paired(path: Path, stamps0: list[int], shifted1: list[int], offset_ns: int) -> str:
    """Why no frame pairs: the cameras' spans on cam0's clock, and how far apart they are.

    It said "no frame of the two cameras could be paired" alone, with no word
    of the clocks, where ``calibrate`` names ``--time-offset``.
    """
    gap_ms = (statistics.median(shifted1) - statistics.median(stamps0)) / 1e6
    given = f" (with --time-offset {offset_ns / 1e6:g} ms)" if offset_ns else ""
    return (
        f"{path}: no cam0 frame lies within pairing tolerance of a cam1 frame{given}: cam0's "
        f"frames span {(max(stamps0) - min(stamps0)) / 1e9:.3g} s, cam1's "
        f"{(max(shifted1) - min(shifted1)) / 1e9:.3g} s, their middles {gap_ms:+.6g} ms apart; "
        "if the cameras' clocks differ, give how far cam1's runs ahead of cam0's in ms "
        "with --time-offset"
    )


RECTIFIED_NAME = re.compile(r"(^|[/_])rect(ified)?([/_]|$)")
"""A topic named as rectified already: ``image_rect``, ``image_rect_color``, ``image_rect_raw``."""


def rectified_topics_note(topics: tuple[str, str] | None) -> str | None:
    """A warning for camera topics named as rectified already, or None.

    stereo_image_proc and a RealSense's infrared streams publish rectified
    images (``image_rect``, ``image_rect_raw``); a calibration of the raw
    cameras (as Kalibr's camchain is) would undistort and rectify them a
    second time, warping every frame, with no error to tell. Said, not refused:
    a calibration made for the rectified images is right for them.
    """
    named = [topic for topic in topics or () if RECTIFIED_NAME.search(topic)]
    if not named:
        return None
    return (
        f"camera topic(s) {', '.join(named)} named as rectified already: capture-ingest "
        "undistorts and rectifies them with the calibration again; record the raw topics "
        "(image_raw), or calibrate the rectified images themselves"
    )


def _say_problems(recording: Recording) -> None:
    """Log the first :data:`MAX_LOGGED_PROBLEMS` of the recording's problems; count the rest."""
    for problem in recording.problems[:MAX_LOGGED_PROBLEMS]:
        log.warning("%s", problem)
    if len(recording.problems) > MAX_LOGGED_PROBLEMS:
        more = len(recording.problems) - MAX_LOGGED_PROBLEMS
        log.warning(
            "%s: %d more problems (each in report.json, or pairs.jsonl for the obstructed "
            "camera's frames)",
            recording.path,
            more,
        )


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
