"""The side check that uses a detector (capture-ingest --detector)."""

from collections.abc import Sequence

import numpy as np
import pytest

from lenspair.capture.errors import CaptureError
from lenspair.capture.side_detector import check_side_with_detector


def _frames(level: int, count: int = 3) -> list[np.ndarray]:
    return [np.full((8, 8), level, np.uint8) for _ in range(count)]


def _by_level(images: Sequence[np.ndarray]) -> np.ndarray:
    """A stand-in detector: the probability is the frame's level / 255."""
    return np.array([float(image.mean()) / 255.0 for image in images])


def test_infers_the_side_the_detector_points_to() -> None:
    result = check_side_with_detector(_frames(20), _frames(230), "cam1", _by_level)
    assert (result.inferred, result.agrees, result.mismatch) == ("cam1", True, False)
    assert result.confidence == pytest.approx(210 / 255, abs=1e-3)
    assert result.num_frames == 3 and result.method == "detector"


def test_flags_a_swapped_declaration() -> None:
    result = check_side_with_detector(_frames(20), _frames(230), "cam0", _by_level)
    assert result.inferred == "cam1" and result.mismatch
    assert "check rig.yaml" in result.message


# (13, 90): p 0.05 and 0.35, far apart but neither camera called obstructed: no side
@pytest.mark.parametrize(("level0", "level1"), [(20, 40), (200, 230), (100, 120), (13, 90)])
def test_undetermined_when_both_agree_or_too_close(level0: int, level1: int) -> None:
    result = check_side_with_detector(_frames(level0), _frames(level1), "cam1", _by_level)
    assert result.inferred == "undetermined"
    assert result.agrees is None and not result.mismatch and result.confidence == 0.0


def test_needs_paired_frames() -> None:
    with pytest.raises(CaptureError, match="same, non-zero number"):
        check_side_with_detector(_frames(1, 2), _frames(1, 3), "cam1", _by_level)
