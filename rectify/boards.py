"""Calibration boards: the ``--board`` spec, the board model and the printed board.

The one board model of lenspair: :class:`Board` is what ``lenspair calibrate``
detects (:mod:`~lenspair.rectify.corner_detection`) and what the simulator
prints and poses (a scene spec's ``board:`` section,
:class:`lenspair.simulate.boardspec.BoardSpec`, builds one through
:attr:`~lenspair.simulate.boardspec.BoardSpec.target`).

Board specs (``lenspair calibrate --board``)::

    chessboard:COLSxROWS:SQUARE_M                  e.g. chessboard:9x6:0.025
    charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT][:legacy]
                                                   e.g. charuco:8x6:0.04:0.03:DICT_5X5_100

* ``chessboard`` counts **inner corners** (as OpenCV, ROS and Kalibr do): a
  ``9x6`` board has 10x7 squares. The first corner and the sense in which
  the detector walks the grid are not defined by a plain chessboard; the
  stereo calibration resolves them per view (:meth:`Board.symmetries`).
* ``charuco`` counts **squares** (as ``cv2.aruco.CharucoBoard`` does); it has
  ``(COLS-1)*(ROWS-1)`` inner corners, each identified by its id. ``DICT`` is
  an ArUco dictionary name (``DICT_`` prefix optional, any case), default
  ``DICT_5X5_100``. Boards follow OpenCV >= 4.6 unless the spec ends in
  ``:legacy``: the pattern OpenCV < 4.6 (and other tools) printed, OpenCV's
  ``setLegacyPattern(True)``. The two differ only for an even number of
  ROWS, where the legacy board's top-left square is white and carries a
  marker; corner ids and positions are the same in both.
* Sizes are in metres.

Corner ids are row-major: id ``j * columns + i`` is inner corner ``(i, j)`` at
board coordinates ``(i, j) * square`` (chessboard) or ``(i + 1, j + 1) * square``
(ChArUco, whose origin is the outer corner), ``z = 0``; with
``grid_origin=True`` both kinds put the origin at the outer top-left corner of
the square grid (the frame the simulator poses boards in). The printed board
(:meth:`Board.printed_image`) has a white border one square wide, the quiet
zone detectors need, and a black top-left square (white on a legacy
ChArUco board of even ROWS). Pixel coordinates
follow OpenCV: the centre of the top-left pixel is ``(0, 0)``.
"""

import functools
import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from lenspair.rectify.errors import RectifyError

BoardKind = Literal["chessboard", "charuco"]
DEFAULT_DICTIONARY = "DICT_5X5_100"
LEGACY = "legacy"
"""The last field of a ChArUco spec whose board has OpenCV < 4.6's pattern."""


def _dictionary_names() -> list[str]:
    return sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_") and n.upper() == n)


MAX_BOARD_SIDE = 200
"""Most corners or squares along a board's side (printed boards have tens)."""

MIN_SQUARE_M = 0.001
"""Smaller printed squares cannot be measured; OpenCV's fit failed on them as ill-conditioned."""


@dataclass(frozen=True)
class Board:
    """A planar calibration board.

    Attributes:
        kind: ``chessboard`` or ``charuco``.
        columns: inner corners (chessboard) or squares (ChArUco) along x.
        rows: inner corners (chessboard) or squares (ChArUco) along y.
        square_m: side of one square, metres.
        marker_m: side of one ArUco marker, metres (ChArUco only).
        dictionary: ArUco dictionary name such as ``DICT_6X6_250`` (ChArUco only).
        legacy: ChArUco only: the pattern of OpenCV < 4.6 (``setLegacyPattern``).

    """

    kind: BoardKind
    columns: int
    rows: int
    square_m: float
    marker_m: float | None = None
    dictionary: str | None = None
    legacy: bool = False

    def __post_init__(self) -> None:
        minimum = 3  # OpenCV finds no chessboard of 2 inner corners along a side (it raises)
        if self.columns < minimum or self.rows < minimum:
            raise RectifyError(
                f"board {self.kind}: need at least {minimum}x{minimum} "
                f"{'inner corners' if self.kind == 'chessboard' else 'squares'}, "
                f"got {self.columns}x{self.rows}"
            )
        if max(self.columns, self.rows) > MAX_BOARD_SIDE:  # OpenCV takes a C int; and no print
            raise RectifyError(
                f"board {self.kind}: at most {MAX_BOARD_SIDE} along a side, "
                f"got {self.columns}x{self.rows}"
            )
        if not 0.0 < self.square_m < 1.0:
            plausible = math.isfinite(self.square_m) and self.square_m >= 1.0
            hint = " (sizes are in metres; did you give millimetres?)" if plausible else ""
            raise RectifyError(
                f"board square size: expected 0 < SQUARE_M < 1, got {self.square_m}{hint}"
            )
        if self.square_m < MIN_SQUARE_M:  # OpenCV's fit fails on it as "ill-conditioned"
            raise RectifyError(
                f"board square size: {self.square_m} m is under a millimetre; sizes are in "
                "metres (a 25 mm square is 0.025)"
            )
        if self.kind == "chessboard":
            if self.legacy:
                raise RectifyError("board chessboard: only a ChArUco board has a legacy pattern")
            return
        if self.marker_m is None or not 0.0 < self.marker_m < self.square_m:
            raise RectifyError(
                f"board marker size: expected 0 < MARKER_M < SQUARE_M = {self.square_m}, "
                f"got {self.marker_m}"
            )
        if self.dictionary not in _dictionary_names():
            valid = ", ".join(_dictionary_names())
            raise RectifyError(f"board dictionary: unknown {self.dictionary!r}; valid: {valid}")
        needed = self.columns * self.rows // 2
        available = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        if needed > available.bytesList.shape[0]:
            raise RectifyError(
                f"board: a {self.columns}x{self.rows} ChArUco board needs {needed} markers, "
                f"{self.dictionary} has {available.bytesList.shape[0]}"
            )

    @property
    def grid(self) -> tuple[int, int]:
        """Inner corners ``(columns, rows)``."""
        if self.kind == "chessboard":
            return self.columns, self.rows
        return self.columns - 1, self.rows - 1

    @property
    def num_corners(self) -> int:
        """Number of inner corners."""
        columns, rows = self.grid
        return columns * rows

    @property
    def squares(self) -> tuple[int, int]:
        """Squares ``(across, down)`` of the printed grid (without the white border)."""
        if self.kind == "chessboard":
            return self.columns + 1, self.rows + 1
        return self.columns, self.rows

    @property
    def grid_size_m(self) -> tuple[float, float]:
        """``(width, height)`` of the square grid, metres (without the white border)."""
        across, down = self.squares
        return across * self.square_m, down * self.square_m

    def object_points(self, grid_origin: bool = False) -> np.ndarray:
        """Board coordinates of every inner corner, metres, ``(N, 3)`` float64, row-major ids.

        Args:
            grid_origin: False: OpenCV's origin for the kind (a chessboard's
                first inner corner, a ChArUco board's outer corner); True: the
                outer top-left corner of the square grid for both kinds.

        """
        columns, rows = self.grid
        i, j = np.meshgrid(np.arange(columns), np.arange(rows))
        offset = 0.0 if self.kind == "chessboard" and not grid_origin else 1.0
        xy = np.stack([i.ravel() + offset, j.ravel() + offset], axis=1) * self.square_m
        return np.column_stack([xy, np.zeros(len(xy))]).astype(np.float64)

    def symmetries(self) -> list[np.ndarray]:
        """Permutations of corner ids that map the grid onto itself by an in-plane rotation.

        A plain chessboard looks the same after a 180 deg turn (and after 90 deg
        turns when square), so a detector may number its corners from any of
        these starting points. ChArUco ids are unique: identity only.

        Returns:
            list of ``(N,)`` int arrays ``perm``; ``ids[perm]`` renumbers; the
            identity comes first.

        """
        columns, rows = self.grid
        ids = np.arange(columns * rows).reshape(rows, columns)
        if self.kind == "charuco":
            return [ids.ravel()]
        turns = (0, 1, 2, 3) if columns == rows else (0, 2)
        return [np.rot90(ids, k).ravel().copy() for k in turns]

    def printed_image(self, pixels_per_square: int) -> np.ndarray:
        """The printed board with a white border one square wide.

        Pixel ``(r, c)`` covers grid-origin board coordinates
        ``[c - p, c - p + 1] * square_m / p`` along x (likewise y), with
        ``p = pixels_per_square``.

        Returns:
            ``uint8`` ``((down + 2) p, (across + 2) p)`` image, 0 black, 255 white.

        """
        p = pixels_per_square
        across, down = self.squares
        if self.kind == "charuco":
            size = ((across + 2) * p, (down + 2) * p)
            image = self.charuco().generateImage(size, marginSize=p, borderBits=1)
            return np.ascontiguousarray(image, dtype=np.uint8)
        rows, cols = np.mgrid[0:down, 0:across]
        cells = np.where((rows + cols) % 2 == 0, 0, 255).astype(np.uint8)
        grid = np.repeat(np.repeat(cells, p, axis=0), p, axis=1)
        return np.ascontiguousarray(np.pad(grid, p, constant_values=255))

    def spec(self) -> str:
        """The ``--board`` spec string of this board."""
        size = f"{self.columns}x{self.rows}:{self.square_m:g}"
        if self.kind == "chessboard":
            return f"chessboard:{size}"
        legacy = f":{LEGACY}" if self.legacy else ""
        return f"charuco:{size}:{self.marker_m:g}:{self.dictionary}{legacy}"

    def charuco(self) -> "cv2.aruco.CharucoBoard":
        """The OpenCV ChArUco board object (ChArUco boards only)."""
        if self.kind != "charuco" or self.dictionary is None or self.marker_m is None:
            raise RectifyError(f"board {self.spec()} is not a ChArUco board")
        return _charuco_board(
            self.columns, self.rows, self.square_m, self.marker_m, self.dictionary, self.legacy
        )


@functools.lru_cache(maxsize=8)
def _charuco_board(
    columns: int, rows: int, square_m: float, marker_m: float, dictionary: str, legacy: bool
) -> "cv2.aruco.CharucoBoard":
    """The OpenCV board of a spec, built once per process.

    OpenCV warns on each construction of a board whose marker border is thin
    (72 identical lines for one calibration); detection only reads it.
    """
    words = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    board = cv2.aruco.CharucoBoard((columns, rows), square_m, marker_m, words)
    board.setLegacyPattern(legacy)
    return board


def parse_board_spec(text: str) -> Board:
    """Parse a ``--board`` spec (see the module docstring).

    Raises:
        RectifyError: with the expected form and what was wrong.

    """
    forms = {
        "chessboard": "chessboard:COLSxROWS:SQUARE_M",
        "charuco": "charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT][:legacy]",
    }
    parts = text.strip().split(":")
    legacy = parts[0].lower() == "charuco" and parts[-1].strip().lower() == LEGACY
    if legacy:
        parts = parts[:-1]
    kind = parts[0].lower()
    if kind not in forms:
        raise RectifyError(
            f"board spec {text!r}: unknown board type {parts[0]!r}; expected "
            f"{forms['chessboard']} or {forms['charuco']}"
        )
    counts = (3,) if kind == "chessboard" else (4, 5)
    if len(parts) not in counts:
        raise RectifyError(f"board spec {text!r}: expected {forms[kind]}")
    size = parts[1].lower().split("x")
    if len(size) != 2 or not all(s.isdigit() for s in size):
        raise RectifyError(f"board spec {text!r}: COLSxROWS must look like 9x6, got {parts[1]!r}")
    lengths = []
    for name, value in zip(("SQUARE_M", "MARKER_M"), parts[2:4], strict=False):
        try:
            lengths.append(float(value))
        except ValueError:
            raise RectifyError(
                f"board spec {text!r}: {name} must be a length in metres, got {value!r}"
            ) from None
    dictionary = None
    if kind == "charuco":
        name = parts[4].upper() if len(parts) == 5 else DEFAULT_DICTIONARY
        dictionary = name if name.startswith("DICT_") else f"DICT_{name}"
    try:
        return Board(
            kind,  # type: ignore[arg-type]
            int(size[0]),
            int(size[1]),
            lengths[0],
            lengths[1] if len(lengths) > 1 else None,
            dictionary,
            legacy,
        )
    except RectifyError as exc:
        raise RectifyError(f"board spec {text!r}: {exc}") from None
