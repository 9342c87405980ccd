"""Check a built dataset against its manifest and card (``dataset-build --verify``).

Every problem is one line naming the file: a file the manifest lists but that
is missing, a sha256 mismatch, a file under a split folder that the manifest
does not list, a row whose files lie outside its split, a repeated name, a
malformed manifest line or card, and card counts that differ from the counts
recomputed from the manifest.
"""

import os
from collections import Counter
from collections.abc import Collection
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from lenspair.core.fsutil import sha256_file
from lenspair.dataset.card import CARD_FILE, compare_counts, count_rows, read_card
from lenspair.dataset.config import SPLITS
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import (
    IMAGE_KINDS,
    MANIFEST_FILE,
    REMOVED_FILE,
    ManifestRow,
    read_manifest,
)

_COMPARED_FILES = (MANIFEST_FILE, CARD_FILE, "config.yaml", REMOVED_FILE)


@dataclass(frozen=True)
class VerifyResult:
    """Outcome of :func:`verify_dataset`.

    Attributes:
        root: the dataset folder.
        pairs: rows in the manifest.
        files: image files checked.
        problems: one line per problem; empty when the dataset is intact.
    """

    root: Path
    pairs: int
    files: int
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        """True when no problem was found."""
        return not self.problems


def verify_dataset(root: Path, workers: int | None = None) -> VerifyResult:
    """Re-check every file of a dataset against ``manifest.jsonl`` and ``dataset.json``.

    Args:
        root: dataset folder (``dataset-build --out``).
        workers: threads hashing files (default: up to 4).

    Raises:
        DatasetError: ``root`` is not a folder, or holds neither a manifest nor a card.
    """
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: not a folder")
    if not (root / MANIFEST_FILE).exists() and not (root / CARD_FILE).exists():
        raise DatasetError(f"{root}: not a dataset (no {MANIFEST_FILE} and no {CARD_FILE})")
    try:
        rows = read_manifest(root / MANIFEST_FILE)
    except DatasetError as exc:
        return VerifyResult(root, 0, 0, (str(exc),))
    problems = _check_rows(root, rows)
    expected = {
        root / relative: row.sha256.get(kind, "")
        for row in rows
        for kind, relative in sorted(row.files.items())
    }
    with ThreadPoolExecutor(max_workers=workers or min(4, os.cpu_count() or 1)) as pool:
        problems += [p for p in pool.map(_check_file, expected.items()) if p]
    for path in sorted(_split_files(root) - set(expected)):
        if not _is_users(path.relative_to(root)):  # a folder-reading loader would take it
            problems.append(f"{path}: not listed in {MANIFEST_FILE}")
    problems += _check_card(root, rows)
    return VerifyResult(root, len(rows), len(expected), tuple(problems))


def _check_rows(root: Path, rows: list[ManifestRow]) -> list[str]:
    problems = []
    manifest = root / MANIFEST_FILE
    names = Counter((row.split, row.name) for row in rows)
    for (split, name), count in sorted(names.items()):
        if count > 1:
            problems.append(f"{manifest}: {split}/{name} is listed {count} times")
    for number, row in enumerate(rows, start=1):
        for kind in ("input", "target"):
            if kind not in row.files or kind not in row.sha256:
                problems.append(f"{manifest}:{number}: {row.name} has no {kind} file or sha256")
        for kind, relative in sorted(row.files.items()):
            parts = Path(relative).parts
            if parts[:2] != (row.split, kind) or Path(relative).stem != row.name:
                expected = f"{row.split}/{kind}/{row.name}.*"
                problems.append(f"{manifest}:{number}: {relative} is not at {expected}")
    return problems


def _check_file(item: tuple[Path, str]) -> str | None:
    path, expected = item
    if not path.is_file():
        return f"{path}: missing (listed in {MANIFEST_FILE})"
    actual = sha256_file(path)
    if actual != expected:
        return f"{path}: sha256 mismatch (manifest {expected[:12]}..., file {actual[:12]}...)"
    return None


def _split_files(root: Path) -> set[Path]:
    found: set[Path] = set()
    for split in SPLITS:
        for folder, _, files in os.walk(root / split):
            found.update(Path(folder) / name for name in files)
    return found


def _check_card(root: Path, rows: list[ManifestRow]) -> list[str]:
    try:
        card = read_card(root / CARD_FILE)
    except DatasetError as exc:
        return [str(exc)]
    where = root / CARD_FILE
    problems = [f"{where}: {p}" for p in compare_counts(card.counts, count_rows(rows))]
    tagged = sum(1 for row in rows if row.difficulty == "clean")
    if card.tagged_clean != tagged:
        problems.append(f"{where}: tagged_clean: card says {card.tagged_clean}, manifest {tagged}")
    per_source: Counter[tuple[str, str]] = Counter((row.recording, row.split) for row in rows)
    for source in card.sources:
        for split in SPLITS:
            recorded = source.in_dataset.get(split, 0)
            actual = per_source.get((source.recording, split), 0)
            if recorded != actual:
                problems.append(
                    f"{where}: sources[{source.recording}].in_dataset.{split}: "
                    f"card says {recorded}, manifest gives {actual}"
                )
    return problems


def user_files(root: Path) -> list[Path]:
    """Files in ``root``'s split folders outside their image folders, or hidden: a user's.

    A build writes a split's images into ``input/``, ``target/`` and ``mask/``
    only, so anything else there (an evaluation in ``train/restored/``) is
    the user's, manifest or not; a rebuild keeps it (``dataset-build``). An
    unlisted file in an image folder is not: ``--verify`` names it, a folder-
    reading loader would take it, and a rebuild with ``--overwrite`` drops it.
    Besides files, a symbolic link to a folder (``train/restored ->
    ../../evals/run1``) and an empty folder count, as whole entries.
    Relative to ``root``, sorted.
    """
    found: set[Path] = set()
    for split in SPLITS:
        for folder, folders, files in os.walk(root / split):  # links to folders not entered
            here = Path(folder)
            found.update(here / name for name in files)
            found.update(here / name for name in folders if (here / name).is_symlink())
            if not folders and not files:
                found.add(here)
    relative = (path.relative_to(root) for path in found)
    return sorted(path for path in relative if len(path.parts) > 1 and _is_users(path))


def _is_users(relative: Path) -> bool:
    """``split/...`` outside the split's image folders, or hidden: the user's (:func:`user_files`).

    A hidden entry (``.DS_Store`` that macOS's Finder leaves in every folder it
    shows, an editor's swap file) is read by no loader (lenspair's readers pass
    over it), so in an image folder too it is neither a problem ``--verify``
    names nor a difference that refuses a rebuild.
    """
    return relative.parts[1] not in IMAGE_KINDS or any(
        part.startswith(".") for part in relative.parts[1:]
    )


def dataset_difference(
    existing: Path, new: Path, new_files: Collection[Path] | None = None
) -> str | None:
    """Why the dataset at ``existing`` differs from the one at ``new``; None if the same.

    Compares the file lists and the bytes of the manifest, card and config
    (the manifest holds the sha256 of every image). Files a user added to
    the split folders (:func:`user_files`, outside their image folders) are no difference.

    Args:
        existing: the dataset on disk.
        new: a folder holding at least the new manifest, card, config and
            ``removed.jsonl``.
        new_files: the image files of the new dataset, relative to its root;
            default: those under ``new``'s split folders. Given, the
            comparison needs no image of ``new`` on disk.
    """
    for name in _COMPARED_FILES:
        a, b = existing / name, new / name
        if not a.is_file() or not b.is_file() or a.read_bytes() != b.read_bytes():
            return f"{name} differs"
    old_files = {p.relative_to(existing) for p in _split_files(existing)}
    old_files = {p for p in old_files if not _is_users(p)}
    if new_files is None:
        new_files = {p.relative_to(new) for p in _split_files(new)}
    if old_files != set(new_files):
        example = sorted(old_files ^ set(new_files))[0]
        return f"file lists differ, e.g. {example}"
    return None
