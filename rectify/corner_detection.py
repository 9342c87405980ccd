"""Finding a calibration board in an image: its inner corners, to sub-pixel accuracy.

:func:`detect_corners` finds the corners of a :class:`~lenspair.rectify.boards.Board`
and returns them as a :class:`Detection`, numbered by the board's corner ids
(see :mod:`~lenspair.rectify.boards`); for a ChArUco board it also measures
the markers' side on the image (:func:`measured_marker_m`).
:func:`marker_family` tells whether an image shows ArUco markers at all, which
a chessboard spec cannot see for itself, and :func:`spec_hint` why a spec may
find the board in no frame (another marker family, ChArUco pattern or size).
Images are ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)`` RGB; pixel
coordinates follow OpenCV: the centre of the top-left pixel is ``(0, 0)``.
"""

from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from lenspair.rectify.boards import Board
from lenspair.rectify.errors import RectifyError

_MIN_CORNERS = 6


@dataclass(frozen=True)
class Detection:
    """Inner corners of a board found in one image.

    Attributes:
        ids: ``(N,)`` int32 corner ids (see :mod:`~lenspair.rectify.boards`), ascending.
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
    if board.marker_m is not None:
        # 0.75 x the white gap between corner and marker: a window reaching the
        # markers' edges is pulled by them (simulated boards, markers 0.6-0.8 of
        # a square: corner errors 0.06-0.09 px at 0.75, against 0.08-0.21 px at
        # 1.25 and 0.08-0.15 px for OpenCV's own corners)
        fraction = 0.75 * (board.square_m - board.marker_m) / (2 * board.square_m)
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


def spec_hint(images: list[np.ndarray], board: Board) -> str:
    """Why a board spec may find the board in few or no views, from a few frames; ``""`` if unknown.

    For ``lenspair calibrate``'s error (its ``--board``): the first cause of
    :func:`_charuco_hint` or :func:`_squares_hint` seen, as a clause starting
    with ``"; "``.

    Args:
        images: a few frames of the recording (the board may be in some only).
        board: the board spec given.
    """
    if not images:
        return ""
    return _charuco_hint(images, board) or next(
        (hint for image in images if (hint := _squares_hint(image, board))), ""
    )


def _squares_hint(image: np.ndarray, board: Board) -> str:
    """Why a chessboard may be found in few or no views: its corners miscounted.

    A chessboard spec counts inner corners (OpenCV's, ROS's and Kalibr's
    convention): a board of 10x7 squares is ``chessboard:9x6``. Given as
    ``10x7``, it is found in no view, and that was all that was said; given a
    corner short (``8x6``), OpenCV still finds that sub-grid in a few views,
    and the calibration failed for "too few views". Nothing is said where the
    spec itself is found in ``image``.
    """
    if board.kind != "chessboard" or detect_corners(image, board, thorough=False) is not None:
        return ""
    columns, rows = board.columns, board.rows
    for other_columns, other_rows in (
        (columns - 1, rows - 1),
        (columns + 1, rows),
        (columns, rows + 1),
        (columns + 1, rows + 1),
    ):
        if min(other_columns, other_rows) < 3:
            continue
        corners = replace(board, columns=other_columns, rows=other_rows)
        if detect_corners(image, corners, thorough=False) is None:
            continue
        squares = other_columns < columns
        why = "counts inner corners, not squares" if squares else "counts every inner corner"
        return (
            f"; the frames show a chessboard of {other_columns}x{other_rows} inner corners: "
            f"the spec {why} (chessboard:{other_columns}x{other_rows}:...)"
        )
    return ""


def _charuco_hint(images: list[np.ndarray], board: Board) -> str:
    """Why a ChArUco board may be found in no view: its markers' family, pattern or size.

    The chessboard corners of a ChArUco board are found through its markers;
    a spec naming another marker family, the squares the other way round
    (ROWSxCOLS), or a board of even ROWS printed with the other pattern
    (OpenCV < 4.6's legacy one, or the current one given ``:legacy``) finds
    none, and said only "found in 0 views".

    Args:
        images: a few frames of the recording (the board may be in some only).
        board: the board spec given.
    """
    if board.kind != "charuco" or board.dictionary is None:
        return ""
    family = next((f for image in images if (f := marker_family(image)) is not None), None)
    if family is None:
        return ""
    seen = family.rsplit("_", 1)[0]  # DICT_4X4
    if not board.dictionary.startswith(f"{seen}_"):
        return (
            f"; the frames show {seen} markers, not {board.dictionary}'s: give the board's "
            "dictionary as the spec's last field"
        )
    other = replace(board, legacy=not board.legacy)
    # the two patterns differ only for even ROWS; otherwise the board would have been found
    if board.rows % 2 == 0 and any(detect_corners(image, other) is not None for image in images):
        if other.legacy:
            return (
                "; the board is the legacy pattern (OpenCV < 4.6): add :legacy to --board "
                f"({other.spec()})"
            )
        return (
            "; the board is not the legacy pattern (it follows OpenCV >= 4.6): drop :legacy "
            f"from --board ({other.spec()})"
        )
    return (
        f"; {seen} markers are seen, so check COLSxROWS (squares across, then down, as the "
        "board was generated) and the dictionary's size"
    )
