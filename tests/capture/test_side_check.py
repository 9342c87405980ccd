import cv2
import numpy as np
import pytest

from lenspair.capture.errors import CaptureError
from lenspair.capture.side_check import DETAIL_HINT, check_obstructed_side, tile_detail


def _textured(rng: np.random.Generator, shape: tuple[int, int] = (120, 160)) -> np.ndarray:
    noise = rng.random(shape, dtype=np.float32)
    texture = 0.5 * noise + 0.5 * cv2.GaussianBlur(noise, (0, 0), 3.0) + 0.2
    image: np.ndarray = np.clip(texture / texture.max() * 230, 0, 255).astype(np.uint8)
    return image


def _obstruct(image: np.ndarray, rng: np.random.Generator, drops: int = 6) -> np.ndarray:
    """Blur and attenuate round blobs, as raindrops and dirt do."""
    blurred = cv2.GaussianBlur(image, (0, 0), 4.0).astype(np.float32) * 0.8 + 20
    height, width = image.shape[:2]
    yy, xx = np.mgrid[:height, :width]
    inside = np.zeros((height, width), bool)
    for _ in range(drops):
        cy, cx = rng.integers(15, height - 15), rng.integers(15, width - 15)
        inside |= (yy - cy) ** 2 + (xx - cx) ** 2 < 18**2
    if image.ndim == 3:
        inside = inside[:, :, None]
    return np.where(inside, blurred, image).astype(image.dtype)


def _frames(count: int = 3, colour: bool = False) -> tuple[list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(7)
    clean = [_textured(rng) for _ in range(count)]
    if colour:
        clean = [np.dstack([c, c[::-1, ::-1], c]) for c in clean]
    return clean, [_obstruct(c, rng) for c in clean]


@pytest.mark.parametrize("colour", [False, True])
def test_declared_side_agrees(colour: bool) -> None:
    clean, dirty = _frames(colour=colour)
    result = check_obstructed_side(clean, dirty, "cam1")
    assert result.inferred == "cam1"
    assert result.agrees is True and not result.mismatch
    assert result.confidence > 0.5
    assert result.lower_cam1 > result.lower_cam0
    assert result.num_frames == 3 and result.num_tiles == 48
    # a hint, never "images agree": refracting drops can add detail (module docstring)
    assert result.message.startswith("fine detail is lower on cam1, as declared (")
    assert "agree" not in result.message and result.message.endswith(DETAIL_HINT)


def test_swapped_declaration_is_flagged() -> None:
    clean, dirty = _frames()
    result = check_obstructed_side(dirty, clean, "cam1")
    assert result.inferred == "cam0"
    assert result.mismatch and result.agrees is False
    assert result.message.startswith("fine detail is lower on cam0, but cam1 is declared (")
    assert result.method == "detail" and result.message.endswith(DETAIL_HINT)


def test_identical_or_gain_shifted_views_are_undetermined() -> None:
    clean, _ = _frames()
    same = check_obstructed_side(clean, clean, "cam0")
    assert (same.inferred, same.agrees, same.mismatch, same.confidence) == (
        "undetermined",
        None,
        False,
        0.0,
    )
    darker = [(c.astype(np.float32) * 0.6).round().astype(np.uint8) for c in clean]
    assert check_obstructed_side(clean, darker, "cam0").inferred == "undetermined"


def test_flat_images_take_no_part() -> None:
    flat = [np.full((40, 40), 128, np.uint16)]
    result = check_obstructed_side(flat, flat, "cam0")
    assert result.inferred == "undetermined" and result.num_tiles == 0


def test_tile_detail_shape_and_bad_input() -> None:
    clean, dirty = _frames(count=1)
    clean_detail, dirty_detail = tile_detail(clean[0], (6, 8)), tile_detail(dirty[0], (6, 8))
    assert clean_detail.shape == (6, 8)
    assert (dirty_detail < 0.5 * clean_detail).any()  # under the blobs
    assert np.median(dirty_detail / clean_detail) > 0.9  # elsewhere about the same
    with pytest.raises(CaptureError, match="same, non-zero number"):
        check_obstructed_side(clean, [], "cam0")
    with pytest.raises(ValueError, match="dtype"):
        check_obstructed_side([clean[0].astype(np.float32)], clean, "cam0")


def test_disparity_between_views_does_not_decide() -> None:
    rng = np.random.default_rng(3)
    wide = [_textured(rng, (120, 176)) for _ in range(3)]
    left = [w[:, 16:] for w in wide]
    right = [w[:, :-16] for w in wide]
    assert check_obstructed_side(left, right, "cam0").inferred == "undetermined"
    dirty = [_obstruct(r, rng) for r in right]
    assert check_obstructed_side(left, dirty, "cam1").agrees is True


def _tiles(image: np.ndarray, tiles: list[tuple[int, int]], flat: bool = False) -> np.ndarray:
    """``image`` with the given tiles of the 6x8 grid (20x20 px) blurred, or made flat."""
    out = image.copy()
    blurred = cv2.GaussianBlur(image, (0, 0), 4.0)
    for row, col in tiles:
        if flat:  # a pixel beyond the tile too: its edge pixels' Laplacian sees no texture
            out[max(20 * row - 2, 0) : 20 * row + 22, max(20 * col - 2, 0) : 20 * col + 22] = 128
        else:
            y, x = slice(20 * row, 20 * row + 20), slice(20 * col, 20 * col + 20)
            out[y, x] = blurred[y, x]
    return out


def test_near_even_contradictory_votes_decide_nothing() -> None:
    # 10 % of the tiles lose detail on cam0 and 8 % on cam1: no side is obstructed more
    # than the other, and without the dominance rule cam0 was named
    rng = np.random.default_rng(3)
    clean = [_textured(rng) for _ in range(3)]
    cam0 = [_tiles(c, [(1, 1), (1, 3), (2, 5), (3, 2), (4, 6)]) for c in clean]
    cam1 = [_tiles(c, [(0, 7), (2, 1), (3, 4), (5, 0)]) for c in clean]
    result = check_obstructed_side(cam0, cam1, "cam1")
    assert result.inferred == "undetermined" and result.agrees is None


def test_a_tile_flat_in_one_view_only_votes() -> None:
    # opaque dirt leaves no detail at all in its tiles: the strongest evidence, and the
    # tiles were dropped as "flat" when either view (not both) was
    rng = np.random.default_rng(4)
    clean = [_textured(rng) for _ in range(3)]
    dirty = [_tiles(c, [(1, 1), (1, 2), (3, 4), (4, 6)], flat=True) for c in clean]
    result = check_obstructed_side(clean, dirty, "cam1")
    assert result.inferred == "cam1" and result.agrees
