"""Where the detector's samples come from, gathered in parallel.

:func:`gather` turns :class:`DetectorSources` into training samples and
named held-out sets: lenspair datasets (train split trained on, val and test
scored), simulated recordings (trained on, or only scored), synthetic
anomalies over clean images, hard cases over the clean views of the training
recordings (:mod:`lenspair.model.detection.hard_cases`) and the simulated
multi-kind set (:mod:`lenspair.model.detection.simset`).

With ``workers > 1`` recordings are read, and synthetic and hard samples
rendered, in a process pool. Synthetic and hard samples are made in chunks of
:data:`CHUNK` with one child seed of ``seed`` per chunk
(``np.random.SeedSequence.spawn``), so the samples depend on the seed, never
on the number of workers.
"""

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import numpy as np

from lenspair.core.bitdepth import widen
from lenspair.core.errors import LenspairError
from lenspair.core.imageio import read_image
from lenspair.dataset.folder_notes import clean_bits
from lenspair.model.detection.data import (
    MIN_CLEAN_SIDE,
    DetectorSample,
    dataset_samples,
    recording_samples,
    synthetic_samples,
    texture_images,
)
from lenspair.model.detection.hard_cases import CleanView, clean_views, hard_samples
from lenspair.model.detection.parallel import process_map
from lenspair.model.detection.simset import (
    kind_set_paths,
    simulate_kind_set,
    split_by_recording,
)
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import DetectorSpec
from lenspair.model.training.synthetic import find_clean_images

log = logging.getLogger(__name__)

CHUNK = 60
"""Synthetic or hard samples per seed (a multiple of the 4 kinds and the 5 hard cases)."""


@dataclass(frozen=True)
class DetectorSources:
    """Where the samples come from.

    Attributes:
        datasets: lenspair dataset roots (train split trained on, val and test scored).
        recordings: simulated recordings trained on (``truth/mask/``).
        test_recordings: simulated recordings only scored.
        synthetic: synthetic samples to render (0: none).
        clean_folder: clean images for synthetic samples; None: the built-in textures.
        simulated_set: folder for :func:`simulate_kind_set` (None: not used);
            its held-out recordings are scored.
        set_per_kind: recordings per kind in the simulated set.
        set_frames: frames per simulated recording.
        max_frames: per camera and recording, frames used.
        hard: hard cases to render over the clean views of the training
            recordings (0: none; needs recordings or a simulated set).
    """

    datasets: tuple[Path, ...] = ()
    recordings: tuple[Path, ...] = ()
    test_recordings: tuple[Path, ...] = ()
    synthetic: int = 0
    clean_folder: Path | None = None
    simulated_set: Path | None = None
    set_per_kind: int = 3
    set_frames: int = 6
    max_frames: int = 12
    hard: int = 0


def _flat(groups: Iterable[list[DetectorSample]]) -> list[DetectorSample]:
    return [sample for group in groups for sample in group]


def _chunks(count: int, seed: int) -> list[tuple[int, int, np.random.SeedSequence]]:
    """``(first, size, seed)`` of each chunk of ``count`` samples."""
    starts = list(range(0, count, CHUNK))
    seeds = np.random.SeedSequence(seed).spawn(len(starts))
    return [(s, min(CHUNK, count - s), q) for s, q in zip(starts, seeds, strict=True)]


def clean_images(folder: Path | None, say: bool = False) -> list[np.ndarray]:
    """Clean images for synthetic samples: up to 200 of ``folder``, or the built-in textures.

    Images under :data:`MIN_CLEAN_SIDE` pixels on a side hold no crop: they are left out
    (with a warning each when ``say``; the chunks of workers read them again quietly).

    Raises:
        ModelError: none of ``folder``'s images is large enough.
    """
    if folder is None:
        return texture_images()
    images = []
    paths = find_clean_images(folder)[:200]
    bits = clean_bits(folder, paths, None if say else [])  # a Mono12 camera's frames, widened
    for path in paths:
        try:
            image = widen(read_image(path), bits)
        except LenspairError as exc:  # this image only, as train and detect skip one
            if say:
                log.warning("%s: left out of the synthetic samples", exc)
            continue
        if min(image.shape[:2]) >= MIN_CLEAN_SIDE:
            images.append(image)
        elif say:
            log.warning(
                "%s: %dx%d pixels, under %d on a side: left out of the synthetic samples",
                path, image.shape[1], image.shape[0], MIN_CLEAN_SIDE,
            )  # fmt: skip
    if not images:
        raise ModelError(f"{folder}: no clean image of at least {MIN_CLEAN_SIDE}x{MIN_CLEAN_SIDE}")
    return images


def _synthetic_chunk(
    chunk: tuple[int, int, np.random.SeedSequence], folder: Path | None, spec: DetectorSpec
) -> list[DetectorSample]:
    first, size, seed = chunk
    rng = np.random.default_rng(seed)
    return synthetic_samples(clean_images(folder), size, spec, rng, first=first)


def _hard_chunk(
    chunk: tuple[int, int, np.random.SeedSequence],
    views: Sequence[CleanView],
    spec: DetectorSpec,
) -> list[DetectorSample]:
    first, size, seed = chunk
    return hard_samples(views, size, spec, np.random.default_rng(seed), first=first)


def _recording(path: Path, spec: DetectorSpec, max_frames: int) -> list[DetectorSample]:
    return recording_samples(path, spec, max_frames)


def _once(paths: Sequence[Path], option: str) -> tuple[Path, ...]:
    """``paths`` without repeats (the same folder however typed), each repeat said."""
    kept: dict[Path, Path] = {}
    for path in paths:
        if Path(path).resolve() in kept:
            log.warning("%s: given twice in %s; used once", path, option)
        else:
            kept[Path(path).resolve()] = Path(path)
    return tuple(kept.values())


def _distinct(sources: DetectorSources) -> DetectorSources:
    """``sources`` with repeated folders used once; a recording both trained on and scored refused.

    A folder given twice was trained on twice; one in ``--recordings`` and
    ``--test-recordings`` was scored on the frames it was trained on.

    The simulated set's recordings count as given: its training ones as
    ``--recordings`` (one given there too is used once), its held-out ones
    as ``--test-recordings``.

    Raises:
        ModelError: a test recording is also a training recording, or the
            clean images of synthetic samples are (or hold, or lie in) one.
    """
    recordings = _once(sources.recordings, "--recordings")
    tests = _once(sources.test_recordings, "--test-recordings")
    set_train: list[Path] = []
    set_test: list[Path] = []
    if sources.simulated_set is not None:
        set_train, set_test = split_by_recording(
            kind_set_paths(sources.simulated_set, sources.set_per_kind)
        )
        rendered = {path.resolve() for path in set_train}
        for path in recordings:
            if path.resolve() in rendered:
                log.warning("%s: in --recordings and --simulated-set; used once", path)
        recordings = tuple(path for path in recordings if path.resolve() not in rendered)
    trained = {path.resolve(): "--recordings" for path in recordings}
    trained |= {path.resolve(): "--simulated-set's training recordings" for path in set_train}
    scored = {path.resolve(): ("--test-recordings", path) for path in tests}
    scored |= {path.resolve(): ("--simulated-set's held-out recordings", path) for path in set_test}
    for resolved, (option, path) in scored.items():
        if resolved in trained:
            raise ModelError(
                f"{option}: {path} is also in {trained[resolved]}: it would be scored on the "
                "frames it was trained on; hold out other recordings"
            )
        clean = sources.clean_folder.resolve() if sources.clean_folder is not None else None
        if clean is not None and (clean == resolved or resolved in clean.parents):
            where = "is" if clean == resolved else "lies in"
        elif clean is not None and clean in resolved.parents:
            where = "holds"
        else:
            continue
        # synthetic frames cut from a scored recording flattered its scores, unsaid
        raise ModelError(
            f"--clean-images {sources.clean_folder}: {where} the {option} {path}: its synthetic "
            "frames would be cut from frames it is scored on; give clean images from elsewhere"
        )
    datasets = _once(sources.datasets, "the datasets")
    return replace(sources, datasets=datasets, recordings=recordings, test_recordings=tests)


def distinct_names(paths: Sequence[Path]) -> list[str]:
    """A readable name per folder, never the same for two folders: its shortest telling suffix.

    Each name is the fewest trailing parts of the folder's absolute path that
    no other folder's path ends with (``siteA/dataset`` and ``siteB/dataset``;
    ``dataset`` alone when no other folder has that name). Named by the last
    part alone, two datasets called ``dataset`` gave one held-out set name,
    and the first one's scores were replaced by the second's without a word.

    Args:
        paths: distinct folders (as given: relative, ``.``, or absolute).

    Returns:
        The names, in the order of ``paths``.
    """
    parts = [Path(path).resolve().parts for path in paths]
    names = []
    for index, mine in enumerate(parts):
        others = [theirs for other, theirs in enumerate(parts) if other != index]
        count = next(
            (k for k in range(1, len(mine)) if all(theirs[-k:] != mine[-k:] for theirs in others)),
            len(mine),
        )
        names.append(Path(*mine[-count:]).as_posix())
    return names


def gather(
    sources: DetectorSources, spec: DetectorSpec, seed: int, workers: int = 1
) -> tuple[list[DetectorSample], dict[str, list[DetectorSample]]]:
    """Training samples and named held-out sets from ``sources``.

    Args:
        sources: what to read and render.
        spec: the detector's architecture (input size).
        seed: seeds the simulated set, the synthetic and the hard samples.
        workers: processes (1: all in this process); the samples do not depend on it.

    Returns:
        ``(train, held_out)``: the training samples, and the held-out sets by
        name, one name each (a dataset's splits as ``dataset <name>, split
        val``, its name from :func:`distinct_names`).

    Raises:
        ModelError: nothing to train on, or hard cases without recordings.
    """
    if sources.hard and not (sources.recordings or sources.simulated_set):
        raise ModelError(
            "train-detector: --hard N is made from the clean views of training recordings: "
            "give --recordings or --simulated-set (a dataset's pairs are cropped, not views)"
        )
    sources = _distinct(sources)
    train: list[DetectorSample] = []
    held_out: dict[str, list[DetectorSample]] = {}
    for root, name in zip(sources.datasets, distinct_names(sources.datasets), strict=True):
        train += dataset_samples(root, "train", spec)
        for split in ("val", "test"):  # no model selection here: both are held out
            try:
                held_out[f"dataset {name}, split {split}"] = dataset_samples(root, split, spec)
            except ModelError as exc:
                log.warning("%s: split %s not scored (%s)", root, split, exc)
    recordings = list(sources.recordings)
    read = partial(_recording, spec=spec, max_frames=sources.max_frames)
    if sources.simulated_set is not None:
        paths = simulate_kind_set(
            sources.simulated_set, sources.set_per_kind, sources.set_frames, seed, workers
        )
        set_train, set_test = split_by_recording(paths)
        recordings += set_train
        names = ", ".join(p.name for p in set_test)
        held_out[f"held-out simulated recordings ({names})"] = _flat(
            process_map(read, set_test, workers)
        )
    train += _flat(process_map(read, recordings, workers))
    if sources.test_recordings:
        held_out["test recordings"] = _flat(
            process_map(read, list(sources.test_recordings), workers)
        )
    if sources.synthetic:
        clean_images(sources.clean_folder, say=True)  # what is left out is said once, here
        synthetic = partial(_synthetic_chunk, folder=sources.clean_folder, spec=spec)
        train += _flat(process_map(synthetic, _chunks(sources.synthetic, seed), workers))
    if sources.hard:
        views = [v for path in recordings for v in clean_views(path, sources.max_frames)]
        hard = partial(_hard_chunk, views=views, spec=spec)
        train += _flat(process_map(hard, _chunks(sources.hard, seed + 1), workers))
    if not train:
        raise ModelError("train-detector: no training data; give DS/recordings or --synthetic N")
    return train, held_out
