"""Checks of a run's training images before its first step, and the data warnings.

A problem with an image (too small for the crop, a format that cannot be
read, too small for validation's SSIM window) would otherwise stop the run
whenever the sampler first drew it, perhaps in epoch 40; the headers are read
up front instead. A dataset of grey and colour images trains a network of
one channel count and converts the others, which must not pass unsaid.

Warnings about the data are logged at once, or kept in ``notes`` for
:func:`~lenspair.model.training.loop.fit` to log (:func:`warn_or_note`):
``lenspair train`` loads before ``RUN/train.log`` exists, and in every
``torchrun`` process.
"""

import logging
from collections.abc import Sequence
from pathlib import Path

from lenspair.core.errors import ImageIOError, listed
from lenspair.core.imageio import format_problem, image_header
from lenspair.core.spread import spread_indices
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.readers import Header, PairedDataset
from lenspair.model.metrics import gaussian_window
from lenspair.model.training.pairs import PairSource, SubsetSource

log = logging.getLogger(__name__)


def warn_or_note(notes: list[str] | None, message: str) -> None:
    """Log a warning about the data now, or keep it in ``notes`` for the run to say."""
    if notes is None:
        log.warning("%s", message)
    else:
        notes.append(message)


Headers = dict[int, dict[int, Header]]
"""``id(dataset)`` -> its good pairs' headers by pair index
(:meth:`~lenspair.dataset.readers.PairedDataset.header_problems`)."""

MOST_BAD_SHARE = 0.5
"""Above this share of bad pairs training is refused, not run on the rest: so many is a
folder given by mistake or a systematic fault (a resize applied to one side), not strays."""


def pairs_behind(source: PairSource) -> tuple[PairSource, Sequence[int]]:
    """The pairs ``source`` picks from (a subset's source, else itself) and which it picks."""
    if isinstance(source, SubsetSource):
        return source.source, source.indices
    return source, range(len(source))


def _dataset_of(source: PairSource, headers: Headers) -> tuple[PairedDataset, Sequence[int]] | None:
    """The paired folder behind ``source`` and the indices of its pairs, if its headers are read."""
    paired, indices = pairs_behind(source)
    if not isinstance(paired, PairedDataset) or id(paired) not in headers:
        return None
    return paired, indices


def check_training_images(
    source: PairSource,
    headers: Headers,
    crop_size: int | None,
    channels: int | None,
    notes: list[str] | None = None,
) -> dict[int, int] | None:
    """Every training pair holds a crop, and mixed channels are said: from headers, up front.

    A smaller image would stop the run whenever the sampler first drew it; a
    dataset of grey and colour pairs trains a network of one channel count
    and converts the others, which must not pass unsaid.

    Args:
        source: the training pairs.
        headers: ``id(dataset)`` -> its pairs' headers, as
            :meth:`~lenspair.dataset.readers.PairedDataset.header_problems`
            returned them (the files are not opened again).
        crop_size: ``data.crop_size`` (``None``: whole images).
        channels: the network's channels (``None``: those of most pairs,
            :func:`majority_channels`).
        notes: collects the mixed-channels warning instead of logging it.

    Returns:
        How many pairs have 1 and 3 channels; None for pairs not read from a
        paired folder (their headers are not known).

    Raises:
        DatasetError: naming the first three images too small and how many there are.
    """
    found = _dataset_of(source, headers)
    if found is None:
        return None
    paired, indices = found
    small, counts = [], {1: 0, 3: 0}
    for index in indices:
        height, width, have = headers[id(paired)][index][:3]
        counts[have] = counts.get(have, 0) + 1
        if crop_size is not None and min(height, width) < crop_size:
            small.append(f"{paired.entries[index].input_path} ({width}x{height})")
    if small:
        raise DatasetError(
            f"{len(small)} training image(s) smaller than the {crop_size} px crop "
            f"(data.crop_size, --crop-size): {listed(small, 3, ', ')}; lower the crop or "
            "leave them out"
        )
    warn_mixed(paired.root, "training pairs", counts, channels, notes)
    return counts


def check_validation_images(
    source: PairSource,
    headers: Headers,
    limit: int | None,
    notes: list[str] | None = None,
) -> None:
    """Validation pairs are large enough for SSIM's window and readable, up front.

    Sizes come from the headers; the pairs validation scores (at most
    ``data.max_val_images``) are also decoded once, so a file cut off after
    its header is found before training, not after the first epoch.

    Validation leaves a pair under the window out (with a warning, at the
    first validation), and refuses when it can score none: found only after
    the first epoch of training, which was lost with no ``last.pt``. The
    same as :func:`check_clean_images` does for held-out clean images.

    Args:
        source: the validation pairs.
        headers: as for :func:`check_training_images`.
        limit: ``data.max_val_images``: only the pairs validation scores
            (:func:`~lenspair.core.spread.spread_indices`, as
            :class:`~lenspair.model.training.pairs.PairedCrops` picks them).
        notes: collects the warning about some pairs instead of logging it.

    Raises:
        DatasetError: every pair validation scores is under the window or
            unreadable (naming the folder and the first three).
    """
    found = _dataset_of(source, headers)
    if found is None:
        return
    paired, indices = found
    scored = [indices[position] for position in spread_indices(len(indices), limit)]
    window = gaussian_window().numel()  # the SSIM window of VAL_CONVENTION
    small, unreadable = [], []
    for index in scored:
        height, width = headers[id(paired)][index][:2]
        if min(height, width) < window:
            small.append(f"{paired.entries[index].input_path} ({width}x{height})")
            continue
        try:  # a pair whose header reads but whose pixels do not (a cut-off file)
            paired[index]
        except (ImageIOError, DatasetError) as exc:
            unreadable.append(str(exc))
    where = paired.root if paired is source else f"the pairs held out of {paired.root}"
    what = f"smaller than validation's {window}x{window} SSIM window"
    if len(small) + len(unreadable) == len(scored):
        if not unreadable:
            raise DatasetError(
                f"{where}: every one of the {len(scored)} validation pair(s) is {what}, so "
                f"none can be scored: {listed(small, 3, ', ')}; give validation pairs of at "
                f"least {window}x{window} px"
            )
        raise DatasetError(
            f"{where}: none of the {len(scored)} validation pair(s) can be scored: "
            f"{listed(unreadable + small, 3, '; ')}"
        )
    if small:
        warn_or_note(
            notes,
            f"{where}: validation leaves out {len(small)} of its {len(scored)} pairs, {what}: "
            f"{listed(small, 3, ', ')}",
        )
    if unreadable:
        warn_or_note(
            notes,
            f"{where}: validation leaves out {len(unreadable)} of its {len(scored)} pairs, "
            f"unreadable: {listed(unreadable, 3, '; ')}",
        )


def majority_channels(counts: dict[int, int]) -> int:
    """The channels a network built for these images takes: those of most of them.

    A tie goes to colour, which holds a grey image exactly (repeated). The
    first image's channels decided before: one grey file sorted first made a
    network of luma for a colour dataset, and the pretraining and fine-tuning
    steps, which sort names differently, then built networks of two kinds.

    Args:
        counts: how many images have 1 and 3 channels.
    """
    return 1 if counts.get(1, 0) > counts.get(3, 0) else 3


def warn_mixed(
    root: Path,
    what: str,
    counts: dict[int, int],
    channels: int | None,
    notes: list[str] | None,
) -> None:
    """Say that grey and colour images are mixed and how they are converted, when they are."""
    if counts.get(1) and counts.get(3):
        if channels:
            takes = f"{channels} channel(s)"
        elif counts[1] == counts[3]:  # "those of most of them" when there is no most
            takes = "colour (3) on a tie, which holds a grey image exactly"
        else:
            takes = f"those of most of them ({majority_channels(counts)})"
        warn_or_note(
            notes,
            f"{root}: the {what} mix {counts[1]} grey and {counts[3]} colour images; the "
            f"network takes {takes}, so the others are converted (colour to Rec. 601 luma, "
            "grey repeated); set model.channels to choose",
        )


def check_clean_images(
    folder: Path,
    train: Sequence[Path],
    val: Sequence[Path],
    crop_size: int | None,
    notes: list[str] | None,
) -> dict[int, int]:
    """Headers of every clean image, and training ones hold a crop: before the first step.

    Held-out images smaller than validation's SSIM window are said here, not
    after the first epoch (validation leaves them out); all of them is an error.

    Returns:
        How many images have 1 and 3 channels.

    Raises:
        DatasetError: naming the first three problems and how many there are.
    """
    problems, training, counts = [], set(train), {1: 0, 3: 0}
    window = gaussian_window().numel()  # the SSIM window of VAL_CONVENTION
    unscored = []
    for path in [*train, *val]:
        try:
            height, width, have, kind = image_header(path)
        except ImageIOError as exc:
            problems.append(str(exc))
            continue
        counts[have] += 1
        if problem := format_problem(kind):
            problems.append(f"{path}: {problem}")
        elif crop_size is not None and path in training and min(height, width) < crop_size:
            problems.append(f"{path}: {width}x{height}, smaller than the {crop_size} px crop")
        elif path not in training and min(height, width) < window:
            unscored.append(f"{path} ({width}x{height})")
    if problems:
        raise DatasetError(f"{folder}: {len(problems)} unusable clean image(s): {listed(problems)}")
    if unscored:
        what = f"held-out clean image(s) smaller than validation's {window}x{window} SSIM window"
        if len(unscored) == len(val):
            raise DatasetError(f"{folder}: every one of the {len(val)} {what}: {listed(unscored)}")
        warn_or_note(
            notes, f"{folder}: validation leaves out {len(unscored)} {what}: {listed(unscored)}"
        )
    return counts


def pair_headers(
    sources: Sequence[PairSource], notes: list[str] | None = None
) -> tuple[list[PairSource], Headers]:
    """The headers of the pairs of each paired dataset behind ``sources``, read once each.

    A pair whose files cannot be opened, or whose input and target differ
    in size, channels or bit depth (a Raindrop pair one pixel apart), is left
    out of the sources, with one warning per dataset naming the first three
    and the count: one bad pair stopped the run before, where ``eval`` skips it.

    Returns:
        ``(sources, headers)``: each source without its bad pairs, in order,
        and ``id(dataset)`` -> its good pairs' headers.

    Raises:
        DatasetError: more than :data:`MOST_BAD_SHARE` of a dataset's pairs are bad.
    """
    headers: Headers = {}
    bad: dict[int, set[int]] = {}
    for source in sources:
        paired, _ = pairs_behind(source)
        if not isinstance(paired, PairedDataset) or id(paired) in headers:
            continue
        headers[id(paired)], problems = paired.header_problems()
        bad[id(paired)] = set(problems)
        if not problems:
            continue
        said = f"{paired.root}: {len(problems)} bad pair(s) of {len(paired)}: " + listed(
            list(problems.values())
        )
        if len(problems) > MOST_BAD_SHARE * len(paired):
            raise DatasetError(f"{said}; more than half, so none are trained on")
        warn_or_note(notes, f"{said}; left out of training and validation")
    return [_without(source, bad) for source in sources], headers


def _without(source: PairSource, bad: dict[int, set[int]]) -> PairSource:
    """``source`` without the pairs of its paired dataset listed in ``bad``."""
    paired, indices = pairs_behind(source)
    left_out = bad.get(id(paired))
    if not left_out:
        return source
    return SubsetSource(paired, [index for index in indices if index not in left_out])
