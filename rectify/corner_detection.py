"""Finding a calibration board in an image: its inner corners, to sub-pixel accuracy.

:func:`detect_corners` finds the corners of a :class:`~lenspair.rectify.boards.Board`
and returns them as a :class:`Detection`, numbered by the board's corner ids
(see :mod:`~lenspair.rectify.boards`); for a ChArUco board it also measures
the markers' side on the image (:func:`measured_marker_m`).
:func:`marker_family` tells whether an image shows ArUco markers at all, which
a chessboard spec cannot see for itself. Images are ``uint8``/``uint16``,
``(H, W)`` or ``(H, W, 3)`` RGB; pixel coordinates follow OpenCV: the centre
of the top-left pixel is ``(0, 0)``.
"""

from collections.abc import Sequence
from dataclasses import dataclass

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
