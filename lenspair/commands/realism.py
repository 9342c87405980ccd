"""Do synthetic drops look real? Print five statistics of the pairs side by side.

For each set of (obstructed, clean) pairs, prints the range (min - max over
the pairs) of five statistics beside the range measured on real adherent
raindrops (4 Raindrop-like pairs): coverage, high-frequency share of the
difference, mean difference, contrast ratio and input PSNR (definitions in
lenspair.simulate.realism). A cell marked * misses the real range.

Sets of pairs are paired folders (a lenspair dataset split, an ingested
recording, input/+target/, lq/+gt/, or a Raindrop split such as test_a) and
drop presets rendered over clean images (by default the natural photographs
that scikit-image and matplotlib ship, at 720x480, Raindrop's size):

    lenspair realism --render ours sharp
    lenspair realism ingested/rain raindrop/test_a --render ours
    lenspair realism DS --split test --json realism.json

Pairs that cannot be read or measured (a truncated file, mismatched sizes,
a flat clean image, a clean image of a format lenspair does not read, an
image without its partner) are listed and skipped.
"""

import argparse
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from lenspair.commands.argtypes import (
    DEFAULT_SPLIT,
    input_path,
    out_file,
    random_seed,
    size,
    split_name,
)
from lenspair.core.bitdepth import widen
from lenspair.core.errors import ConfigError, LenspairError
from lenspair.core.fsutil import atomic_write_json
from lenspair.core.imageio import read_image
from lenspair.core.progress import progress
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.folder_notes import clean_bits
from lenspair.dataset.layouts import detect_layout
from lenspair.dataset.readers import PairedDataset, open_paired, read_mask
from lenspair.simulate.natural_images import fit, load_natural_images
from lenspair.simulate.presets import DROPS_PRESETS, drops_preset, find_clean_images
from lenspair.simulate.realism import (
    MeasuredPair,
    PairStatistics,
    format_ranges,
    measure_pairs,
    rendered_pairs,
    summarise,
)

DEFAULT_SIZE = (720, 480)
"""``--render`` size, width x height: the Raindrop dataset's frames."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the ``realism`` arguments."""
    parser.add_argument("pairs", type=input_path, nargs="*", help="paired folders to measure")
    parser.add_argument(
        "--split",
        type=split_name,
        help=f"split of a dataset root (default: {DEFAULT_SPLIT}); paired folders are measured "
        "whole",
    )
    parser.add_argument(
        "--render",
        nargs="*",
        metavar="PRESET",
        help=f"drop presets to render and measure ({', '.join(DROPS_PRESETS)}); "
        "default: ours sharp when no folder is given",
    )
    parser.add_argument(
        "--images",
        type=input_path,
        metavar="DIR",
        help="clean images to render on (default: the bundled natural photographs)",
    )
    parser.add_argument(
        "--size",
        type=size(16, 8192),  # 100000x100000 was an OpenCV allocation traceback
        metavar="WxH",
        help="render size (default: 720x480)",
    )
    parser.add_argument("--seed", type=random_seed, help="seed of the rendered drops (0)")
    parser.add_argument("--json", type=out_file, metavar="FILE", help="also write per-pair figures")


def run(args: argparse.Namespace) -> int:
    """Measure every set of pairs and print the table; returns the exit code."""
    presets = args.render if args.render is not None else ([] if args.pairs else ["ours", "sharp"])
    if not presets and not args.pairs:
        raise ConfigError("nothing to measure: give paired folders or --render PRESET")
    if not presets:  # said, not ignored: they shape rendered drops only
        unused = [
            f"--{name}" for name in ("images", "size", "seed") if getattr(args, name) is not None
        ]
        if unused:
            raise ConfigError(f"{', '.join(unused)}: for rendered drops; add --render PRESET")
    if args.split is not None and not any(detect_layout(f) is None for f in args.pairs):
        raise ConfigError(
            f"--split {args.split}: no dataset root given (a paired folder is measured whole); "
            "leave --split out, or give the dataset root whose split it is"
        )
    width, height = args.size or DEFAULT_SIZE
    shape = (height, width)
    seed = args.seed or 0
    _check_distinct(args.pairs, args.split or DEFAULT_SPLIT, presets)
    effects = {name: drops_preset(name) for name in presets}
    results: dict[str, list[PairStatistics]] = {}
    for folder in args.pairs:
        split = None if detect_layout(folder) is not None else args.split or DEFAULT_SPLIT
        dataset = open_paired(folder, split, strict=False)  # an orphan is listed and skipped
        unread = [PairStatistics(file, None, lacks) for file, lacks in dataset.unpaired]
        items = progress(
            _readable(dataset, unread),
            desc=f"realism {folder.name}",
            total=len(dataset),
            unit="pair",
        )
        results[_folder_label(folder, presets)] = measure_pairs(items) + unread
    if presets:
        skipped: list[PairStatistics] = []
        if args.images is not None:
            images = {}
            paths = find_clean_images(args.images)
            bits = clean_bits(args.images, paths)  # a Mono12 camera's frames, widened
            for path in paths:
                # by path below DIR: test_a/gt/0_clean.png and test_b/gt/0_clean.png are two
                name = path.relative_to(args.images).as_posix()
                try:
                    images[name] = fit(widen(read_image(path), bits), shape)
                except LenspairError as exc:  # this image only
                    skipped.append(PairStatistics(name, None, str(exc)))
        else:
            images = load_natural_images(shape)
        for name, spec in effects.items():
            pairs = progress(
                rendered_pairs(images, spec, seed),
                desc=f"realism {name}",
                total=len(images),
                unit="image",
            )
            results[name] = measure_pairs(pairs) + skipped
    columns = []
    for label, rows in results.items():
        for row in rows:
            if row.problem is not None:
                print(f"realism: {label}: skipped {row.name}: {row.problem}")
        measured = [row.statistics for row in rows if row.statistics is not None]
        if not rows:
            raise ConfigError(f"{label}: no pairs to measure (an empty folder or split)")
        if not measured:
            raise ConfigError(f"{label}: none of its {len(rows)} pairs could be measured")
        columns.append((f"{label} ({len(measured)})", summarise(measured)))
    print(format_ranges(columns))
    if args.json is not None:
        atomic_write_json(
            args.json, {label: [_row(r) for r in rows] for label, rows in results.items()}
        )
    return 0


def _check_distinct(folders: list[Path], split: str, presets: list[str]) -> None:
    """Refuse pairs or a preset given twice: two columns of the same figures.

    A folder is the pairs it stands for: a dataset root given beside its
    own split (``DS DS/test``) is the same pairs twice.
    """
    seen: dict[Path, Path] = {}
    for folder in folders:
        pairs = folder if detect_layout(folder) is not None else folder / split
        first = seen.setdefault(pairs.resolve(), folder)
        if first is not folder:
            raise ConfigError(f"{folder}: the same pairs as {first} ({pairs}), given twice")
    if twice := sorted({name for name in presets if presets.count(name) > 1}):
        raise ConfigError(f"--render: {', '.join(twice)} named twice")


def _folder_label(folder: Path, presets: list[str]) -> str:
    """The folder's column label: its path, with a slash where it reads like a preset's name."""
    label = str(folder)
    return f"{label}/" if label in presets else label


def _readable(dataset: PairedDataset, unread: list[PairStatistics]) -> Iterator[MeasuredPair]:
    """``(name, obstructed, clean, untrusted)`` of every readable pair; the others go to ``unread``.

    The files are read as they are: a grey clean image beside a colour
    obstructed one, or 8 bits beside 16, is measured (both go to grey
    ``[0, 1]``), where a training set would refuse the pair. 16-bit images
    holding 10- or 12-bit values are widened as the folder's reader says
    (:meth:`~lenspair.dataset.readers.PairedDataset.widened`). An ingested
    recording's or a dataset's ``mask/`` leaves its untrustworthy pixels
    (residual parallax) out of the statistics: they are the registration's,
    not the glass's.
    """
    for entry in dataset.entries:
        try:
            obstructed, clean = (
                dataset.widened(path, read_image(path))
                for path in (entry.input_path, entry.target_path)
            )
            if obstructed.shape[:2] != clean.shape[:2]:
                raise DatasetError(
                    f"{entry.input_path}: {obstructed.shape[1]}x{obstructed.shape[0]} does not "
                    f"match {entry.target_path} {clean.shape[1]}x{clean.shape[0]}"
                )
            mask = read_mask(entry, obstructed.shape[:2])  # as training reads it
        except LenspairError as exc:  # a truncated file, an unknown format, a size: this pair
            unread.append(PairStatistics(entry.name, None, str(exc)))
            continue
        yield entry.name, obstructed, clean, mask


def _row(row: PairStatistics) -> dict[str, Any]:
    """One pair for the JSON file (an infinite PSNR, identical images, becomes null)."""
    values: dict[str, Any] = {"name": row.name, "problem": row.problem}
    if row.statistics is not None:
        for key, value in vars(row.statistics).items():
            values[key] = value if math.isfinite(value) else None
    return values
