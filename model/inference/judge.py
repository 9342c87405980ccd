"""The hook for ``--only-obstructed``: something that says whether a frame is obstructed.

``lenspair restore --only-obstructed`` restores only frames a
:class:`FrameJudge` calls obstructed and copies the others unchanged. The
real judge is the anomaly detector (``lenspair train-detector``), wrapped by
:class:`DetectorJudge`; the library accepts any judge
(``restore_input(..., judge=...)``), e.g. :class:`ThresholdJudge` in tests.
"""

from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from lenspair.capture.frame_types import InputFrame
from lenspair.model.detection.judge import judge
from lenspair.model.detection.train import load_detector
from lenspair.model.networks.detector import AnomalyDetector


class FrameJudge(Protocol):
    """Frames in, obstructed yes/no out."""

    def __call__(self, frame: InputFrame, image: np.ndarray) -> bool:
        """True when ``image`` (``frame``'s pixels, core.pixels convention) is obstructed."""


class ThresholdJudge:
    """A trivial judge: obstructed when the mean code value is below ``threshold``.

    Args:
        threshold: fraction of the full code range, in [0, 1].
    """

    def __init__(self, threshold: float) -> None:
        self.threshold = threshold

    def __call__(self, frame: InputFrame, image: np.ndarray) -> bool:
        """True when the image is darker on average than the threshold."""
        top = float(np.iinfo(image.dtype).max)
        return bool(float(image.mean()) / top < self.threshold)


class DetectorJudge:
    """The anomaly detector as a :class:`FrameJudge` (``--only-obstructed MODEL``).

    A frame is obstructed when the detector's probability exceeds its threshold
    (:data:`lenspair.model.detection.judge.OBSTRUCTED_THRESHOLD`); blank frames
    (all black, saturated) are never obstructed.

    Args:
        network: a trained detector (:func:`lenspair.model.detection.train.load_detector`).
        path: the file it was loaded from, if any: ``restore --resume`` compares its hash.
    """

    def __init__(self, network: AnomalyDetector, path: Path | None = None) -> None:
        self.network = network
        self.path = path

    def __call__(self, frame: InputFrame, image: np.ndarray) -> bool:
        """True when the detector calls ``image`` obstructed (widened already: ``bits=16``)."""
        # the batching stage widened the frame to the run's bit depth: widening it again
        # by its own brightest pixel would brighten a dark 16-bit frame up to 64x
        return bool(judge(self.network, [image], bits=16).obstructed[0])


def default_judge(model: Path, device: torch.device) -> FrameJudge:
    """The judge ``--only-obstructed MODEL`` uses: the detector saved at ``model``.

    Raises:
        ModelError: ``model`` is not a readable lenspair detector.
    """
    return DetectorJudge(load_detector(model, device), Path(model))
