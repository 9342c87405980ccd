"""The pairs a tradeoff scores, the checkpoint they score, and whether it trained on them.

:func:`eval_pairs` chooses the pairs as
:func:`lenspair.model.evaluation.tradeoff.run_tradeoff`'s ``split`` says;
:func:`note_trained_on` counts how many of them the networks trained on, by
``lenspair eval``'s rule (:func:`lenspair.model.evaluation.evaluate.trained_on_scored`),
and warns (:func:`lenspair.model.evaluation.tradeoff_report.trained_on_line`
says it under the table): a split trained on (``--split train``) flatters
every row, and the int8 row, calibrated on the training pairs, was then
calibrated on the scored pairs too.
"""

import logging
from pathlib import Path
from typing import Any, NamedTuple

from lenspair.core.errors import LenspairError
from lenspair.dataset.layouts import detect_layout, split_folders
from lenspair.model.checkpoint import LoadedModel
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.evaluate import trained_on_scored
from lenspair.model.evaluation.scoring import scorable_pairs
from lenspair.model.training.config import DataConfig
from lenspair.model.training.datasets import TrainData
from lenspair.model.training.pairs import PairSource, SubsetSource, Unread, open_eval_pairs

log = logging.getLogger(__name__)


class EvalPairs(NamedTuple):
    """The pairs a tradeoff scores, what they are, and which checkpoint they score.

    Attributes:
        pairs: the readable pairs.
        text: what they are, for the table (``DS split test``).
        checkpoint: ``best.pt`` or ``last.pt``.
        unread: pairs that cannot be read or scored, by the split's own index
            (scoring adds to it).
        view: when some cannot, the split's own index of each readable pair.
        split: the dataset split opened whole; None for held-out validation pairs.
    """

    pairs: Any
    text: str
    checkpoint: str
    unread: list[Unread]
    view: list[int]
    split: PairSource | None


def eval_pairs(
    dataset: Path, split: str | None, config: DataConfig, data: TrainData, convention: str
) -> EvalPairs:
    """The pairs to score (see :func:`run_tradeoff`'s ``split``), the readable ones only.

    Args:
        dataset: the paired data, as given.
        split: the evaluation split asked for, or None.
        config: the data section training used (its train and validation splits).
        data: the training data opened from ``dataset``.
        convention: metric convention the pairs are scored under.

    Raises:
        ModelError: no pairs to score (naming the splits that hold some), or
            none of them can be read and scored.

    """
    pairs: Any = None
    opened: PairSource | None = None
    # the checkpoint the validation pairs chose, scored on other pairs; scored on
    # those same pairs it would be a best of noisy validations: the budget's end then
    checkpoint = "best.pt"
    wanted = split or "test"
    if detect_layout(Path(dataset)) is None:  # a dataset with splits: score on ``split``
        # asked for, or there: its problems are the answer (an unpaired file, a bad pair),
        # never a quiet switch to other pairs; only a dataset without a test folder falls back
        if split is not None or (Path(dataset) / wanted).is_dir():
            pairs = opened = open_eval_pairs(dataset, wanted)
            pairs_text = f"{dataset} split {wanted}"
            if wanted == config.val_split:  # the pairs that chose best.pt: its end instead
                checkpoint = "last.pt"
        if split is None and pairs is not None and len(pairs) == 0:
            pairs = opened = None  # an empty test split (dataset-build left it empty): as if none
    if pairs is None:
        # One paired folder (input/ + target/, Raindrop's train/) trains on nine
        # tenths of itself: score on the held-out tenth, never on training pairs.
        pairs = getattr(data.val, "source", None)
        if pairs is None:
            raise ModelError(f"{dataset}: no test split and no held-out pairs to score")
        pairs_text = f"{dataset} held-out validation pairs ({len(pairs)}, not trained on)"
        checkpoint = "last.pt"
    if len(pairs) == 0 and opened is None:
        raise ModelError(f"{pairs_text}: no pairs to score")
    if len(pairs) == 0:
        counts = _pair_counts(Path(dataset), wanted)
        listed = ", ".join(
            f"{name} ({count}{', trained on' if name == config.train_split else ''})"
            for name, count in counts.items()
        )
        default = "the test split" if counts.get("test") else "the held-out validation pairs"
        raise ModelError(
            f"{pairs_text}: no pairs to score; "
            + (f"splits with pairs: {listed}" if counts else "no other split holds pairs")
            + f"; leave --split out to score {default}, or rebuild the dataset with a "
            f"non-empty {wanted} split (dataset-build --splits)"
        )
    readable, unread = scorable_pairs(pairs, data.channels, convention)
    if len(readable) == 0:
        raise ModelError(
            f"{pairs_text}: none can be read and scored; the first: {unread[0].reason}"
        )
    # scoring indexes the readable pairs; problems are reported by the split's own index
    view = readable.indices if isinstance(readable, SubsetSource) and unread else []
    return EvalPairs(readable, pairs_text, checkpoint, unread, view, opened)


def _pair_counts(dataset: Path, empty: str) -> dict[str, int]:
    """Pairs in each split of ``dataset`` but ``empty`` that holds some, by split name."""
    counts: dict[str, int] = {}
    for name in split_folders(dataset) if dataset.is_dir() else []:
        if name == empty:
            continue
        try:
            count = len(open_eval_pairs(dataset, name))
        except LenspairError:  # a broken split is not one to advise
            continue
        if count:
            counts[name] = count
    return counts


def note_trained_on(meta: dict[str, Any], loaded: LoadedModel, chosen: EvalPairs) -> None:
    """Record in ``meta`` how many scored pairs ``loaded`` trained on; warn when any.

    ``lenspair eval``'s rule (:func:`trained_on_scored`) on the split opened
    whole, less the pairs that could not be read or scored; held-out
    validation pairs never are. Sets ``trained_on_scored_pairs`` and, when
    it is not 0, ``scored_pairs``.
    """
    trained = 0
    if chosen.split is not None:
        unread = {problem.index for problem in chosen.unread}
        trained = trained_on_scored(loaded, chosen.split, unread) or 0
    meta["trained_on_scored_pairs"] = trained
    if not trained or chosen.split is None:
        return
    meta["scored_pairs"] = scored = len(chosen.split) - len(chosen.unread)
    log.warning(
        "tradeoff: the networks trained on %d of the %d scored pairs of %s, which flatter their "
        "scores, and an int8 row calibrates on the training pairs, so on them too; score pairs "
        "they did not train on (leave --split out: the test split, or the held-out validation "
        "pairs)",
        trained,
        scored,
        chosen.text,
    )
