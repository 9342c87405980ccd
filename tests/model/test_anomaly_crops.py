"""Training crops drawn on the anomaly: every such crop holds a pixel where the pair differs."""

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.model.training.config import DataConfig
from lenspair.model.training.pairs import PairedCrops, anomaly_crop_box, crop_box, item_rng


@dataclass(frozen=True)
class _Pair:
    input: np.ndarray
    target: np.ndarray
    name: str = "pair"
    mask: np.ndarray | None = None
    difficulty: str | None = None


def _pair(shape: tuple[int, int], blob: tuple[int, int, int], masked: bool = False) -> _Pair:
    """Textured clean view; the input has a bright square blob (top, left, side)."""
    rng = np.random.default_rng(0)
    target = rng.integers(60, 120, shape, dtype=np.uint8)
    obstructed = target.copy()
    top, left, side = blob
    obstructed[top : top + side, left : left + side] = 250
    mask = None
    if masked:
        mask = np.zeros(shape, np.uint8)
        mask[top : top + side, left : left + side] = 255  # the differing pixels are untrustworthy
    return _Pair(obstructed, target, mask=mask)


def _holds_blob(box: tuple[int, int, int, int], blob: tuple[int, int, int]) -> bool:
    top, left, height, width = box
    b_top, b_left, side = blob
    return (
        top < b_top + side
        and b_top < top + height
        and left < b_left + side
        and b_left < left + width
    )


class _Source:
    def __init__(self, pairs: list[_Pair]) -> None:
        self.pairs = pairs

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, index: int) -> _Pair:
        return self.pairs[index]


@settings(max_examples=60, deadline=None)
@given(
    height=st.integers(32, 160),
    width=st.integers(32, 160),
    crop=st.integers(8, 32),
    y=st.floats(0, 1),
    x=st.floats(0, 1),
    side=st.integers(4, 12),  # a visible drop: a cell at 1/4 resolution sees it
    seed=st.integers(0, 2**16),
)
def test_an_anomaly_crop_lies_inside_the_image_and_holds_the_anomaly(
    height: int, width: int, crop: int, y: float, x: float, side: int, seed: int
) -> None:
    # the blob anywhere, edges and corners included, sizes not a multiple of the cells'
    blob = (int(y * (height - side)), int(x * (width - side)), side)
    box = anomaly_crop_box(_pair((height, width), blob), crop, np.random.default_rng(seed))
    assert box is not None
    top, left, h, w = box
    assert (h, w) == (crop, crop)
    assert 0 <= top <= height - crop and 0 <= left <= width - crop
    assert _holds_blob(box, blob)


def test_a_clean_or_masked_anomaly_gives_no_anomaly_crop() -> None:
    rng = np.random.default_rng(0)
    clean = _pair((64, 96), (0, 0, 0))
    assert anomaly_crop_box(clean, 32, rng) is None
    masked = _pair((64, 96), (20, 40, 8), masked=True)
    assert anomaly_crop_box(masked, 32, rng) is None  # untrustworthy pixels are not anomalies
    offset = _Pair(clean.input // 2 + 40, clean.target // 2)  # only a gain/offset between cameras
    assert anomaly_crop_box(offset, 32, rng) is None


@pytest.mark.parametrize("share", [0.0, 0.5, 1.0])
def test_the_share_of_crops_on_the_anomaly_follows_the_setting(share: float) -> None:
    blob = (120, 200, 8)  # a small drop in a 360x540 frame
    pairs = _Source([_pair((360, 540), blob) for _ in range(200)])
    crops = PairedCrops(pairs, 1, 32, seed=3, anomaly_crops=share)
    held = []
    for index in range(len(pairs)):
        sample = crops[index]
        held.append(bool((sample["input"] > 0.9).any()))  # the blob is the only bright pixel
    uniform = (32 + 8) ** 2 / ((360 - 32 + 1) * (540 - 32 + 1))  # chance a random crop holds it
    expected = share + (1 - share) * uniform
    assert abs(np.mean(held) - expected) < 0.1
    again = PairedCrops(pairs, 1, 32, seed=3, anomaly_crops=share)
    assert all(np.array_equal(again[i]["input"], crops[i]["input"]) for i in (0, 7))


def test_the_share_is_a_setting_with_a_range() -> None:
    assert DataConfig().anomaly_crops == 0.0  # opt-in: see its docstring
    with pytest.raises(ValueError, match="anomaly_crops"):
        DataConfig(anomaly_crops=1.5)
    with pytest.raises(ValueError, match="anomaly_crops"):
        PairedCrops(_Source([]), 1, 32, anomaly_crops=-0.1)
    assert item_rng(0, 0, 0).random() == item_rng(0, 0, 0).random()


def test_a_share_of_zero_keeps_the_uniform_crops_of_earlier_versions() -> None:
    pairs = _Source([_pair((64, 96), (20, 40, 8)) for _ in range(5)])
    crops = PairedCrops(pairs, 1, 32, seed=4)
    for index in range(len(pairs)):
        top, left, _, _ = crop_box(64, 96, 32, item_rng(4, 0, index))  # the first draws
        window = pairs[index].input[top : top + 32, left : left + 32]
        assert np.array_equal(crops[index]["input"][0].numpy(), window / np.float32(255))
