"""The dataset folder on disk: writing its files, and putting it in place of ``out``.

A build writes into a temporary sibling folder: first the records that tell
two datasets apart (:func:`write_records`), so a rebuild can be refused before
any image is copied (:func:`check_replaceable`), then the images and contact
sheets (:func:`write_images`). :func:`place_dataset` renames the finished
folder into place, replacing an old dataset only when allowed and carrying the
user's own files over; :func:`recover_swap` puts back an old dataset that a
build killed during that swap had set aside.
"""

import contextlib
import json
import logging
import os
import shutil
import stat
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Literal

from lenspair.core.config import dump_yaml
from lenspair.core.folderlock import holding, lock_shared
from lenspair.core.fsutil import (
    atomic_write_text,
    clone_file,
    temporary_folder,
)
from lenspair.core.imagewrite import write_image
from lenspair.core.leftovers import leftovers
from lenspair.core.progress import progress
from lenspair.dataset.card import CARD_FILE, DatasetCard, contact_sheet, write_card
from lenspair.dataset.config import SPLITS, DatasetConfig
from lenspair.dataset.curation import Measured
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.layouts import is_lenspair_dataset
from lenspair.dataset.manifest import (
    MANIFEST_FILE,
    REMOVED_FILE,
    ManifestRow,
    RemovedPair,
    write_manifest,
    write_removed,
)
from lenspair.dataset.verify import CONFIG_FILE, dataset_difference, user_files

logger = logging.getLogger(__name__)
LinkMode = Literal["copy", "hard"]
_WRITE_BITS = stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH


def write_records(
    folder: Path,
    rows: Sequence[ManifestRow],
    card: DatasetCard,
    config: DatasetConfig,
    removed: list[RemovedPair],
) -> None:
    """Write the manifest, card, ``removed.jsonl`` and ``config.yaml`` into ``folder``.

    They are what tells two datasets apart (with the file list the rows give),
    so a rebuild can be compared with the dataset it would replace before a
    single image is copied.
    """
    write_manifest(folder / MANIFEST_FILE, list(rows))
    write_card(folder / CARD_FILE, card)
    write_removed(folder / REMOVED_FILE, removed)
    atomic_write_text(folder / CONFIG_FILE, dump_yaml(config))


def write_images(
    folder: Path, pairs: Sequence[tuple[ManifestRow, Measured]], link: LinkMode = "copy"
) -> None:
    """Place every pair's images under ``folder`` and draw the contact sheets."""
    for name in SPLITS:
        for kind in ("input", "target"):
            (folder / name / kind).mkdir(parents=True, exist_ok=True)
    for row, m in progress(pairs, desc="linking", total=len(pairs), unit="pair"):
        for kind, relative in row.files.items():
            destination = folder / relative
            destination.parent.mkdir(parents=True, exist_ok=True)
            _place_image(m.files[kind], destination, link)
    rows = [row for row, _ in pairs]
    for name in SPLITS:
        selected = [row for row in rows if row.split == name]
        if selected:
            write_image(folder / f"contact_{name}.png", contact_sheet(folder, name, selected))


def _place_image(source: Path, destination: Path, link: LinkMode) -> None:
    if link == "hard":
        try:
            os.link(source, destination)
        except OSError as exc:
            raise DatasetError(  # the destination lies in the build's temporary folder
                f"{source}: --link hard cannot link it into the dataset ({exc.strerror}); "
                "the default copies instead"
            ) from None
        os.chmod(destination, os.stat(destination).st_mode & ~_WRITE_BITS)
        return
    clone_file(source, destination)


DATASET_LOCK = ".lenspair-dataset.lock"
"""The file of a dataset whose ``flock`` its readers share and a rebuild takes.

Its readers are the commands that name a dataset among their inputs
(``train``, ``tradeoff``, ``eval``, ``export --calibration``,
``train-detector``): see :func:`reading_datasets`."""


def _own_entries() -> frozenset[str]:
    """Top-level names a build writes (:func:`write_records`, :func:`write_images`).

    Anything else is the user's.
    """
    contact = {f"contact_{name}.png" for name in SPLITS}
    own = {*SPLITS, MANIFEST_FILE, CARD_FILE, REMOVED_FILE, CONFIG_FILE, DATASET_LOCK}
    return frozenset(own | contact)


def dataset_root(path: Path) -> Path | None:
    """The lenspair dataset ``path`` is, or whose split folder it is (``DS/test``).

    Returns:
        That dataset's root; ``None`` for any other folder or layout (a
        Raindrop folder, a paired folder: nothing of lenspair rewrites them).
    """
    path = Path(path)
    if path.is_dir() and is_lenspair_dataset(path):
        return path
    if path.name in SPLITS and path.parent.is_dir() and is_lenspair_dataset(path.parent):
        return path.parent
    return None


@contextlib.contextmanager
def reading_datasets(paths: Iterable[Path]) -> Iterator[None]:
    """Hold a shared lock on each lenspair dataset among ``paths`` meanwhile.

    ``dataset-build --overwrite`` swapped ``DS`` under a running ``train``,
    which then died blaming a missing pair, or went on over a mix of the two
    datasets where their file names agreed. Every command reading a dataset
    holds its lock while it runs (``lenspair.cli``), so no rebuild replaces
    it meanwhile; a split folder (``DS/test``) locks its dataset. Other
    layouts get no lock file.

    Raises:
        DatasetError: a dataset-build is replacing one of them now.
    """
    with contextlib.ExitStack() as held:
        for path in paths:
            root = dataset_root(path)
            if root is None:
                continue
            try:
                descriptor = lock_shared(root / DATASET_LOCK, create=True)
            except BlockingIOError:
                raise DatasetError(
                    f"{path}: a dataset-build is replacing it; run again when it has finished"
                ) from None
            if descriptor is not None:  # None: a read-only dataset, which nothing rebuilds
                held.callback(os.close, descriptor)  # closing releases the lock
        yield


@contextlib.contextmanager
def replacing(out: Path, probe: bool = False) -> Iterator[None]:
    """Hold a dataset's lock exclusively meanwhile: refused while a ``train`` reads it.

    With ``probe`` (a build's early check, before minutes of measuring) a
    dataset without a lock file, which no reader holds, is left without one:
    a refused build writes nothing into it.

    Raises:
        DatasetError: a reader holds it.
    """
    if out_state(out) != "dataset" or (probe and not (out / DATASET_LOCK).exists()):
        yield
        return
    taken = DatasetError(
        f"{out}: another lenspair command (train, tradeoff, eval, export, train-detector) "
        "is reading it; rebuild it when that has finished, or give another --out"
    )
    with holding(out / DATASET_LOCK, "dataset-build", taken):
        yield


def _json_object(path: Path) -> bool:
    """Whether ``path`` holds a JSON object (a card, lenspair's or another tool's)."""
    try:
        return isinstance(json.loads(path.read_text(encoding="utf-8")), dict)
    except (OSError, ValueError):
        return False


def out_state(out: Path) -> Literal["absent", "empty", "dataset"]:
    """What ``out`` holds now; raise when it is something that must not be replaced.

    A lenspair dataset is told as the readers tell it
    (:func:`~lenspair.dataset.layouts.is_lenspair_dataset`): by its card's
    format tag, or, with a card that cannot be parsed, by its manifest's first
    row. A ``dataset.json`` or ``manifest.jsonl`` of another tool (COCO,
    Hugging Face) is not one, and is never replaced, even with ``--overwrite``.
    """
    if not out.exists():
        return "absent"
    if not out.is_dir():
        raise DatasetError(f"{out}: exists and is not a folder")
    if not any(out.iterdir()):
        return "empty"
    if is_lenspair_dataset(out):
        return "dataset"
    if _json_object(out / CARD_FILE):
        raise DatasetError(
            f"{out}: its {CARD_FILE} is not a lenspair dataset card; refusing to replace "
            "the folder (choose another --out)"
        )
    raise DatasetError(
        f"{out}: not empty and not a lenspair dataset; refusing to replace it (choose another "
        "--out)"
    )


def check_replaceable(out: Path, temp: Path, rows: Sequence[ManifestRow] | None = None) -> None:
    """Refuse to replace a different dataset at ``out`` (see :func:`place_dataset`).

    With ``rows``, ``temp`` need only hold the new manifest, card, config and
    ``removed.jsonl`` (:func:`write_records`): the new file list is the rows'
    files, so the refusal comes before any image is copied. Without, the
    images in ``temp`` are listed.

    Raises:
        DatasetError: ``out`` holds a dataset that differs from the new one.
    """
    if out_state(out) != "dataset":
        return
    listed = None
    if rows is not None:
        listed = {Path(relative) for row in rows for relative in row.files.values()}
    difference = dataset_difference(out, temp, listed)
    if difference is not None:
        raise DatasetError(
            f"{out}: holds a different dataset ({difference}); use --overwrite to replace it"
        )


def place_dataset(temp: Path, out: Path, overwrite: bool) -> None:
    """Rename the finished ``temp`` to ``out``, replacing an old dataset when allowed.

    Files and folders the user put into an old dataset (notes, evaluations)
    are carried over into the new one, with a warning; a rebuild used to
    delete them.
    """
    state = out_state(out)
    if state == "dataset" and not overwrite:
        check_replaceable(out, temp)
    if state == "absent":
        os.replace(temp, out)
        return
    own = _own_entries()
    theirs = sorted(p.name for p in out.iterdir() if p.name not in own)
    # and what they put inside the split folders (an evaluation in train/restored/)
    inside = [p for p in user_files(out) if not (temp / p).exists()]
    for name in [*theirs, *map(str, inside)]:  # linked, not moved: kept until the swap
        (temp / name).parent.mkdir(parents=True, exist_ok=True)
        _link_tree(out / name, temp / name)
    theirs += sorted({str(Path(*p.parts[:2])) for p in inside})  # by folder: train/restored
    trash = temporary_folder(out.parent, out.name, ".old")
    try:
        with replacing(out):  # not under a train reading it
            os.replace(out, trash / "dataset")
            os.replace(temp, out)
    except BaseException:  # a refused rename, and Ctrl-C or SIGTERM between the two
        if not out.exists() and (trash / "dataset").is_dir():
            os.replace(trash / "dataset", out)  # put the old dataset back
        raise
    finally:
        if out.exists():  # else the old dataset is still set aside: recover_swap finds it
            shutil.rmtree(trash, ignore_errors=True)
    if theirs:
        logger.warning(
            "%s: kept %s, not part of the dataset, in the rebuilt one", out, ", ".join(theirs)
        )


def recover_swap(out: Path) -> None:
    """Put back the dataset a build killed during its swap (:func:`place_dataset`) had set aside.

    Between the swap's two renames the old dataset, with the user's files in it,
    lies in a ``.<name>.<pid>.*.old`` folder and ``out`` is missing; the rerun's
    clean-up of leftovers would delete it. When ``out`` exists the swap finished
    and the set-aside copy is a leftover like any other.
    """
    if out.exists():
        return
    for trash in leftovers(out.parent, out.name):
        if trash.name.endswith(".old") and (trash / "dataset").is_dir():
            os.replace(trash / "dataset", out)
            logger.warning("%s: put back from %s, set aside by an interrupted rebuild", out, trash)
            return


def _link_tree(source: Path, destination: Path) -> None:
    """Hard-link ``source`` (a file, or a folder's files) at ``destination``, else copy."""

    def link(src: str, dst: str) -> None:
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)

    if source.is_dir() and not source.is_symlink():
        shutil.copytree(source, destination, symlinks=True, copy_function=link)
    elif source.is_symlink():
        os.symlink(os.readlink(source), destination)
    else:
        link(str(source), str(destination))
