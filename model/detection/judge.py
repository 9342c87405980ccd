"""Judging frames with a trained detector: batch of images in, numpy out.

:func:`judge` is the one entry point other commands use (``detect``, the
ingest side check, ``restore --only-obstructed``)::

    from lenspair.model.detection.judge import judge
    from lenspair.model.detection.train import load_detector

    detector = load_detector(Path("detector.pt"))
    verdict = judge(detector, [frame0, frame1])     # uint8/uint16, grey or RGB, any size
    keep = verdict.obstructed                       # bool (N,): worth restoring

Colour frames are RGB: convert OpenCV's BGR first
(``cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)``), or the luma weights fall on the
wrong channels and the verdicts change. ``uint16`` frames holding 10- or
12-bit values (``mono16`` words of a Mono10/Mono12 camera) are widened to the
full 16-bit scale first, as ``detect`` does (:mod:`lenspair.core.bitdepth`);
read as they are, they would all be nearly black, hence blank.

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

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from lenspair.core.bitdepth import BIT_DEPTHS, is_bit_depth, significant_bits, widen
from lenspair.core.numbers import is_whole_number
from lenspair.core.pixels import check_image, is_one_frame
from lenspair.core.quality import BLANK_STD
from lenspair.model.detection.data import prepare
from lenspair.model.networks.detector import KINDS, AnomalyDetector
from lenspair.model.networks.padding import MIN_SIDE

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


def size_problem(image: np.ndarray) -> str | None:
    """Why ``image`` is too small to judge, or None: restore's minimum, ``MIN_SIDE`` a side.

    The detector scales every frame to its input size: a 5x5 or 1x40 frame came
    back with a confident "clean" that restore, reading the same folder, refused.
    """
    height, width = image.shape[:2]
    if min(height, width) < MIN_SIDE:
        return f"{width}x{height} pixels, smaller than the {MIN_SIDE}x{MIN_SIDE} minimum"
    return None


def judge(
    network: AnomalyDetector,
    images: Iterable[np.ndarray],
    batch_size: int = 8,
    threshold: float = OBSTRUCTED_THRESHOLD,
    bits: int | None = None,
) -> Judgement:
    """Judge frames with a detector.

    Args:
        network: a trained detector (any device; eval mode is set here).
        images: ``uint8``/``uint16`` ``(H, W)`` grey or ``(H, W, 3)`` RGB frames
            (convert OpenCV's BGR), sizes may differ; a list or any iterable.
        batch_size: frames per forward pass (at least 1).
        threshold: obstructed above this probability.
        bits: the bits the ``uint16`` frames use (10, 12 or 16); they are
            widened to the full 16-bit scale (:func:`lenspair.core.bitdepth.widen`)
            before judging, as ``detect`` does; ``uint8`` frames are judged as
            they are. Default: :func:`lenspair.core.bitdepth.significant_bits`
            of this call's frames, 10 or 12 when every frame is ``uint16`` and
            no value exceeds that depth, else 16 (as they are). Pass 16 for
            frames already on the full scale: a genuine 16-bit frame whose
            brightest pixel is below 4096 would be brightened.

    Returns:
        The :class:`Judgement` (empty arrays for no images).

    Raises:
        ValueError: an image breaks the :mod:`lenspair.core.pixels` convention
            (the message names its index in ``images``: ``frame 3: ...``),
            ``images`` is one frame, not a list of them, ``bits`` is not 10,
            12 or 16, or ``batch_size`` is not a whole number >= 1.
    """
    if isinstance(images, np.ndarray) and is_one_frame(images):
        raise ValueError(
            f"judge takes a list of frames, got one {images.shape} array: judge(detector, [frame])"
        )
    if not is_whole_number(batch_size) or batch_size < 1:
        raise ValueError(f"batch_size: expected a whole number of frames >= 1, got {batch_size!r}")
    images = list(images)  # a generator too: the frames are gone over more than once
    if bits is not None and not is_bit_depth(bits):
        raise ValueError(f"bits: expected one of {', '.join(map(str, BIT_DEPTHS))}, got {bits!r}")
    for index, image in enumerate(images):
        check_image(image, f"frame {index}")
        if (problem := size_problem(image)) is not None:
            raise ValueError(f"frame {index}: {problem}")
    if bits is None:
        bits = significant_bits(list(images))
    spec = network.spec
    rows, cols = spec.grid
    device = next(network.parameters()).device
    network.eval()
    probabilities, kinds, maps, blanks = [], [], [], []
    with torch.inference_mode():
        for start in range(0, len(images), batch_size):
            frames = images[start : start + batch_size]
            chunk = [prepare(widen(image, bits), spec) for image in frames]
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

    The frames are taken as they are (``bits=16``): ingest widens 16-bit frames
    of 10- or 12-bit values with the depth told from its sampled pairs, and a
    dim frame must not be widened a second time. A blank frame's probability
    is 0: it is never called obstructed.
    """

    def probabilities(images: Sequence[np.ndarray]) -> np.ndarray:
        verdict = judge(network, images, bits=16)  # already on the full scale (docstring)
        return np.where(verdict.blank, 0.0, verdict.probability)  # blank: never obstructed

    return probabilities
