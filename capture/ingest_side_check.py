"""An ingest's side check: the declared obstructed camera checked against a few frame pairs.

:func:`check_side` reads up to :data:`SIDE_CHECK_FRAMES` readable pairs among
those the homography was estimated from, leaves out pairs with a blank view,
and hands them to the detail-ratio check
(:func:`lenspair.capture.side_check.check_obstructed_side`) or, when given, a
trained detector (:func:`lenspair.capture.side_detector.check_side_with_detector`).
A mismatch is only said (in the log and in ``report.json``), never fatal.
"""

import logging
from typing import Any

import cv2
import numpy as np

from lenspair.capture import ingest_frames as frame_work
from lenspair.capture.recording import FrameRef, Recording, load_frame
from lenspair.capture.rigfile import CameraName
from lenspair.capture.side_check import check_obstructed_side
from lenspair.capture.side_detector import ObstructedProbability, check_side_with_detector
from lenspair.core.bitdepth import widen
from lenspair.core.config import to_plain
from lenspair.core.errors import LenspairError
from lenspair.core.quality import is_blank
from lenspair.core.spread import spread_indices

log = logging.getLogger(__name__)

SIDE_CHECK_FRAMES = 8


def check_side(
    recording: Recording,
    frame_pairs: list[tuple[FrameRef, FrameRef]],
    context: frame_work.Context,
    obstructed: CameraName,
    max_frames: int,
    side_detector: ObstructedProbability | None,
) -> dict[str, Any]:
    """Check that ``obstructed`` is the camera whose frames show the anomaly.

    Args:
        recording: the recording (named in the log).
        frame_pairs: every ``(obstructed, clean)`` frame pair.
        context: the frame work's context (image sizes, bit depth).
        obstructed: the declared obstructed camera.
        max_frames: how many pairs the homography was sampled from
            (``EstimationParams.max_frames``); the check reads among the same.
        side_detector: a trained detector, or None for the detail ratio.

    Returns:
        The check as ``report.json``'s ``side_check`` holds it, with
        ``blank_pairs_left_out``; ``mismatch`` False when nothing was checked.
    """
    chosen = [frame_pairs[i] for i in spread_indices(len(frame_pairs), max_frames)]
    images0, images1, blank = _side_check_images(chosen, context, SIDE_CHECK_FRAMES)
    nothing = "no readable frame pair to check"
    if blank:
        nothing = f"every readable frame pair checked ({blank}) has a blank view; side not checked"
    side_check: dict[str, Any] = {"message": nothing, "mismatch": False}
    if images0:
        side: Any = (
            check_obstructed_side(images0, images1, obstructed)
            if side_detector is None
            else check_side_with_detector(images0, images1, obstructed, side_detector)
        )
        side_check = to_plain(side)
        if side.mismatch:
            log.warning("%s: %s", recording.path, side.message)
    elif blank:
        log.warning("%s: %s (a camera or exposure fault?)", recording.path, nothing)
    side_check["blank_pairs_left_out"] = blank
    return side_check


def _side_check_images(
    pairs: list[tuple[FrameRef, FrameRef]], context: frame_work.Context, count: int
) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """Raw cam0 and cam1 images of ``count`` readable pairs spread over ``pairs``.

    ``count`` pairs spread over the whole list are read first, then the others
    in order in place of unreadable or blank ones: the first ``count`` of 30
    sampled pairs lay in a recording's first quarter, and glass that got wet
    later went unseen (the declared side confirmed, input and target swapped).
    Cameras of different resolutions are compared at the coarser one's (:func:`_one_size`).

    A pair with a blank view (:func:`lenspair.core.quality.is_blank`: lens cap,
    exposure fault) is left out: it says nothing about the glass, and a black
    frame has less detail than any other. The third value counts those pairs.
    """
    images: dict[str, list[np.ndarray]] = {"cam0": [], "cam1": []}
    blank = 0
    first = spread_indices(len(pairs), count)
    order = first + sorted(set(range(len(pairs))) - set(first))
    for pair in (pairs[index] for index in order):
        if len(images["cam0"]) == count:
            break
        try:
            loaded = [widen(load_frame(frame), context.bits_of(frame.camera)) for frame in pair]
        except LenspairError:
            continue
        sizes = [(image.shape[1], image.shape[0]) for image in loaded]
        if sizes != [context.raw_size(frame.camera) for frame in pair]:
            continue
        if any(is_blank(image) for image in loaded):
            blank += 1
            continue
        for frame, image in zip(pair, _one_size(loaded), strict=True):
            images[frame.camera].append(image)
    return images["cam0"], images["cam1"], blank


def _one_size(images: list[np.ndarray]) -> list[np.ndarray]:
    """The views at the smaller one's size (the larger reduced by pixel area).

    Detail per pixel falls as resolution rises: a rig whose clean camera had
    twice the resolution had its clean view judged the blurrier one.
    """
    width = min(image.shape[1] for image in images)
    height = min(image.shape[0] for image in images)
    return [
        image
        if image.shape[:2] == (height, width)
        else np.asarray(cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA))
        for image in images
    ]
