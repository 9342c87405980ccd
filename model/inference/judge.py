"""The hook for ``--only-obstructed``: something that says whether a frame is obstructed.

``lenspair restore --only-obstructed`` restores only frames a
:class:`FrameJudge` calls obstructed and copies the others unchanged. The
anomaly detector (issue 14) is to provide the real judge through
:func:`default_judge`; until it is merged that function refuses with a
one-line error, and the library accepts any judge
(``restore_input(..., judge=...)``), e.g. :class:`ThresholdJudge` in tests.
"""

from typing import Protocol

import numpy as np

from lenspair.capture.frames import InputFrame
from lenspair.model.errors import ModelError


class FrameJudge(Protocol):
    """Frames in, obstructed yes/no out."""

    def __call__(self, frame: InputFrame, image: np.ndarray) -> bool:
        """True when ``image`` (``frame``'s pixels, imageio convention) is obstructed."""


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


def default_judge() -> FrameJudge:
    """The judge ``--only-obstructed`` uses.

    TODO(issue 14): return the anomaly detector's judge once it is merged.

    Raises:
        ModelError: always, for now: there is no detector in this build.
    """
    raise ModelError(
        "--only-obstructed needs the anomaly detector (lenspair detect, issue 14), "
        "which this build does not have yet; restore every frame instead"
    )
