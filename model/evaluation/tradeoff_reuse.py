"""Reusing a tradeoff's run folders: which run a rerun may resume, and which it must clear.

A rerun into the same ``OUT`` reuses (resumes) a variant's run only when
everything that decides what it learns is unchanged: the model, data, loss
and train sections (seed included), the dataset and whether the perceptual
loss runs. A larger budget extends the run; anything else clears the run
folder and trains it again, with one log line naming the first difference
(:func:`reuse_obstacle`). Only a run folder tradeoff started (its
:data:`RUN_MARKER` says so) is tradeoff's to resume or to clear.
"""

import logging
from pathlib import Path

import torch

from lenspair.core.fsutil import atomic_write_text, remove_path
from lenspair.model.checkpoint import checkpoint_config, load_checkpoint
from lenspair.model.errors import ModelError
from lenspair.model.training.config import RunConfig
from lenspair.model.training.config_loading import config_differences
from lenspair.model.training.run_files import RunPaths
from lenspair.model.training.step import (
    describe_precision,
    training_precision,
    vgg19_weights_path,
)

log = logging.getLogger(__name__)


RUN_MARKER = "tradeoff_run.txt"
"""A file tradeoff writes into each run folder it starts (``OUT/runs/<variant>``).

Only such a folder is tradeoff's to resume or to clear: a run of the user's
own at that path (``--out .`` in a project with ``runs/GEA``) is refused,
never deleted (:func:`_owned`)."""

MARKER_TEXT = "lenspair tradeoff trains this run\n"
"""What :data:`RUN_MARKER` holds."""

REUSE_IGNORES: frozenset[str] = frozenset(
    {
        "data.num_workers",
        "train.log_every",
        "train.tensorboard",
        "train.checkpoint_every_steps",
        "train.checkpoint_every_seconds",
    }
)
"""Settings that change how a run loads data, logs and checkpoints, never what it learns."""

BUDGET_FIELDS: tuple[str, ...] = ("epochs", "max_steps", "max_seconds")
"""Train settings a rerun may raise: resuming then extends the run (``fit(resume=True)``)."""


def reuse_obstacle(
    stored: RunConfig,
    wanted: RunConfig,
    dataset: str | None = None,
    precision: str | None = None,
) -> str | None:
    """The first setting that keeps a run trained under ``stored`` from standing for ``wanted``.

    A run is reused when the model, data, loss and train sections match
    (the seed included) but for :data:`REUSE_IGNORES` and the budget: each
    budget limit of ``wanted`` must be at least the stored one (``None`` is
    no limit), since resuming extends a run and cannot shorten it. The
    perceptual loss must be on (or off) in both, and when ``dataset`` (the
    data description, ``runtime.data``) is given, the stored run must have
    trained on the same. When ``precision`` is given, the stored run must have
    trained at it: ``auto`` resolves to bf16 on one CPU and fp32 on another
    (or under ``ONEDNN_MAX_CPU_ISA``), and a resumed run would be labelled
    with the new precision.

    Args:
        stored: the configuration in the run's ``last.pt``.
        wanted: the resolved configuration the rerun asks for.
        dataset: the description of the data the rerun trains on.
        precision: what the rerun trains at (``runtime.precision``'s words).

    Returns:
        ``"train.seed: 0 -> 5"`` and the like, or ``None`` when the run can be reused.

    """
    budget = {f"train.{name}" for name in BUDGET_FIELDS}
    for change in config_differences(stored, wanted):
        key = change.partition(":")[0]
        if key not in REUSE_IGNORES and key not in budget:
            return change
    for name in BUDGET_FIELDS:
        before, after = getattr(stored.train, name), getattr(wanted.train, name)
        if after is not None and (before is None or after < before):
            return f"train.{name}: {before!r} -> {after!r} (the run may have trained past it)"
        if wanted.train.lr_decay > 0 and before != after:
            return (
                f"train.{name}: {before!r} -> {after!r} (the learning rate decays to the "
                "budget's end: a longer run is another schedule, not an extension)"
            )
    runtime = stored.runtime
    if dataset is not None and (runtime is None or runtime.data != dataset):
        return f"dataset: {runtime.data if runtime else 'unknown'!r} -> {dataset!r}"
    if precision is not None and runtime is not None and runtime.precision not in ("", precision):
        return f"precision: {runtime.precision!r} -> {precision!r}"
    if runtime is not None and runtime.perceptual:
        was = runtime.perceptual.startswith("enabled")
        weights = vgg19_weights_path(wanted.train.vgg19_weights)
        now = wanted.loss.perceptual > 0 and weights is not None
        if was != now:
            after = f"enabled ({weights})" if now else "disabled"
            return f"perceptual loss: {runtime.perceptual!r} -> {after!r}"
    return None


def reusable(
    run: Path,
    config: RunConfig,
    device: torch.device,
    dataset: str | None = None,
    earlier_tradeoff: bool = False,
) -> bool:
    """Whether ``run`` holds a run that ``config`` may resume; else clear it.

    Args:
        run: the variant's run folder.
        config: the resolved configuration of the rerun.
        device: where it trains (its precision is resolved for it).
        dataset: the description of its data (checked when given).
        earlier_tradeoff: an earlier tradeoff wrote this output
            (``tradeoff_config.yaml`` was there before this run began).

    Returns:
        True when ``run/checkpoints/last.pt`` may be resumed (:func:`reuse_obstacle`).

    Raises:
        ModelError: ``run`` is not tradeoff's (:func:`_owned`).
    """
    if run.exists() and not _owned(run, earlier_tradeoff):
        raise ModelError(
            f"{run}: exists and holds more than a run tradeoff started (no {RUN_MARKER} "
            "in it), so it is not tradeoff's to resume or replace; move it, or choose "
            "another --out"
        )
    last = run / "checkpoints" / "last.pt"
    if not last.is_file():
        if run.exists():  # killed before its first checkpoint: train it from the start
            log.warning(
                "tradeoff: %s has no checkpoints/last.pt (stopped before its first); "
                "training it from the start",
                run,
            )
            _clear_training(run)
        return False
    checkpoint = load_checkpoint(last)
    stored = checkpoint_config(checkpoint, last)
    precision = describe_precision(training_precision(config.train, device).precision)
    obstacle = reuse_obstacle(stored, config, dataset, precision)
    best_written = int(checkpoint.get("best_epoch", 0)) > 0
    if obstacle is None and best_written and not (run / "checkpoints" / "best.pt").is_file():
        # scored from it, and a resume forgets the lost best and might never validate
        # again; a run killed before its first best takes one when it resumes
        obstacle = "its best.pt is missing"
    if obstacle is None:
        return True
    log.warning("tradeoff: %s cannot be resumed (%s); training it again", run, obstacle)
    _clear_training(run)
    return False


def _training_entries(run: Path) -> tuple[Path, ...]:
    """What training writes into ``run``: its files, checkpoints/, samples/ and tensorboard/."""
    paths = RunPaths(run)
    return (paths.config, paths.last.parent, paths.metrics, paths.log, paths.samples,
            paths.tensorboard)  # fmt: skip


def _clear_training(run: Path) -> None:
    """Remove what training wrote into ``run``; the rest stays (said when there is any).

    The whole folder went: an ``eval`` of the run's checkpoint (its default
    output lies in the run folder) and the user's notes with it.
    """
    for path in _training_entries(run):
        remove_path(path)
    kept = sorted(
        p.name for p in run.iterdir() if p.name != RUN_MARKER and not p.name.startswith(".")
    )
    if kept:
        log.warning("tradeoff: %s: kept %s, not written by its training", run, ", ".join(kept))


def _owned(run: Path, earlier_tradeoff: bool) -> bool:
    """Whether the run folder ``run`` is tradeoff's to resume or clear.

    Its marker says so. A folder without one (tradeoff before the marker, or
    killed before writing it) is adopted, marker written, when an earlier
    tradeoff wrote the output and the folder holds only what training writes;
    a note or any other file of the user's keeps it the user's.
    """
    if (run / RUN_MARKER).is_file():
        return True
    written = {path.name for path in _training_entries(run)}
    theirs = [p.name for p in run.iterdir() if p.name not in written and not p.name.startswith(".")]
    if not earlier_tradeoff or theirs:
        return False
    atomic_write_text(run / RUN_MARKER, MARKER_TEXT)
    return True
