"""Synthetic views of a calibration board for the rectify tests and the calibration benchmark.

Test-only scaffolding (moved out of ``lenspair.rectify.boards``): a direct
texture lookup through a lens model, much faster than the simulator's scene
renderer, for tests that need many board views with exactly known corners.
"""

import cv2
import numpy as np

from lenspair.rectify.boards import Board
from lenspair.rectify.projection import pixel_rays
from lenspair.rectify.rig import CameraModel


def board_texture(board: Board, pixels_per_square: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A printable image of the board, with a one-square white margin.

    Returns:
        ``(texture, board_to_texture)``: ``uint8`` ``(H, W)`` image and the 3x3
        float64 affine matrix taking board coordinates in metres (``x, y, 1``)
        to texture pixel coordinates.

    """
    s = pixels_per_square
    texture = board.printed_image(s)
    # object_points' origin: the first inner corner (margin + one square) or the outer corner
    origin = 2.0 * s if board.kind == "chessboard" else float(s)
    scale = s / board.square_m
    board_to_texture = np.array([[scale, 0, origin - 0.5], [0, scale, origin - 0.5], [0, 0, 1.0]])
    return np.asarray(texture, dtype=np.uint8), board_to_texture


class BoardRenderer:
    """Synthetic images of a board seen by a distorted camera (tests, benchmarks).

    Every output pixel is the area average of ``supersample**2`` samples of the
    board texture, each found by back-projecting the sample through the lens
    (:func:`lenspair.rectify.projection.pixel_rays`) and intersecting it with the
    board plane, so corners land where the camera model puts them.
    """

    def __init__(
        self, board: Board, camera: CameraModel, supersample: int = 2, pixels_per_square: int = 48
    ) -> None:
        """Prepare the texture and the per-sample rays of ``camera`` (done once).

        Args:
            board: the board to draw.
            camera: the camera that sees it.
            supersample: samples per output pixel along each axis.
            pixels_per_square: texture resolution.

        """
        self.camera = camera
        self.supersample = supersample
        self.texture, self.board_to_texture = board_texture(board, pixels_per_square)
        width, height = camera.resolution
        s = supersample
        ys, xs = np.mgrid[0 : height * s, 0 : width * s].astype(np.float64)
        samples = np.stack([(xs + 0.5) / s - 0.5, (ys + 0.5) / s - 0.5], axis=-1)
        self.rays = pixel_rays(camera, samples).astype(np.float32)

    def render(self, rvec: np.ndarray, tvec: np.ndarray, background: int = 110) -> np.ndarray:
        """Render the board at pose ``(rvec, tvec)`` (board -> camera, metres).

        Returns:
            ``uint8`` ``(H, W)`` image; ``background`` where the board is not seen.

        """
        rotation = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))[0]
        t = np.asarray(tvec, dtype=np.float64).reshape(3)
        normal = rotation[:, 2]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            depth = float(normal @ t) / (self.rays @ normal.astype(np.float32))
            points = self.rays * depth[..., None] - t.astype(np.float32)
            board_xy = points @ rotation[:, :2].astype(np.float32)  # R^T (p - t), first two axes
        affine = self.board_to_texture.astype(np.float32)
        map_x = board_xy[..., 0] * affine[0, 0] + affine[0, 2]
        map_y = board_xy[..., 1] * affine[1, 1] + affine[1, 2]
        behind = ~((depth > 0) & np.isfinite(map_x) & np.isfinite(map_y))
        map_x[behind] = -1e4
        map_y[behind] = -1e4
        fine = cv2.remap(
            self.texture, map_x, map_y, cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT, borderValue=background,
        )  # fmt: skip
        width, height = self.camera.resolution
        return np.asarray(cv2.resize(fine, (width, height), interpolation=cv2.INTER_AREA))
