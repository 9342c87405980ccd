"""What lenspair makes of a paired folder's files beyond the pairs, said once.

Readers of paired folders (:mod:`lenspair.dataset.readers`) apply lenspair's
own conventions to any folder, a generic ``paired`` one too; these helpers
tell what they did, in one warning each, logged at once or kept in ``notes``
for a training run to log into its own log:

* files of suffixes other than :data:`IMAGE_SUFFIXES` and sub-folders (not
  searched) are left out of the pairs (:func:`left_out`);
* ``mask/`` marks the pixels registration cannot vouch for, left out of the
  training loss and of every score. Other projects' ``mask/`` often marks
  the anomaly (where the rain is): leaving that out inflates the scores
  (:func:`say_masks`);
* 16-bit images holding 10- or 12-bit values (a Mono10/Mono12 camera's
  words) are scaled to the full 16-bit range, input and target alike, as
  ``capture-ingest`` and ``restore`` do (:mod:`lenspair.core.bitdepth`); the
  depth is told from a sample of the pairs (:func:`folder_bits`).
"""

import logging
from collections.abc import Sequence
from pathlib import Path

from lenspair.capture.folders import IMAGE_SUFFIXES as FRAME_SUFFIXES
from lenspair.core.bitdepth import significant_bits
from lenspair.core.errors import ImageIOError
from lenspair.core.imageio import image_header, read_image
from lenspair.core.spread import spread_indices

log = logging.getLogger(__name__)

IMAGE_SUFFIXES: frozenset[str] = FRAME_SUFFIXES
"""Suffixes of the files read as images (any case): those ``restore`` reads as frames
(PNG, TIFF, JPEG, BMP, netpbm), so that ``train``, ``eval`` and ``restore`` see the same
images."""
SUFFIX_TEXT = ", ".join(sorted(IMAGE_SUFFIXES))
BIT_DEPTH_PAIRS = 32
"""Pairs, spread over a folder, whose 16-bit images tell the bits they use (as
``capture-ingest`` samples a recording's frames)."""


def say(notes: list[str] | None, message: str) -> None:
    """Log a warning about the folder now, or keep it in ``notes`` for a run to log."""
    if notes is None:
        log.warning("%s", message)
    else:
        notes.append(message)


def left_out(skipped: Sequence[str]) -> str:
    """``2 file(s) not read as images (e.g. input/a.txt) and 1 sub-folder(s), ...``; "" for none.

    Args:
        skipped: ``sub/file`` for each file of another suffix, ``sub/dir/``
            for each sub-folder.
    """
    folders = [entry for entry in skipped if entry.endswith("/")]
    files = [entry for entry in skipped if not entry.endswith("/")]
    parts = []
    if files:
        parts.append(f"{len(files)} file(s) not read as images (e.g. {files[0]})")
    if folders:
        parts.append(f"{len(folders)} sub-folder(s), not searched (e.g. {folders[0]})")
    return " and ".join(parts)


def say_masks(folder: Path, used: int, notes: list[str] | None) -> None:
    """Say what a generic folder's ``mask/`` is taken for, when ``used`` pairs have a mask."""
    if used:
        say(
            notes,
            f"{folder / 'mask'}/: {used} masks mark pixels left out of the loss and the scores "
            "(lenspair's meaning: pixels the registration cannot vouch for); remove or rename "
            "mask/ if yours marks the anomaly",
        )


def folder_bits(
    folder: Path,
    pairs: Sequence[tuple[Path, ...]],
    notes: list[str] | None = None,
    scaled: str = "input and target are",
) -> int:
    """The bits the 16-bit images of a paired folder use: 10, 12 or 16.

    Told by :func:`lenspair.core.bitdepth.significant_bits` from the inputs
    and targets of :data:`BIT_DEPTH_PAIRS` of the ``(input, target)`` pairs,
    spread over them (headers first: a folder of 8-bit images reads no
    pixels). One depth for input and target alike, so that a pair stays
    comparable; below 16 it is said once (``scaled`` names what is scaled).
    A file that cannot be read is left to the pair's own checks.
    """
    depths = []
    for index in spread_indices(len(pairs), BIT_DEPTH_PAIRS):
        for path in pairs[index]:
            try:
                if image_header(path)[3] == "uint16":
                    depths.append(significant_bits([read_image(path)]))
            except ImageIOError:
                continue
    bits = max(depths, default=16)
    if bits < 16:
        say(
            notes,
            f"{folder}: its 16-bit images hold {bits}-bit values (none above {(1 << bits) - 1} "
            f"in {len(depths)} sampled images): {scaled} scaled to the full 16-bit range, "
            "as capture-ingest and restore do",
        )
    return bits


def clean_bits(folder: Path, images: Sequence[Path], notes: list[str] | None = None) -> int:
    """The bits the 16-bit images of a folder of clean images use: 10, 12 or 16.

    As :func:`folder_bits`, over single images: drops rendered on a Mono12
    camera's frames read as 16-bit data were rendered on a nearly black
    scene (``train --synthetic``, ``realism --images``, the detector's
    synthetic samples).
    """
    return folder_bits(folder, [(path,) for path in images], notes, "the clean images are")
