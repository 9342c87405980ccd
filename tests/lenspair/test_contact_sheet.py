import numpy as np
import pytest

from lenspair.core.contact_sheet import fit_into, make_contact_sheet, to_display


@pytest.mark.parametrize(
    ("image", "expected"),
    [
        (np.full((4, 6), 65535, np.uint16), 255),
        (np.full((4, 6), 257 * 100, np.uint16), 100),
        (np.full((4, 6, 3), 7, np.uint8), 7),
        (np.full((4, 6, 1), 0.5, np.float32), 128),
        (np.full((4, 6), 2.0, np.float64), 255),
        (np.ones((4, 6), bool), 255),
        (np.full((4, 6, 4), 9, np.uint8), 9),
    ],
)
def test_to_display_normalises_every_convention(image: np.ndarray, expected: int) -> None:
    out = to_display(image)
    assert out.dtype == np.uint8 and out.shape == (4, 6, 3)
    assert int(out[0, 0, 0]) == expected


def test_to_display_stretch_and_bad_shape() -> None:
    dark = np.linspace(0, 4095, 24, dtype=np.float64).astype(np.uint16).reshape(4, 6)
    assert to_display(dark).max() < 20
    assert to_display(dark, stretch=True).max() == 255
    with pytest.raises(ValueError, match="expected"):
        to_display(np.zeros((2, 2, 2, 2), np.uint8))
    nan = np.full((2, 2), np.nan, np.float32)
    assert to_display(nan).max() == 0


def test_fit_into_keeps_aspect_and_centres() -> None:
    cell = fit_into(np.full((10, 40, 3), 200, np.uint8), 20, 20, background=0)
    assert cell.shape == (20, 20, 3)
    assert cell[10, 10, 0] == 200 and cell[0, 10, 0] == 0  # letterboxed top and bottom


def test_sheet_grid_labels_and_determinism() -> None:
    rng = np.random.default_rng(0)
    rgb16 = rng.integers(0, 65535, (36, 54, 3), dtype=np.uint16)
    mono8 = rng.integers(0, 255, (36, 54), dtype=np.uint8)
    mask = np.zeros((9, 14), bool)
    rows: list[list[np.ndarray | None]] = [[rgb16, mono8, mask], [mono8]]
    labels = [["input", "target", "mask"], ["only"]]
    sheet = make_contact_sheet(rows, labels, title="split: train", cell_width=60, padding=2)
    assert sheet.dtype == np.uint8 and sheet.ndim == 3 and sheet.shape[2] == 3
    assert sheet.shape[1] == 2 + 3 * (60 + 2)
    again = make_contact_sheet(rows, labels, title="split: train", cell_width=60, padding=2)
    assert np.array_equal(sheet, again)
    unlabelled = make_contact_sheet(rows, cell_width=60, padding=2)
    assert unlabelled.shape[0] < sheet.shape[0]
    # text is drawn: the label band holds bright pixels
    assert (sheet[:30] > 200).any()


def test_sheet_handles_empty_cells_and_long_labels() -> None:
    image = np.zeros((10, 10), np.uint8)
    sheet = make_contact_sheet(
        [[image, None], [None, image]], [["x" * 200]], cell_width=30, cell_height=30
    )
    assert sheet.shape[1:] == (4 + 2 * (30 + 4), 3) and sheet.shape[0] > 4 + 2 * (30 + 4)
    with pytest.raises(ValueError, match="no images"):
        make_contact_sheet([[None]])
    with pytest.raises(ValueError, match="cell size"):
        make_contact_sheet([[image]], cell_width=0)


@pytest.mark.parametrize("first", [(11, 2000), (2000, 11)])
def test_a_strip_listed_first_does_not_set_the_cells(first: tuple[int, int]) -> None:
    # the first image's aspect set every cell: an 11x12420 strip made a 980x542034 sheet
    # (eval ran out of memory), and a 4000x100 frame shrank every other to a few pixels
    frame = np.full((360, 540), 200, np.uint8)
    rows = [[np.zeros(first, np.uint8), frame], [frame, frame]]
    sheet = make_contact_sheet(rows, cell_width=120, padding=0, background=0)
    assert sheet.shape[:2] == (2 * 80, 2 * 120)  # the frames' 2:3, not the strip's
    assert (sheet[80:, :120] == 200).all()  # a frame fills its cell
