"""Glass layer: sprite rasterisation helpers and order-preserving compositing."""

import numpy as np
import pytest

from lenspair.simulate.effects.layer import (
    Sprites,
    box_grid,
    clip_boxes,
    composite_over,
    place,
    support_mask,
)


def _square(y: int, x: int, size: int, alpha: float, index: int) -> tuple[np.ndarray, ...]:
    ys, xs = np.mgrid[y : y + size, x : x + size]
    count = size * size
    return ys.ravel(), xs.ravel(), np.full(count, index), np.full(count, alpha, np.float32)


def _sprites(*squares: tuple[np.ndarray, ...]) -> Sprites:
    ys, xs, owner, alpha = (np.concatenate(parts) for parts in zip(*squares, strict=True))
    return Sprites(np.zeros((len(squares), 4), np.int64), ys, xs, owner, alpha)


@pytest.mark.parametrize("alpha", [1.0, 0.5])
def test_later_sprites_lie_on_top(alpha: float) -> None:
    sprites = _sprites(
        _square(2, 2, 4, alpha, 0), _square(4, 4, 4, alpha, 1), _square(5, 5, 1, alpha, 2)
    )
    colours = np.array([0.2, 0.6, 0.9], np.float32)[sprites.owner][:, None]
    placement = place(sprites, (12, 12), margin=1)
    assert len(placement.rounds) == 3  # pixel (5, 5) is covered three times
    canvas = np.zeros((14, 14, 2), np.float32)
    composite_over(canvas, placement, colours * sprites.alpha[:, None], sprites.alpha, empty=True)
    image = canvas[1:-1, 1:-1]
    a = alpha
    assert image[2, 2, 0] == pytest.approx(0.2 * a)  # first sprite alone
    assert image[4, 4, 0] == pytest.approx(0.6 * a + (1 - a) * 0.2 * a)  # second over first
    assert image[5, 5, 0] == pytest.approx(0.9 * a + (1 - a) * (0.6 * a + (1 - a) * 0.2 * a))
    assert image[5, 5, 1] == pytest.approx(1 - (1 - a) ** 3)
    assert image[0, 0].tolist() == [0.0, 0.0]
    mask = support_mask(placement, (14, 14))
    assert np.count_nonzero(mask) == 16 + 16 - 4 and mask[1 + 2, 1 + 2] == 255


def test_boxes_are_clipped_to_the_padded_image() -> None:
    boxes = clip_boxes(
        np.array([0.0, 50.0, 500.0]),
        np.array([0.0, 20.0, 20.0]),
        np.array([5.0, 2.5, 3.0]),
        np.array([5.0, 2.5, 3.0]),
        (40, 60),
        pad=2,
    )
    assert boxes[0].tolist() == [-2, 6, -2, 6]
    assert boxes[1].tolist() == [17, 24, 47, 54]
    assert boxes[2, 3] - boxes[2, 2] == 0  # entirely outside: empty
    ys, xs, owner = box_grid(boxes)
    assert len(ys) == 8 * 8 + 7 * 7 and (np.bincount(owner, minlength=3) == [64, 49, 0]).all()
    assert ys.min() == -2 and xs.max() == 53
