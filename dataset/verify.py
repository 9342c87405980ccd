"""Check a built dataset against its manifest and card (``dataset-build --verify``).

Every problem is one line naming the file: a file the manifest lists but that
is missing, a sha256 mismatch, a file under a split folder (or in an image
folder outside the splits, which a reader of the dataset's splits would take
for one) that the manifest does not list, a row whose files lie outside its
split, a repeated name, a malformed manifest line or card, card counts that
differ from the counts recomputed from the manifest, a card whose ``pairs_in``
or per-rule removed counts differ from the manifest and ``removed.jsonl``,
and a missing ``removed.jsonl`` or ``config.yaml``, or one that differs from
the card's configuration (seed included).

These records have been written by every version of ``dataset-build``, under
the one card format ``lenspair-dataset/1``: a rule an older card does not list
is counted as removing no pair, and ``config.yaml`` is compared as loaded (the
defaults of keys added since filled in on both sides), so an intact dataset of
an older version is not flagged.
"""

import os
from collections import Counter
from collections.abc import Collection
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from lenspair.core.config import to_plain
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import sha256_file
from lenspair.dataset.card import CARD_FILE, DatasetCard, compare_counts, count_rows, read_card
from lenspair.dataset.config import SPLITS, load_dataset_config
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import (
    IMAGE_KINDS,
    MANIFEST_FILE,
    REMOVED_FILE,
    ManifestRow,
    read_manifest,
    read_removed,
)

CONFIG_FILE = "config.yaml"
"""The resolved configuration a build writes beside its dataset."""
_COMPARED_FILES = (MANIFEST_FILE, CARD_FILE, CONFIG_FILE, REMOVED_FILE)


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
    outside = f"an image folder outside {', '.join(f'{split}/' for split in SPLITS)}"
    for path in sorted(_stray_image_files(root) - set(expected)):
        problems.append(f"{path}: not listed in {MANIFEST_FILE} ({outside})")
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


def _stray_image_files(root: Path) -> set[Path]:
    """Files in ``input/``, ``target/`` or ``mask/`` folders of ``root`` or of a non-split folder.

    No build writes them, and a reader of the dataset's splits takes such a
    folder for one (``tradeoff`` reads every folder holding ``input/`` +
    ``target/``; ``DS/input/`` makes ``DS`` itself a plain paired folder).
    Hidden entries are passed over, as in the splits (:func:`_is_users`).
    """
    tops = [root]
    tops += [p for p in sorted(root.iterdir()) if p.is_dir() and p.name not in SPLITS]
    found: set[Path] = set()
    for top in tops:
        for kind in IMAGE_KINDS:
            for folder, _, files in os.walk(top / kind):
                found.update(Path(folder) / name for name in files)
    return {p for p in found if not any(part.startswith(".") for part in p.relative_to(root).parts)}


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
    return problems + _check_removed(root, card, len(rows)) + _check_config(root, card)


def _check_removed(root: Path, card: DatasetCard, kept: int) -> list[str]:
    """The card's ``pairs_in`` and per-rule removed counts against ``removed.jsonl``.

    Every line of the sources' ``pairs.jsonl`` is either a manifest row or a
    line of ``removed.jsonl`` (under the one rule that removed it).
    """
    where = root / CARD_FILE
    try:
        removed = read_removed(root / REMOVED_FILE)
    except DatasetError as exc:
        return [str(exc)]
    problems = []
    if kept + len(removed) != card.pairs_in:
        problems.append(
            f"{where}: pairs_in: card says {card.pairs_in}, {MANIFEST_FILE} ({kept} pairs) and "
            f"{REMOVED_FILE} ({len(removed)}) give {kept + len(removed)}"
        )
    recorded = {rule.rule: rule.removed for rule in card.curation}
    actual = Counter(pair.rule for pair in removed)
    for rule in sorted(actual.keys() - recorded.keys()):
        problems.append(
            f"{where}: curation: no rule {rule!r}, which removed {actual[rule]} pair(s) in "
            f"{REMOVED_FILE}"
        )
    for rule, count in recorded.items():
        if count != actual.get(rule, 0):
            problems.append(
                f"{where}: curation.{rule}.removed: card says {count}, {REMOVED_FILE} gives "
                f"{actual.get(rule, 0)}"
            )
    return problems


def _check_config(root: Path, card: DatasetCard) -> list[str]:
    """``config.yaml`` against the card's configuration, and the card's seed and fractions.

    Both are compared as loaded, so keys a later version added (absent from
    an older dataset's files) are their defaults on both sides.
    """
    where, path = root / CARD_FILE, root / CONFIG_FILE
    problems = []
    split = card.config.split
    for key, value, resolved in (
        ("seed", card.seed, split.seed),
        ("fractions", card.fractions, split.fractions),
    ):
        if value != resolved:
            problems.append(f"{where}: {key}: card says {value}, its config.split.{key} {resolved}")
    if not path.is_file():
        problems.append(f"{path}: missing (every build writes its resolved configuration)")
        return problems
    try:
        saved = load_dataset_config(path)
    except ConfigError as exc:  # names the file and the key
        return [*problems, str(exc)]
    for key, mine, theirs in _differences(to_plain(saved), to_plain(card.config)):
        problems.append(f"{path}: {key}: {mine}, but {CARD_FILE}'s config says {theirs}")
    return problems


def _differences(a: object, b: object, path: str = "") -> list[tuple[str, object, object]]:
    """``(dotted key, a's value, b's value)`` where two plain nested dicts differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        found = []
        for key in sorted(set(a) | set(b)):
            found += _differences(a.get(key), b.get(key), f"{path}.{key}" if path else key)
        return found
    return [] if a == b else [(path, a, b)]


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
