"""Curation under a clean camera exposed unlike the obstructed one (gain, darkness)."""

import cv2
import numpy as np
import pytest
from skimage import data

from lenspair.capture.ingested import PairRecord
from lenspair.dataset.config import CurationConfig
from lenspair.dataset.curation import Measured, curate, is_clean, measure_pair
from lenspair.simulate.effects.spec import (
    BrightnessSpec,
    EffectsSpec,
    RaindropsSpec,
    VeilSpec,
)
from lenspair.simulate.render import render_effects

CONFIG = CurationConfig()


def _photo(width: int = 240, height: int = 160) -> np.ndarray:
    """A natural RGB ``uint8`` photograph (scikit-image's astronaut), reduced."""
    return cv2.resize(data.astronaut(), (width, height), interpolation=cv2.INTER_AREA)


def _expose(image: np.ndarray, gain: float) -> np.ndarray:
    """``image`` as a camera with another gain records it (8-bit codes)."""
    exposed = image.astype(np.float64) * gain
    return np.clip(np.rint(exposed), 0, 255).astype(np.uint8)


@pytest.mark.parametrize(
    "effects",
    [
        EffectsSpec(veil=VeilSpec()),
        EffectsSpec(raindrops=RaindropsSpec(count=8), brightness=BrightnessSpec(fraction=1.0)),
    ],
    ids=["veil", "brightened-drops"],
)
@pytest.mark.parametrize("gain", [1.0, 0.85])
def test_veil_and_drops_are_not_clean_under_any_exposure(effects: EffectsSpec, gain: float) -> None:
    photo = _photo()
    obstructed, _ = render_effects(photo, effects, np.random.default_rng(3))
    stats = measure_pair(obstructed, _expose(photo, gain), None, CONFIG.anomaly_delta)
    assert not is_clean(stats, CONFIG)


def _duplicates(shifts: list[float], gain: float) -> set[int]:
    """Indices ``curate`` removes as duplicates from a slow pan over the photo (``shifts``, px)."""
    photo = _photo().astype(np.float32)
    items = []
    for index, shift in enumerate(shifts):
        moved = cv2.warpAffine(photo, np.float32([[1, 0, -shift], [0, 1, 0]]), (240, 160))
        target = _expose(moved, gain)
        stats = measure_pair(target, target, None, CONFIG.anomaly_delta)
        items.append(Measured(0, index, PairRecord(10 * (index + 1), "kept"), {}, {}, stats))
    removed = curate(items, CONFIG)
    return {index for (_, index), (rule, _) in removed.items() if rule == "duplicate"}


def test_duplicates_do_not_depend_on_exposure() -> None:
    # steps of a tenth of a pixel (a robot standing still) and of three tenths (creeping on)
    shifts = [0.0, 0.1, 0.4, 0.5, 0.8, 0.9, 1.2, 1.3]
    normal = _duplicates(shifts, 1.0)
    assert normal and len(normal) < len(shifts) - 1  # some frames kept, some removed
    assert _duplicates(shifts, 0.5) == normal
