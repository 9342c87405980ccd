"""The state a run starts from: a resumed run's ``last.pt``, or a new run's seed.

A resumed run restores the trainer, the random generators and its progress
(:class:`~lenspair.model.training.run_state.RunState`) from ``last.pt``,
keeps the ``metrics.csv`` rows and the ``best.pt`` that ``last.pt`` vouches
for, and records in its config what it did before (:func:`with_history`).
A new run seeds the global generator and may load ``--init`` weights; a
restarted one (``--resume`` of a run killed before its first ``last.pt``)
first removes the partial files (:func:`remove_partial_run`).

The checks that come before any of this are
:mod:`lenspair.model.training.start_checks`.
"""

import dataclasses
import logging
import math
from pathlib import Path
from typing import Any

import torch

from lenspair.model.checkpoint import checkpoint_config, load_checkpoint, load_weights
from lenspair.model.errors import ModelError
from lenspair.model.training.config import RunConfig, split_until, until_step
from lenspair.model.training.datasets import recorded_digest
from lenspair.model.training.run_files import RunPaths, read_metrics_rows
from lenspair.model.training.run_state import RunState
from lenspair.model.training.start_checks import check_resume_batch
from lenspair.model.training.step import Trainer, set_rng_state

log = logging.getLogger(__name__)


def remove_partial_run(paths: RunPaths, stale: list[Path]) -> None:
    """Remove what a run killed before its first ``last.pt`` left, to start it over.

    Args:
        paths: the run folder.
        stale: its ``best.pt`` and ``metrics.csv``, as
            :func:`~lenspair.model.training.start_checks.open_run_folder` named them.
    """
    replaced = [p for p in stale if p.exists()]
    log.warning(
        "%s has no last.pt to resume from; starting the run again from step 0%s",
        paths.root,
        f" (replacing its {', '.join(p.name for p in replaced)})" if replaced else "",
    )
    for path in replaced:
        path.unlink()


FORGOTTEN_SUFFIX = ".forgotten"
"""A ``best.pt`` a resume could not use (unreadable, or of a validation ``last.pt`` does not
know) is moved to ``best.pt.forgotten``."""


def start_state(
    trainer: Trainer,
    config: RunConfig,
    paths: RunPaths,
    checkpoint: dict[str, Any] | None,
    init: tuple[Path, dict[str, Any]] | None,
) -> RunState:
    """Restore a resumed run, or load ``--init`` weights into a new one.

    Args:
        trainer: the run's trainer, built from ``config``.
        config: the configuration the run trains with.
        paths: the run folder.
        checkpoint: the loaded ``last.pt`` of a resumed run, else ``None``.
        init: ``--init``'s path and checkpoint, as
            :func:`~lenspair.model.training.start_checks.read_init` returned them.

    Returns:
        The run's progress: restored from ``checkpoint``, or a new one.

    Raises:
        ModelError: ``checkpoint`` holds another network or was written
            mid-epoch at another batch size or seed.
    """
    if checkpoint is not None:
        stored = checkpoint_config(checkpoint, paths.last)
        if stored.model != config.model:
            raise ModelError(
                f"{paths.last}: its network {stored.model} differs from {config.model}"
            )
        check_resume_batch(checkpoint, paths.last, config)
        trainer.load_state_dict(checkpoint)
        set_rng_state(checkpoint.get("rng", {}))
        state = RunState.from_checkpoint(checkpoint)
        state.rows = _resumed_rows(paths.metrics, state)
        problem = _best_problem(paths.best, state) if state.best_epoch else None
        if problem is not None:
            # a best PSNR whose checkpoint is gone would never be written again; a file
            # that cannot be used is moved aside, not left for eval to trip over
            aside = paths.best.with_name(paths.best.name + FORGOTTEN_SUFFIX)
            try:
                paths.best.replace(aside)
                moved = f" (moved to {aside.name})"
            except FileNotFoundError:  # missing, or moved by another torchrun process
                moved = ""
            log.warning(
                "%s %s: its best validation (%.2f dB, epoch %d) is forgotten%s, and the next "
                "validation writes a new one",
                paths.best,
                problem,
                state.best_psnr,
                state.best_epoch,
                moved,
            )
            state.best_psnr, state.best_epoch, state.stale = -math.inf, 0, 0
        log.info("resuming %s at epoch %d, step %d", paths.root, state.epoch + 1, state.step)
        return state
    # A new run starts the global generator from the seed, not from whatever this
    # process drew before: its checkpoints (which store that state) then match
    # those of the same run in a fresh process, and of a killed-and-resumed one.
    torch.manual_seed(config.train.seed)
    if init is not None:
        path, data = init
        load_weights(trainer.model, data, path)
        log.info("initialised the network from %s (weights only)", path)
    return RunState()


def _resumed_rows(path: Path, state: RunState) -> list[dict[str, str]]:
    """The rows of ``metrics.csv`` that ``last.pt`` (``state``) vouches for.

    None past its step, and none of an epoch it has not completed (a
    checkpoint written on an epoch's last step precedes that epoch's
    validation row, which has the same step). A run that has validated but
    whose file is gone or emptied loses those rows: said as a warning.

    Raises:
        ModelError: the file is not a metrics table (one line naming it).
    """
    rows = read_metrics_rows(path)
    try:
        kept = [
            row
            for row in rows
            if int(row["step"]) <= state.step and int(row["epoch"]) <= state.epoch
        ]
    except (KeyError, TypeError, ValueError):
        raise ModelError(
            f"{path}: a row without a whole-number epoch and step; move the file aside to "
            "resume without the run's earlier rows"
        ) from None
    if not kept and state.best_epoch:  # an emptied file too, not only a missing one
        what = "holds none of the run's rows" if path.exists() else "is missing"
        log.warning("%s %s: the rows of the run's first %d steps are lost", path, what, state.step)
    return kept


def _best_problem(path: Path, state: RunState) -> str | None:
    """Why ``best.pt`` is not the best validation that ``last.pt`` (``state``) records, or None.

    A validation writes ``best.pt`` before ``last.pt``, the commit point of a
    resume (:func:`~lenspair.model.training.validation.validate_and_save`): a
    run stopped between the two left a ``best.pt`` of a validation that
    ``last.pt`` and the metrics rows it keeps know nothing of. Kept, it stayed
    the run's best.pt beside another reported best, or a worse one replaced
    it. Both files record the best they were written with, so they are
    compared; writing ``last.pt`` first instead would leave a ``best.pt`` older
    than the best ``last.pt`` records, just as wrong.
    """
    if not path.is_file():
        return "is missing"
    try:
        best = load_checkpoint(path)
    except ModelError as exc:
        return f"cannot be read ({exc})"
    vouched = (
        best.get("best_metric") == state.best_psnr
        and best.get("best_epoch") == state.best_epoch
        and int(best.get("step", 0)) <= state.step
    )
    if not vouched:
        return "holds a validation that last.pt does not record (stopped between the two)"
    return None


def with_history(
    config: RunConfig, checkpoint: dict[str, Any], path: Path, step: int, warn: bool = True
) -> RunConfig:
    """``config`` whose runtime also says what a resumed run did before ``step``.

    The precision and the data it trained on before, when they differ (said
    once as a warning too), and the ``--init`` of its first session. Without
    it, a run resumed at another precision (``--precision``, another
    machine) or on another dataset had its config.yaml say it all ran so, and
    lost where its weights started.
    """
    before = checkpoint_config(checkpoint, path).runtime
    runtime = config.runtime
    assert runtime is not None  # set by fit() before the start
    if before is None:
        return config
    earlier_precisions, earlier_data = before.earlier_precisions, before.earlier_data
    if before.precision and before.precision != runtime.precision:
        earlier_precisions = (*earlier_precisions, until_step(before.precision, step))
        if warn:
            log.warning(
                "resuming at %s; %s trained at %s",
                runtime.precision,
                _steps_since(before.earlier_precisions, step),
                before.precision,
            )
    if before.data_path and runtime.data_path and before.data_path != runtime.data_path:
        earlier_data = (*earlier_data, until_step(before.data_path, step))
        if warn:
            log.warning(
                "resuming on %s; the first %d steps trained on %s (its validation PSNRs and "
                "best.pt were measured there)",
                runtime.data_path,
                step,
                before.data_path,
            )
    elif (
        (then := recorded_digest(before.data))
        and (now := recorded_digest(runtime.data))
        and then != now
    ):
        earlier_data = (*earlier_data, until_step(before.data, step))
        if warn:  # rebuilt in place: same folder, other pairs
            log.warning(
                "resuming on %s, whose pairs changed since the run's first %d steps (then: "
                "%s); its validation PSNRs and best.pt were measured on the pairs of then",
                runtime.data,
                step,
                before.data,
            )
    runtime = dataclasses.replace(
        runtime,
        earlier_precisions=earlier_precisions,
        earlier_data=earlier_data,
        init=runtime.init or before.init,
    )
    return dataclasses.replace(config, runtime=runtime)


def _steps_since(earlier: tuple[str, ...], step: int) -> str:
    """``the first 8 steps``, or ``steps 7 to 8`` after an earlier change of precision.

    The previous session's precision holds since the last change that
    ``earlier`` (``bf16 autocast until step 6``, as :func:`with_history` writes
    it) records: "the first 8 steps trained at fp32" was said of a run whose
    steps 1 to 6 had trained at bf16.
    """
    since = split_until(earlier[-1])[1] if earlier else None
    if since is None or not 0 < since < step:
        return f"the first {step} steps"
    return f"steps {since + 1} to {step}"
