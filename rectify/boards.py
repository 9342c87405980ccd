"""Calibration boards: the ``--board`` spec, the board model, the printed board, corner detection.

The one board model of lenspair: :class:`Board` is what ``lenspair calibrate``
detects and what the simulator prints and poses (a scene spec's ``board:``
section, :class:`lenspair.simulate.boardspec.BoardSpec`, builds one through
:attr:`~lenspair.simulate.boardspec.BoardSpec.target`).

Board specs (``lenspair calibrate --board``)::

    chessboard:COLSxROWS:SQUARE_M                  e.g. chessboard:9x6:0.025
    charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]     e.g. charuco:8x6:0.04:0.03:DICT_5X5_100

* ``chessboard`` counts **inner corners** (as OpenCV, ROS and Kalibr do): a
  ``9x6`` board has 10x7 squares. The first corner and the sense in which
  the detector walks the grid are not defined by a plain chessboard; the
  stereo calibration resolves them per view (:meth:`Board.symmetries`).
* ``charuco`` counts **squares** (as ``cv2.aruco.CharucoBoard`` does); it has
  ``(COLS-1)*(ROWS-1)`` inner corners, each identified by its id. ``DICT`` is
  an ArUco dictionary name (``DICT_`` prefix optional, any case), default
  ``DICT_5X5_100``. Boards follow OpenCV >= 4.6 (not the legacy pattern).
* Sizes are in metres.

Corner ids are row-major: id ``j * columns + i`` is inner corner ``(i, j)`` at
board coordinates ``(i, j) * square`` (chessboard) or ``(i + 1, j + 1) * square``
(ChArUco, whose origin is the outer corner), ``z = 0``; with
``grid_origin=True`` both kinds put the origin at the outer top-left corner of
the square grid (the frame the simulator poses boards in). The printed board
(:meth:`Board.printed_image`) has a white border one square wide, the quiet
zone detectors need, and a black top-left square. Pixel coordinates
follow OpenCV: the centre of the top-left pixel is ``(0, 0)``.
"""

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from lenspair.rectify.errors import RectifyError

BoardKind = Literal["chessboard", "charuco"]
DEFAULT_DICTIONARY = "DICT_5X5_100"
_MIN_CORNERS = 6


def _dictionary_names() -> list[str]:
    return sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_") and n.upper() == n)


MAX_BOARD_SIDE = 200
"""Most corners or squares along a board's side (printed boards have tens)."""


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

    """

    kind: BoardKind
    columns: int
    rows: int
    square_m: float
    marker_m: float | None = None
    dictionary: str | None = None

    def __post_init__(self) -> None:
        minimum = 2 if self.kind == "chessboard" else 3
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
        return f"charuco:{size}:{self.marker_m:g}:{self.dictionary}"

    def charuco(self) -> "cv2.aruco.CharucoBoard":
        """The OpenCV ChArUco board object (ChArUco boards only)."""
        if self.kind != "charuco" or self.dictionary is None or self.marker_m is None:
            raise RectifyError(f"board {self.spec()} is not a ChArUco board")
        return _charuco_board(
            self.columns, self.rows, self.square_m, self.marker_m, self.dictionary
        )


@functools.lru_cache(maxsize=8)
def _charuco_board(
    columns: int, rows: int, square_m: float, marker_m: float, dictionary: str
) -> "cv2.aruco.CharucoBoard":
    """The OpenCV board of a spec, built once per process.

    OpenCV warns on each construction of a board whose marker border is thin
    (72 identical lines for one calibration); detection only reads it.
    """
    words = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    return cv2.aruco.CharucoBoard((columns, rows), square_m, marker_m, words)


MIN_SQUARE_M = 0.001
"""Smaller printed squares cannot be measured; OpenCV's fit failed on them as ill-conditioned."""

MARKER_FAMILIES = ("DICT_4X4_1000", "DICT_5X5_1000", "DICT_6X6_1000", "DICT_7X7_1000")
"""The largest dictionary of each marker size: a smaller one's markers are among its first."""


def marker_family(image: np.ndarray, at_least: int = 4) -> str | None:
    """The ArUco family of which ``image`` shows ``at_least`` markers, or ``None``.

    For a chessboard spec: a ChArUco board's chessboard corners are found
    too, but the markers pull ``cornerSubPix``, and the calibration came out
    biased (focal length 0.6 % off, RMS 0.54 px) without a word.
    """
    gray = _to_gray(image)
    for family in MARKER_FAMILIES:
        words = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family))
        detector = cv2.aruco.ArucoDetector(words, cv2.aruco.DetectorParameters())
        _, ids, _ = detector.detectMarkers(gray)
        if ids is not None and len(ids) >= at_least:
            return family
    return None


def parse_board_spec(text: str) -> Board:
    """Parse a ``--board`` spec (see the module docstring).

    Raises:
        RectifyError: with the expected form and what was wrong.

    """
    forms = {
        "chessboard": "chessboard:COLSxROWS:SQUARE_M",
        "charuco": "charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]",
    }
    parts = text.strip().split(":")
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
        )
    except RectifyError as exc:
        raise RectifyError(f"board spec {text!r}: {exc}") from None


@dataclass(frozen=True)
class Detection:
    """Inner corners of a board found in one image.

    Attributes:
        ids: ``(N,)`` int32 corner ids (see the module docstring), ascending.
        corners: ``(N, 2)`` float32 sub-pixel image coordinates, pixels.
        marker_m: ChArUco: the markers' side measured in this image, metres
            (the median over its markers, mapped onto the board plane by
            the homography of its corners; see :func:`measured_marker_m`);
            ``None`` for chessboards.

    """

    ids: np.ndarray
    corners: np.ndarray
    marker_m: float | None = None

    def __len__(self) -> int:
        return len(self.ids)


def _to_gray(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    colour = image.ndim == 3 and image.shape[2] == 3
    if image.dtype not in (np.uint8, np.uint16) or not (image.ndim == 2 or colour):
        raise RectifyError(
            f"expected a uint8/uint16 (H, W) or (H, W, 3) image, got {image.dtype} {image.shape}"
        )
    if colour:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if image.dtype == np.uint16:
        # the top 8 of the bits the image uses: a full-range image loses its low
        # byte, and 10- or 12-bit values in 16-bit words (mono16 from a Mono10/Mono12
        # camera) keep their own top bits instead of coming out all but black
        shift = max(0, int(image.max()).bit_length() - 8)
        image = np.right_shift(image, shift).astype(np.uint8)
    return image


def _refine(gray: np.ndarray, corners: np.ndarray, board: Board) -> np.ndarray:
    # The search window must stay clear of neighbouring corners (chessboard) and
    # of the markers' inner edges (ChArUco), or they pull the corner.
    points = corners.reshape(-1, 2).astype(np.float64)
    distances = np.linalg.norm(points[:, None] - points[None], axis=2)
    np.fill_diagonal(distances, np.inf)
    spacing = float(np.min(distances))
    fraction = 0.4
    if board.marker_m is not None:  # 1.25 x the white gap between corner and marker (measured)
        fraction = 1.25 * (board.square_m - board.marker_m) / (2 * board.square_m)
    half = int(np.clip(round(fraction * spacing), 2, 11))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    refined = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (half, half), (-1, -1), criteria)
    return np.asarray(refined, dtype=np.float32).reshape(-1, 2)


def detect_corners(image: np.ndarray, board: Board, thorough: bool = True) -> Detection | None:
    """Find the board's inner corners in one image, to sub-pixel accuracy.

    Chessboards: ``cv2.findChessboardCorners`` then ``cv2.cornerSubPix`` with a
    window sized to the squares. ChArUco: OpenCV 5's ``cv2.aruco.CharucoDetector``
    (markers, missed markers recovered from the board layout, interpolated
    corners), then ``cv2.cornerSubPix`` with a window that stays clear of the
    markers.

    Args:
        image: ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)`` RGB.
        board: what to look for.
        thorough: chessboards: search a frame the quick check rejects again
            without it (small, far boards); ``False`` is the quick pass alone.

    Returns:
        The detection, or ``None`` when the board is not found (chessboards
        must be complete; ChArUco needs at least 6 non-collinear corners).

    """
    gray = _to_gray(image)
    if board.kind == "chessboard":
        # FAST_CHECK rejects a board-less frame in milliseconds, but also misses
        # boards whose squares span about 12 px or less (far away, wide lenses):
        # ``thorough`` searches a miss again without it (about 20x as long on a
        # frame without a board; calibrate_recording asks only where it may pay).
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(
            gray, board.grid, flags=flags | cv2.CALIB_CB_FAST_CHECK
        )
        if not found and thorough:
            found, corners = cv2.findChessboardCorners(gray, board.grid, flags=flags)
        if not found:
            return None
        refined = _refine(gray, corners, board)
        return Detection(np.arange(board.num_corners, dtype=np.int32), refined)
    charuco = board.charuco()
    parameters = cv2.aruco.CharucoParameters()
    parameters.tryRefineMarkers = True  # find small markers the board layout predicts
    detector = cv2.aruco.CharucoDetector(charuco, parameters, cv2.aruco.DetectorParameters())
    corners, ids, markers, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < _MIN_CORNERS:
        return None
    ids = np.asarray(ids, dtype=np.int32).reshape(-1)
    if charuco.checkCharucoCornersCollinear(ids):
        return None
    order = np.argsort(ids)
    refined = _refine(gray, np.asarray(corners, dtype=np.float32).reshape(-1, 2), board)
    marker_m = measured_marker_m(board, ids, refined, markers)
    return Detection(ids[order], refined[order], marker_m)


_MIN_MARKER_PX = 20.0


def measured_marker_m(
    board: Board, ids: np.ndarray, corners: np.ndarray, markers: Sequence[np.ndarray]
) -> float | None:
    """The side of a ChArUco board's markers as one image shows it, metres.

    The homography from the image to the board plane (fitted to the
    chessboard corners, whose board positions the square size fixes) maps
    each marker's four corners onto the board, where its side is measured;
    the median over the markers is returned. A ``MARKER_M`` in ``--board``
    far from it is a typing mistake the calibration cannot see otherwise: the
    detector places its first corner guesses by the stated size, and a wrong
    one biases the focal length (0.5 % for markers stated a third smaller).
    ArUco's corners sit a fraction of a pixel inside the black border, so the
    measure comes out a few percent small (3 % at 45 pixels per marker, 6 %
    at about 25 on the sample ChArUco scene); markers under
    ``_MIN_MARKER_PX`` on a side are left out, where that grows.

    Args:
        board: the ChArUco board.
        ids: ``(N,)`` ids of the chessboard corners found.
        corners: ``(N, 2)`` their image positions.
        markers: the markers' ``(1, 4, 2)`` image corners, as
            ``cv2.aruco.CharucoDetector.detectBoard`` returns them.

    Returns:
        The median side, or ``None`` without markers large enough or a
        homography.

    """
    if not len(markers) or len(ids) < 4:
        return None
    on_board = np.asarray(board.charuco().getChessboardCorners(), np.float64)[ids, :2]
    homography, _ = cv2.findHomography(corners.astype(np.float64), on_board)
    if homography is None:
        return None
    quads = np.concatenate([np.asarray(m, np.float64).reshape(-1, 4, 2) for m in markers])
    pixels = np.linalg.norm(quads - np.roll(quads, 1, axis=1), axis=2).min(axis=1)
    quads = quads[pixels >= _MIN_MARKER_PX]
    if not len(quads):
        return None
    mapped = cv2.perspectiveTransform(quads.reshape(-1, 1, 2), homography).reshape(-1, 4, 2)
    sides = np.linalg.norm(mapped - np.roll(mapped, 1, axis=1), axis=2).mean(axis=1)
    return float(np.median(sides))
