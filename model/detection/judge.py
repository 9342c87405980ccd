"""Judging frames with a trained detector: batch of images in, numpy out.

:func:`judge` is the one entry point other commands use (``detect``, the
ingest side check, ``restore --only-obstructed``)::

    from lenspair.model.detection.judge import judge
    from lenspair.model.detection.train import load_detector

    detector = load_detector(Path("detector.pt"))
    verdict = judge(detector, [frame0, frame1])     # uint8/uint16, grey or RGB, any size
    keep = verdict.obstructed                       # bool (N,): worth restoring

Frames are converted to luma and resized to the detector's input size
(``DetectorSpec.input_size``: 270x180 by default, half a 540x360 frame)
before judging, so any camera resolution works; maps have one tile per 8
pixels of that size (16 pixels of a 540x360 frame).

A *blank* frame (all black, saturated, or otherwise nearly uniform: luma
standard deviation below 1/255 after resizing) carries no evidence about the
glass; it is flagged ``blank`` and never called obstructed, whatever the
network says, so that ``restore --only-obstructed`` skips it and a side
check is not swayed by it. The robot should treat a run of blank frames as a
camera or exposure fault, which is a different alarm.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from lenspair.core.quality import BLANK_STD
from lenspair.model.detection.data import prepare
from lenspair.model.networks.detector import KINDS, AnomalyDetector

OBSTRUCTED_THRESHOLD = 0.5
"""Probability above which a frame is called obstructed."""


@dataclass(frozen=True)
class Judgement:
    """The detector's answers for ``N`` frames (numpy, on the CPU).

    Attributes:
        probability: ``float32`` ``(N,)``, probability that the glass is obstructed.
        kind_probabilities: ``float32`` ``(N, len(KINDS))``, rows sum to 1.
        maps: ``float32`` ``(N, rows, cols)``, probability that a tile is covered.
        blank: ``bool`` ``(N,)``, nearly uniform frames (module docstring).
        threshold: the probability above which a frame is obstructed.
    """

    probability: np.ndarray
    kind_probabilities: np.ndarray
    maps: np.ndarray
    blank: np.ndarray
    threshold: float = OBSTRUCTED_THRESHOLD

    @property
    def obstructed(self) -> np.ndarray:
        """``bool`` ``(N,)``: probability above the threshold, and not blank."""
        return np.asarray((self.probability > self.threshold) & ~self.blank)

    @property
    def kinds(self) -> list[str]:
        """Most likely anomaly kind per frame; ``clean`` when not obstructed."""
        best_anomaly = 1 + np.argmax(self.kind_probabilities[:, 1:], axis=1)
        return [
            KINDS[int(k)] if hit else "clean"
            for k, hit in zip(best_anomaly, self.obstructed, strict=True)
        ]

    @property
    def obstructed_share(self) -> np.ndarray:
        """``float32`` ``(N,)``: fraction of tiles called covered (map > 0.5); 0 when clean."""
        share = (self.maps > 0.5).mean(axis=(1, 2)).astype(np.float32)
        return np.where(self.obstructed, share, np.float32(0.0))


def judge(
    network: AnomalyDetector,
    images: Sequence[np.ndarray],
    batch_size: int = 8,
    threshold: float = OBSTRUCTED_THRESHOLD,
) -> Judgement:
    """Judge frames with a detector.

    Args:
        network: a trained detector (any device; eval mode is set here).
        images: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)`` frames, sizes may differ.
        batch_size: frames per forward pass.
        threshold: obstructed above this probability.

    Returns:
        The :class:`Judgement` (empty arrays for no images).

    Raises:
        ValueError: an image breaks the :mod:`lenspair.core.pixels` convention.
    """
    spec = network.spec
    rows, cols = spec.grid
    device = next(network.parameters()).device
    network.eval()
    probabilities, kinds, maps, blanks = [], [], [], []
    with torch.inference_mode():
        for start in range(0, len(images), batch_size):
            chunk = [prepare(image, spec) for image in images[start : start + batch_size]]
            blanks.append(np.array([float(c.std()) < BLANK_STD for c in chunk], dtype=bool))
            batch = torch.from_numpy(np.stack(chunk))[:, None].to(device)
            output = network(batch)
            probabilities.append(output.obstructed.float().cpu().numpy())
            kinds.append(torch.softmax(output.kind_logits, dim=1).float().cpu().numpy())
            maps.append(torch.sigmoid(output.tile_logits).float().cpu().numpy())
    if not probabilities:
        return Judgement(
            np.zeros(0, np.float32),
            np.zeros((0, len(KINDS)), np.float32),
            np.zeros((0, rows, cols), np.float32),
            np.zeros(0, bool),
            threshold,
        )
    return Judgement(
        np.concatenate(probabilities),
        np.concatenate(kinds),
        np.concatenate(maps),
        np.concatenate(blanks),
        threshold,
    )


def obstructed_probability(
    network: AnomalyDetector,
) -> Callable[[Sequence[np.ndarray]], np.ndarray]:
    """``judge`` as a plain function, frames -> ``(N,)`` probabilities (for ingest).

    A blank frame's probability is 0: it is never called obstructed.
    """

    def probabilities(images: Sequence[np.ndarray]) -> np.ndarray:
        verdict = judge(network, images)
        return np.where(verdict.blank, 0.0, verdict.probability)  # blank: never obstructed

    return probabilities
