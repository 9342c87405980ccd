"""Readers of paired (obstructed, clean) image folders, for ``train`` and ``eval``.

Three layouts, detected automatically by :func:`open_paired`:

* ``lenspair``: a dataset built by ``dataset-build``: ``DS/<split>/input/``,
  ``DS/<split>/target/`` (and ``mask/``) with identical names, plus
  ``DS/manifest.jsonl`` for each pair's difficulty. Open the dataset root
  with a split name, or a split folder. A folder is one only when its
  ``dataset.json`` is a lenspair dataset card (format ``lenspair-dataset/1``),
  or, without a readable card, when the first row of its ``manifest.jsonl``
  is a lenspair manifest row: another tool's ``manifest.jsonl`` or
  ``dataset.json`` beside a paired folder leaves it a ``paired`` one.
* ``paired``: any folder with ``input/`` and ``target/`` (or ``lq/`` and
  ``gt/``) holding files of identical names (optionally ``mask/``); the
  convention of restoration toolkits.
* ``raindrop``: the Raindrop dataset of Qian et al. (DeRaindrop):
  ``data/N_rain.png`` paired with ``gt/N_clean.png``; ``.jpg`` is accepted
  too (the released test set mixes them). Open a split folder (``test_a``)
  or the root with ``split="test_a"``.

Names are matched on the file stem (``.png`` and ``.jpg`` may pair up) and
listed in natural order (``2`` before ``10``). Images are the files whose
suffix ``restore`` reads too (:data:`IMAGE_SUFFIXES`: PNG, TIFF, JPEG, BMP
and netpbm), so that ``train``, ``eval`` and ``restore`` see the same
images; files of other suffixes and sub-folders (not searched) are left out,
said in one warning. Images follow :mod:`lenspair.core.pixels`:
``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)`` RGB.

In a generic ``paired`` (or Raindrop) folder, ``mask/`` is taken in
lenspair's meaning (pixels left out of the loss and the scores), and 16-bit
images holding 10- or 12-bit values are widened to the full 16-bit range,
input and target alike, as ``restore`` does; both are said once
(:mod:`lenspair.dataset.folder_notes`). A ``lenspair`` dataset was widened
when it was ingested and is read as stored.
"""

from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lenspair.capture.ingested import PAIRS_FILE, REPORT_FILE
from lenspair.core.bitdepth import widen
from lenspair.core.errors import ImageIOError, listed
from lenspair.core.imageio import format_problem, image_header, read_image
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.folder_notes import (
    SUFFIX_TEXT,
    folder_bits,
    left_out,
    say,
    say_masks,
)
from lenspair.dataset.layouts import (
    FOLDERS,
    Layout,
    detect_layout,
    difficulties,
    index_images,
    natural_key,
    raindrop_key,
    split_folders,
    stem_key,
    unpaired_files,
)

Header = tuple[int, int, int, str]
"""An image's ``(height, width, channels, format)``
(:func:`~lenspair.core.imageio.image_header`)."""


@dataclass(frozen=True)
class PairEntry:
    """Where the files of one pair are (nothing read yet).

    Attributes:
        name: the pair's name (file stem; for Raindrop the number ``N``).
        input_path: obstructed image.
        target_path: clean image.
        mask_path: untrustworthy-pixel mask, when the layout has one.
        difficulty: ``easy``/``medium``/``hard``/``clean`` from a lenspair
            manifest, else None.
    """

    name: str
    input_path: Path
    target_path: Path
    mask_path: Path | None = None
    difficulty: str | None = None


@dataclass(frozen=True, eq=False)
class PairedItem:
    """One pair, read.

    Attributes:
        name: the pair's name.
        input: obstructed image, ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)``.
        target: clean image, same shape and dtype.
        mask: ``uint8`` ``(H, W)``, non-zero where untrustworthy; or None.
        difficulty: see :class:`PairEntry`.
    """

    name: str
    input: np.ndarray
    target: np.ndarray
    mask: np.ndarray | None = None
    difficulty: str | None = None


def is_ingested(folder: Path) -> bool:
    """A recording capture-ingest wrote: ``pairs.jsonl`` and ``report.json`` beside the pairs."""
    return (folder / PAIRS_FILE).is_file() and (folder / REPORT_FILE).is_file()


def _mask_mismatch(entry: PairEntry, mask: tuple[int, ...], image: tuple[int, ...]) -> str:
    """A mask whose ``(height, width)`` is not its input's, said about the mask file."""
    return (
        f"{entry.mask_path}: mask {mask[1]}x{mask[0]} does not match "
        f"{entry.input_path.name} {image[1]}x{image[0]}"
    )


def _format_problem(
    entry: PairEntry, have: Header, want: Header, mask: Header | None
) -> str | None:
    """The first file of the pair whose pixels :func:`read_image` refuses, said; or None."""
    files = [(entry.input_path, have), (entry.target_path, want)]
    if entry.mask_path is not None and mask is not None:
        files.append((entry.mask_path, mask))
    for path, header in files:
        if problem := format_problem(header[3]):
            return f"{path}: {problem}"
    return None


def read_mask(entry: PairEntry, size: tuple[int, ...]) -> np.ndarray | None:
    """The pair's untrustworthy-pixel mask, ``(H, W)`` (a colour file: any channel set), or None.

    Args:
        entry: the pair.
        size: ``(height, width)`` of its input.

    Raises:
        ImageIOError: the mask file is missing or unreadable (names it).
        DatasetError: the mask is not ``size`` (names the mask file).
    """
    if entry.mask_path is None:
        return None
    mask = read_image(entry.mask_path)
    mask = mask if mask.ndim == 2 else mask.max(axis=2)
    if mask.shape != tuple(size):
        raise DatasetError(_mask_mismatch(entry, mask.shape[:2], tuple(size)))
    return mask


class PairedDataset:
    """A list of pairs that reads its images on access (map-style, like a torch Dataset)."""

    def __init__(
        self,
        root: Path,
        layout: Layout,
        entries: Sequence[PairEntry],
        unpaired: Sequence[tuple[str, str]] = (),
        bits: int = 16,
    ) -> None:
        """Wrap ``entries`` found under ``root`` in ``layout``.

        ``unpaired`` holds ``(file, what it lacks)`` for each file left without
        a partner (``("input/c.png", "no target")``), which only a lenient
        :func:`open_paired` leaves out. ``bits`` (10, 12 or 16) is what the
        16-bit images hold: below 16 they are read widened to the full 16-bit
        range (:func:`lenspair.core.bitdepth.widen`).
        """
        self.root = Path(root)
        self.layout: Layout = layout
        self.entries: tuple[PairEntry, ...] = tuple(entries)
        self.unpaired: tuple[tuple[str, str], ...] = tuple(unpaired)
        self.bits = bits

    def __len__(self) -> int:
        """Number of pairs."""
        return len(self.entries)

    def __getitem__(self, index: int) -> PairedItem:
        """Read pair ``index``.

        Raises:
            ImageIOError: a file is missing or unreadable (names it).
            DatasetError: input and target differ in shape or dtype, or the
                mask in height and width; or a 16-bit image holds values above
                :attr:`bits` (widening would clip them).
        """
        entry = self.entries[index]
        input_image = read_image(entry.input_path)
        target = read_image(entry.target_path)
        if input_image.shape != target.shape or input_image.dtype != target.dtype:
            raise DatasetError(
                f"{entry.input_path}: {input_image.shape} {input_image.dtype} does not match "
                f"{entry.target_path} {target.shape} {target.dtype}"
            )
        input_image = self.widened(entry.input_path, input_image)
        target = self.widened(entry.target_path, target)
        mask = read_mask(entry, input_image.shape[:2])
        return PairedItem(entry.name, input_image, target, mask, entry.difficulty)

    def widened(self, path: Path, image: np.ndarray) -> np.ndarray:
        """``image`` (read from ``path``) on the full 16-bit scale, if it holds :attr:`bits`.

        Only a ``uint16`` image of a folder whose 16-bit images hold 10 or 12
        bits is widened; others are returned as they are.

        Raises:
            DatasetError: a value above :attr:`bits` (this pair's problem).
        """
        if self.bits >= 16 or image.dtype != np.uint16:
            return image
        top = (1 << self.bits) - 1
        if int(image.max()) > top:
            raise DatasetError(
                f"{path}: holds values above {top}, though {self.root}'s 16-bit images were "
                f"taken for {self.bits}-bit values from a sample (widening would clip it)"
            )
        return widen(image, self.bits)

    def header_problems(self) -> tuple[dict[int, Header], dict[int, str]]:
        """Every pair's files checked from their headers, pixels unread (fast).

        A training run reads its pairs for minutes or hours; a pair whose input
        and target differ in size, channels or bit depth, whose file cannot
        be opened, or whose input, target or mask holds pixels :func:`read_image`
        refuses (float, 32-bit: :func:`~lenspair.core.imageio.format_problem`),
        is better found before the first step than in epoch 40.

        Returns:
            ``(headers, problems)``: by pair index, the header of each good
            pair (:func:`~lenspair.core.imageio.image_header`: height, width,
            channels, format), and one line naming the file and the problem
            for each bad one.
        """
        headers: dict[int, Header] = {}
        problems: dict[int, str] = {}
        for index, entry in enumerate(self.entries):
            try:
                have = image_header(entry.input_path)
                want = image_header(entry.target_path)
                mask_header = image_header(entry.mask_path) if entry.mask_path else None
            except ImageIOError as exc:
                problems[index] = str(exc)
                continue
            mask = mask_header[:2] if mask_header else have[:2]
            if unreadable := _format_problem(entry, have, want, mask_header):
                problems[index] = unreadable
            elif have != want:
                problems[index] = (
                    f"{entry.input_path}: {have[1]}x{have[0]}x{have[2]} {have[3]} does not "
                    f"match {entry.target_path} {want[1]}x{want[0]}x{want[2]} {want[3]}"
                )
            elif mask != have[:2]:
                problems[index] = _mask_mismatch(entry, mask, have[:2])
            else:
                headers[index] = have
        return headers, problems

    def __iter__(self) -> Iterator[PairedItem]:
        """Read the pairs in order."""
        return (self[i] for i in range(len(self)))

    @property
    def names(self) -> tuple[str, ...]:
        """Pair names, in order."""
        return tuple(entry.name for entry in self.entries)

    def select(self, difficulties: Collection[str]) -> "PairedDataset":
        """The pairs whose difficulty is in ``difficulties`` (e.g. ``{"easy", "medium"}``)."""
        kept = [e for e in self.entries if e.difficulty in difficulties]
        return PairedDataset(self.root, self.layout, kept, bits=self.bits)

    def __repr__(self) -> str:
        """Short description."""
        return f"PairedDataset({str(self.root)!r}, layout={self.layout!r}, pairs={len(self)})"


def open_paired(
    path: Path, split: str | None = None, strict: bool = True, notes: list[str] | None = None
) -> PairedDataset:
    """Open paired images in any supported layout.

    Args:
        path: a folder holding the paired sub-folders, or a dataset root
            whose sub-folder ``split`` does.
        split: split name (``train``, ``val``, ``test``, ``test_a``, ...);
            required for a dataset root.
        strict: refuse files without a partner (training and scoring must
            not pass over a pair); False leaves them out and names them in
            :attr:`PairedDataset.unpaired` (a report that lists what it skips).
        notes: collects the warnings about the folder (files and sub-folders
            left out, a generic ``mask/``, 10/12-bit values: module docstring)
            instead of logging them now; a training run logs them into its own
            log.

    Raises:
        DatasetError: no folder, no recognised layout, a missing split, a
            name that appears twice, no images in the input folder (saying
            what it holds), or (``strict``) files without a partner (the
            message lists a few).
    """
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: not a folder")
    folder = path
    if split is not None and (path / split).is_dir():
        folder = path / split
    elif split is not None and path.name != split:
        found = ", ".join(split_folders(path))
        if not found:  # not a dataset at all: say what a paired folder holds
            raise DatasetError(
                f"{path}: no paired images (expected input/ + target/, lq/ + gt/ or Raindrop "
                "data/ + gt/ folders, or split folders holding them)"
            )
        raise DatasetError(f"{path}: no split folder {split!r} (splits found: {found})")
    layout = detect_layout(folder)
    if layout is None:
        splits = split_folders(path)
        if splits:
            raise DatasetError(f"{path}: holds several splits; choose one of {', '.join(splits)}")
        raise DatasetError(
            f"{folder}: no paired images found (expected input/ + target/, lq/ + gt/, "
            "or Raindrop data/ + gt/)"
        )
    input_dir, target_dir = FOLDERS[layout]
    if layout == "paired" and not all((folder / d).is_dir() for d in (input_dir, target_dir)):
        # the pair of folders detect_layout found: input/ + target/ first
        input_dir, target_dir = "lq", "gt"
    key = raindrop_key if layout == "raindrop" else stem_key
    skipped: list[str] = []
    inputs = index_images(folder, input_dir, key, skipped)
    targets = index_images(folder, target_dir, key, skipped)
    masks = index_images(folder, "mask", key, skipped) if (folder / "mask").is_dir() else {}
    unpaired = unpaired_files(input_dir, target_dir, inputs, targets, masks)
    skipped_text = left_out(skipped)
    if unpaired and strict:
        names = listed([f"{file} ({lacks})" for file, lacks in unpaired], 5, ", ")
        also = f"; left out: {skipped_text}" if skipped_text else ""
        raise DatasetError(f"{folder}: {len(unpaired)} unpaired file(s): {names}{also}")
    if not inputs and layout != "lenspair":  # a lenspair split may be empty (fraction 0)
        held = left_out([entry for entry in skipped if entry.startswith(f"{input_dir}/")])
        holds = f"it holds {held}" if held else "it is empty"
        raise DatasetError(
            f"{folder}: no images in {input_dir}/ ({holds}; images are files ending {SUFFIX_TEXT})"
        )
    if skipped_text:
        say(
            notes,
            f"{folder}: left out of the pairs: {skipped_text}; images are files ending "
            f"{SUFFIX_TEXT}",
        )
    difficulty = difficulties(folder) if layout == "lenspair" else {}
    entries = [
        PairEntry(name, inputs[name], targets[name], masks.get(name), difficulty.get(name))
        for name in sorted(inputs.keys() & targets.keys(), key=natural_key)
    ]
    bits = 16
    # a lenspair dataset's or ingested recording's 16-bit frames were widened when
    # ingested, and its mask/ is lenspair's own
    if layout != "lenspair" and not is_ingested(folder):
        if layout == "paired":
            say_masks(folder, sum(entry.mask_path is not None for entry in entries), notes)
        bits = folder_bits(folder, [(e.input_path, e.target_path) for e in entries], notes)
    return PairedDataset(folder, layout, entries, unpaired, bits)
