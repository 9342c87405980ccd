"""The ``board:`` section of a scene spec: a calibration board and how it is posed.

Kept apart from :mod:`lenspair.simulate.spec` (which uses it) to keep modules
small. The board itself (geometry, printed image) is lenspair's one board
model, :class:`lenspair.rectify.boards.Board`, built by :attr:`BoardSpec.target`;
this section adds how the simulator poses and prints it.
"""

from dataclasses import dataclass
from typing import Literal

from lenspair.rectify.boards import DEFAULT_DICTIONARY, Board
from lenspair.rectify.errors import RectifyError

DICTIONARIES = (
    "DICT_4X4_50",
    "DICT_4X4_100",
    "DICT_4X4_250",
    "DICT_5X5_50",
    "DICT_5X5_100",
    "DICT_5X5_250",
    "DICT_6X6_50",
    "DICT_6X6_250",
)
"""ArUco dictionaries accepted for ChArUco boards (names of ``cv2.aruco`` constants)."""


MAX_BOARD_TEXELS = 2**25
"""Largest printed board texture, texels: 128 MiB as float32 mono, with its mip levels
and an RGB copy well under the memory of a small robot computer."""


@dataclass(frozen=True)
class BoardSpec:
    """A calibration board shown to both cameras in varied poses.

    One pose per frame: the board centre lies on the viewing ray of a target
    pixel of cam0 (targets cycle through a grid so that the views cover the
    image including its corners), at a distance drawn from ``distance_m``,
    facing the camera with a random tilt up to ``max_tilt_deg``; poses are
    redrawn until the whole board (with its white border) is inside both
    images by ``margin_px``.

    Attributes:
        kind: ``chessboard`` or ``charuco``.
        cols: chessboard: inner corners per row; ChArUco: squares per row.
        rows: chessboard: inner corners per column; ChArUco: squares per column.
        square_m: side of one square, metres.
        marker_m: ChArUco marker side, metres (default 0.75 * square_m).
        dictionary: ChArUco ArUco dictionary (one of ``DICTIONARIES``).
        distance_m: ``(min, max)`` distance of the board centre, metres.
        max_tilt_deg: largest tilt of the board away from facing the camera.
        margin_px: the board must be this far inside both images, pixels.
        pixels_per_square: texture resolution of the board.
        grid: ``(cols, rows)`` of the cam0 target-pixel grid that poses cycle through.

    """

    kind: Literal["chessboard", "charuco"]
    cols: int
    rows: int
    square_m: float
    marker_m: float | None = None
    dictionary: str = DEFAULT_DICTIONARY
    distance_m: tuple[float, float] = (0.6, 1.6)
    max_tilt_deg: float = 40.0
    margin_px: float = 12.0
    pixels_per_square: int = 64
    grid: tuple[int, int] = (3, 3)

    def __post_init__(self) -> None:
        if not (2 <= self.cols <= 64 and 2 <= self.rows <= 64):
            raise ValueError(f"cols, rows: expected 2..64, got {self.cols} x {self.rows}")
        if not 0.002 <= self.square_m < 1.0:  # as --board SQUARE_M: under a metre
            raise ValueError(f"square_m: expected 0.002 <= square_m < 1 m, got {self.square_m}")
        if self.kind == "chessboard" and (
            self.marker_m is not None or self.dictionary != DEFAULT_DICTIONARY
        ):  # a chessboard has no markers: the value would be ignored
            raise ValueError("marker_m, dictionary: a chessboard has no markers (charuco only)")
        if self.marker_m is not None and not 0 < self.marker_m < self.square_m:
            raise ValueError(f"marker_m: expected 0 < marker_m < square_m, got {self.marker_m}")
        if self.dictionary not in DICTIONARIES:
            raise ValueError(
                f"dictionary: unknown {self.dictionary!r}; valid: {', '.join(DICTIONARIES)}"
            )
        low, high = self.distance_m
        if not 0.05 <= low <= high <= 100.0:
            raise ValueError(
                f"distance_m: expected 0.05 <= min <= max <= 100, got {self.distance_m}"
            )
        if not 0.0 <= self.max_tilt_deg <= 70.0:
            raise ValueError(f"max_tilt_deg: expected 0..70, got {self.max_tilt_deg}")
        if not 8 <= self.pixels_per_square <= 512:
            raise ValueError(f"pixels_per_square: expected 8..512, got {self.pixels_per_square}")
        texels = (self.cols + 3) * (self.rows + 3) * self.pixels_per_square**2
        if texels > MAX_BOARD_TEXELS:  # 64x64 squares at 512 px: a 4.4 GiB traceback
            raise ValueError(
                f"pixels_per_square: a {self.cols}x{self.rows} board at {self.pixels_per_square} "
                f"px a square is a texture of {texels / 1e6:.0f} M texels, over "
                f"{MAX_BOARD_TEXELS / 1e6:.0f} M; use fewer pixels_per_square"
            )
        if not 0.0 <= self.margin_px <= 1000.0:  # a negative margin let boards leave the image
            raise ValueError(f"margin_px: expected 0..1000, got {self.margin_px}")
        if not (min(self.grid) >= 1 and max(self.grid) <= 100):
            raise ValueError(f"grid: expected sizes 1..100, got {self.grid}")
        try:
            self.target  # noqa: B018 (validated as the calibration tool will read it)
        except RectifyError as exc:
            raise ValueError(str(exc)) from None

    @property
    def marker_size_m(self) -> float:
        """ChArUco marker side, metres."""
        return self.marker_m if self.marker_m is not None else 0.75 * self.square_m

    @property
    def target(self) -> Board:
        """The board as ``lenspair calibrate`` sees it (the shared board model)."""
        marker = self.marker_size_m if self.kind == "charuco" else None
        dictionary = self.dictionary if self.kind == "charuco" else None
        return Board(self.kind, self.cols, self.rows, self.square_m, marker, dictionary)
