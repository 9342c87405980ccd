"""The layouts of paired image folders, and listing a folder's images by name.

:func:`detect_layout` tells a ``lenspair`` dataset split, a generic
``paired`` folder (``input/`` + ``target/`` or ``lq/`` + ``gt/``) and a
Raindrop folder (``data/`` + ``gt/``) apart; :func:`index_images` lists the
images of one sub-folder by the name they pair on, and what it left out.
:func:`lenspair.dataset.readers.open_paired` puts both together (its module
docstring describes the layouts).
"""

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Literal

from lenspair.core.config import load_dataclass
from lenspair.core.errors import ConfigError
from lenspair.dataset.card import CARD_FILE, CARD_FORMAT
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.folder_notes import IMAGE_SUFFIXES
from lenspair.dataset.manifest import MANIFEST_FILE, ManifestRow, read_manifest

Layout = Literal["lenspair", "paired", "raindrop"]
FOLDERS: dict[Layout, tuple[str, str]] = {
    "lenspair": ("input", "target"),
    "paired": ("input", "target"),
    "raindrop": ("data", "gt"),
}
IMAGE_FOLDERS: tuple[str, ...] = ("input", "target", "mask", "lq", "gt", "data")
"""Sub-folders of a paired folder whose files the readers take as images (of any layout)."""
RAINDROP_SUFFIX = re.compile(r"_(rain|clean)$")


def detect_layout(folder: Path) -> Layout | None:
    """Layout of a folder that directly holds the paired sub-folders, or None.

    ``input/`` + ``target/`` are a lenspair split when the parent folder is a
    lenspair dataset (:func:`is_lenspair_dataset`): a ``manifest.jsonl`` or
    ``dataset.json`` of another tool beside a plain paired folder made it
    unreadable (its manifest was read strictly).
    """
    folder = Path(folder)
    if (folder / "input").is_dir() and (folder / "target").is_dir():
        return "lenspair" if is_lenspair_dataset(folder.parent) else "paired"
    if (folder / "lq").is_dir() and (folder / "gt").is_dir():
        return "paired"
    if (folder / "data").is_dir() and (folder / "gt").is_dir():
        return "raindrop"
    return None


def is_lenspair_dataset(root: Path) -> bool:
    """True when ``root`` holds a dataset built by ``dataset-build``.

    Its ``dataset.json`` decides when it is a JSON object: a lenspair card has
    format ``lenspair-dataset/1``, anything else is another tool's (COCO,
    Hugging Face). Without a card, or with one that cannot be parsed, the
    first row of ``manifest.jsonl`` decides: a lenspair manifest row (a dataset
    whose card was lost or never written), or not. Only that row is read, so
    a damaged later row is still reported by the strict manifest reader.
    """
    try:
        card = json.loads((Path(root) / CARD_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        card = None
    if isinstance(card, dict):
        return card.get("format") == CARD_FORMAT
    try:
        with (Path(root) / MANIFEST_FILE).open(encoding="utf-8") as manifest:
            first = next((line for line in manifest if line.strip()), None)
        if first is None:
            return False
        load_dataclass(ManifestRow, json.loads(first))
    except (OSError, ValueError, ConfigError):
        return False
    return True


def split_folders(root: Path) -> list[str]:
    """Names of ``root``'s sub-folders that hold paired images (a dataset's splits), sorted."""
    return sorted(p.name for p in Path(root).iterdir() if p.is_dir() and detect_layout(p))


def natural_key(name: str) -> tuple[tuple[tuple[int, int | str], ...], str]:
    """Sort key that orders embedded numbers by value (``2`` before ``10``).

    Names whose numbers differ only in leading zeros (``img1``, ``img01``)
    have the same value; the name itself then decides, so that the order is
    total: sorted from a set, pairs came in an order that changed from run to
    run with Python's string hashing, and a seeded shuffle drew other pairs.
    """
    parts = re.split(r"(\d+)", name)
    return tuple((0, int(p)) if p.isdigit() else (1, p) for p in parts if p), name


def stem_key(path: Path) -> str:
    """The name a file pairs on: its stem."""
    return path.stem


def raindrop_key(path: Path) -> str:
    """The name a Raindrop file pairs on: its stem without ``_rain``/``_clean``."""
    return RAINDROP_SUFFIX.sub("", path.stem)


def index_images(
    folder: Path, sub: str, key: Callable[[Path], str], skipped: list[str]
) -> dict[str, Path]:
    """Name -> image file of ``folder/sub``; what is left out goes to ``skipped``.

    ``skipped`` gets ``sub/file`` for a file of another suffix and ``sub/dir/``
    for a sub-folder (not searched); hidden entries (``.DS_Store``) are passed over.
    """
    found: dict[str, Path] = {}
    for file in sorted((folder / sub).iterdir()):
        if file.name.startswith("."):
            continue
        if file.is_dir():
            skipped.append(f"{sub}/{file.name}/")
            continue
        if file.suffix.lower() not in IMAGE_SUFFIXES:
            skipped.append(f"{sub}/{file.name}")
            continue
        name = key(file)
        if name in found:
            raise DatasetError(f"{file}: name {name!r} also used by {found[name].name}")
        found[name] = file
    return found


def unpaired_files(
    input_dir: str,
    target_dir: str,
    inputs: dict[str, Path],
    targets: dict[str, Path],
    masks: dict[str, Path],
) -> list[tuple[str, str]]:
    """``(file, what it lacks)`` for each file without a partner, in natural order."""
    unpaired = [
        (f"{input_dir}/{inputs[n].name}", f"no {target_dir}") for n in inputs.keys() - targets
    ]
    unpaired += [
        (f"{target_dir}/{targets[n].name}", f"no {input_dir}") for n in targets.keys() - inputs
    ]
    unpaired += [(f"mask/{masks[n].name}", "no pair") for n in masks.keys() - inputs]
    return sorted(unpaired, key=lambda orphan: natural_key(orphan[0]))


def difficulties(split_folder: Path) -> dict[str, str]:
    """Each pair's difficulty in a lenspair split, from the dataset's manifest (none: empty)."""
    manifest = split_folder.parent / MANIFEST_FILE
    if not manifest.is_file():
        return {}
    return {
        row.name: row.difficulty
        for row in read_manifest(manifest)
        if row.split == split_folder.name
    }
