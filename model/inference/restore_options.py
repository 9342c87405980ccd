"""How to restore: :class:`RestoreOptions`, the values refused, the cameras ``--camera`` picks.

The choices and defaults themselves (importable without torch, for
``--help``) are in :mod:`lenspair.model.inference.options`; this module
holds the options of one run and the checks that need no input to refuse
them (:func:`check_options`).
"""

import logging
from dataclasses import dataclass
from pathlib import Path

from lenspair.capture.bag_frames import bag_camera_topics
from lenspair.capture.frames import InputKind
from lenspair.capture.recording import CAMERAS, find_rig_file, present_cameras
from lenspair.capture.rigfile import CameraName, read_rig_file
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import Backend
from lenspair.model.inference.options import (
    CAMERA_CHOICES,
    DEFAULT_BATCH_SIZE,
    DEFAULT_JPEG_QUALITY,
    DEFAULT_OVERLAP,
    MAX_JPEG_QUALITY,
)
from lenspair.model.inference.tiling import check_tile

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RestoreOptions:
    """How to restore.

    Attributes:
        camera: ``auto`` (the obstructed camera named by ``rig.yaml``, else
            every camera the recording holds: both, or the one of a
            recording of one camera), ``cam0``, ``cam1`` or ``both``;
            recordings and bags only.
        batch_size: frames per network call (>= 1).
        tile: square tile side in pixels, or None for whole images.
        overlap: pixels shared by neighbouring tiles.
        suffix: bags only: write restored images to ``<topic><suffix>``
            beside the originals instead of replacing them.
        resume: continue a killed run in a non-empty OUT.
        topics: bags only: the ``(cam0, cam1)`` image topics; None picks
            them from their names (:func:`lenspair.capture.bag_frames.bag_camera_topics`).
        jpeg_quality: the quality 1-100 of every restored JPEG: image files
            and JPEG ``CompressedImage`` messages (PNG, TIFF and raw images are
            unaffected; the input's own quality cannot be read to match it).
    """

    camera: str = "auto"
    batch_size: int = DEFAULT_BATCH_SIZE
    tile: int | None = None
    overlap: int = DEFAULT_OVERLAP
    suffix: str = ""
    resume: bool = False
    topics: tuple[str, str] | None = None
    jpeg_quality: int = DEFAULT_JPEG_QUALITY


def check_options(options: RestoreOptions, backend: Backend | None = None) -> None:
    """Refuse option values no input can use, before anything is read or written.

    Raises:
        ModelError: naming the option (``--batch-size``, ``--overlap``, ``--tile``,
            ``--jpeg-quality``);
            ``--tile`` for a model exported at a fixed size, which always runs
            on tiles of that size (the option was ignored without a word).
    """
    fixed = backend.fixed_size if backend is not None else None
    if options.tile is not None and fixed is not None:
        model = getattr(backend, "path", "the model")
        raise ModelError(
            f"--tile: {model} was exported at {fixed[1]}x{fixed[0]} and runs on tiles of "
            "that size; leave --tile out, or export it again (lenspair export) to run any "
            "size whole and in --tile tiles"
        )
    check_tile(options.tile)
    if options.batch_size < 1:
        raise ModelError(f"--batch-size: expected at least 1, got {options.batch_size}")
    if not 1 <= options.jpeg_quality <= MAX_JPEG_QUALITY:
        raise ModelError(
            f"--jpeg-quality: expected an integer from 1 to {MAX_JPEG_QUALITY}, "
            f"got {options.jpeg_quality}"
        )
    if options.overlap < 0:
        raise ModelError(f"--overlap: expected at least 0 pixels, got {options.overlap}")
    if options.tile is not None and options.tile <= options.overlap:
        raise ModelError(
            f"--tile: expected more than --overlap ({options.overlap}) pixels, got {options.tile}"
        )
    if options.tile is not None and 2 * options.overlap > options.tile:
        # --tile 16 --overlap 15 stepped one pixel at a time: minutes a frame, unsaid
        times = (options.tile / (options.tile - options.overlap)) ** 2
        log.warning(
            "--overlap %d of --tile %d: tiles step %d px, so each pixel is computed about %.0f "
            "times; an overlap up to half the tile computes each at most about 4 times",
            options.overlap, options.tile, options.tile - options.overlap, times,
        )  # fmt: skip


def resolve_cameras(
    path: Path, kind: InputKind, choice: str, topics: tuple[str, str] | None = None
) -> tuple[CameraName, ...]:
    """The cameras to restore for ``--camera`` (see :class:`RestoreOptions`).

    A bag with a single image topic has one camera (``cam0``), restored
    whatever ``rig.yaml`` says.

    Raises:
        ModelError: an unknown choice.
    """
    if choice not in CAMERA_CHOICES:
        raise ModelError(f"--camera: expected one of {', '.join(CAMERA_CHOICES)}, got {choice!r}")
    if kind in ("rosbag1", "rosbag2") and len(bag_camera_topics(path, topics)) == 1:
        return ("cam0",)
    if choice == "both":
        return CAMERAS
    if choice in CAMERAS:
        return ("cam0",) if choice == "cam0" else ("cam1",)
    rig = find_rig_file(path)
    if rig is not None:
        return (read_rig_file(rig).obstructed,)
    return present_cameras(path)  # a recording of one camera: that one
