"""Checking the declared obstructed camera with a trained anomaly detector.

The detail-ratio check of :mod:`lenspair.capture.side_check` needs the two
views to differ in fine detail tile by tile; light rain on a textured scene
barely changes the Laplacian energy, and the check answers "undetermined".
A detector (``capture-ingest --detector MODEL``) judges each view on its own:
for the same frame pairs, the mean probability that the glass is obstructed
is computed per camera, ``p0`` and ``p1``. The camera with the larger mean
is inferred when that mean reaches ``min_probability`` (0.5) and exceeds the
other's by ``margin`` (0.25); the confidence is ``|p1 - p0|`` (in ``[0, 1]``).
Otherwise the answer is ``undetermined`` (both clean, both obstructed, or
too close to call). As with the detail check, a mismatch is reported, never
fatal.

This module takes the detector as a plain function (images in, probabilities
out) so that ``capture`` does not import torch; the CLI builds it with
:func:`lenspair.model.detection.judge.judge`.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from lenspair.capture.errors import CaptureError
from lenspair.capture.rigfile import CameraName
from lenspair.capture.side_check import Inferred, side_message

ObstructedProbability = Callable[[Sequence[np.ndarray]], np.ndarray]
"""Frames (``uint8``/``uint16``, grey or RGB) -> ``(N,)`` probabilities of an obstructed glass."""


@dataclass(frozen=True)
class DetectorSideCheck:
    """Outcome of :func:`check_side_with_detector`.

    Attributes:
        declared: the camera ``rig.yaml`` or ``--obstructed`` names.
        inferred: the camera the detector points to, or ``undetermined``.
        confidence: ``|p1 - p0|`` when a side is inferred, else 0.
        agrees: ``inferred == declared``; None when undetermined.
        mismatch: True when a side was inferred and it is not the declared one.
        probability_cam0: mean probability that cam0's glass is obstructed.
        probability_cam1: the same for cam1.
        num_frames: frame pairs judged.
        method: ``detector``.
        message: one line for people and reports.
    """

    declared: CameraName
    inferred: Inferred
    confidence: float
    agrees: bool | None
    mismatch: bool
    probability_cam0: float
    probability_cam1: float
    num_frames: int
    method: str
    message: str


def check_side_with_detector(
    images_cam0: Sequence[np.ndarray],
    images_cam1: Sequence[np.ndarray],
    declared: CameraName,
    obstructed_probability: ObstructedProbability,
    *,
    min_probability: float = 0.5,
    margin: float = 0.25,
) -> DetectorSideCheck:
    """Infer the obstructed camera with a detector and compare with the declared one.

    Args:
        images_cam0: cam0 views of a few frame pairs.
        images_cam1: the cam1 views of the same pairs (same count).
        declared: the camera said to be obstructed.
        obstructed_probability: the detector, as a function (module docstring).
        min_probability: mean probability the inferred side must reach.
        margin: how much it must exceed the other side's.

    Returns:
        The :class:`DetectorSideCheck`.

    Raises:
        CaptureError: no frames, or different numbers of frames per camera.
    """
    if len(images_cam0) != len(images_cam1) or not images_cam0:
        raise CaptureError(
            "side check needs the same, non-zero number of frames per camera, "
            f"got {len(images_cam0)} and {len(images_cam1)}"
        )
    p0 = float(np.mean(obstructed_probability(images_cam0)))
    p1 = float(np.mean(obstructed_probability(images_cam1)))
    inferred: Inferred = "undetermined"
    if max(p0, p1) >= min_probability and abs(p1 - p0) >= margin:
        inferred = "cam1" if p1 > p0 else "cam0"
    confidence = abs(p1 - p0) if inferred != "undetermined" else 0.0
    shares = f"detector: p(obstructed) cam0 {p0:.2f}, cam1 {p1:.2f} over {len(images_cam0)} pairs"
    agrees, message = side_message(declared, inferred, shares)
    return DetectorSideCheck(
        declared=declared,
        inferred=inferred,
        confidence=round(confidence, 4),
        agrees=agrees,
        mismatch=agrees is False,
        probability_cam0=round(p0, 4),
        probability_cam1=round(p1, 4),
        num_frames=len(images_cam0),
        method="detector",
        message=message,
    )
