"""The checks before a run starts: the run folder, ``--resume`` and ``--init``.

Each refusal comes before the run folder is touched, so a refused command
leaves the folder as it was (but for its ``.lock``, which
:func:`~lenspair.model.training.loop.fit` holds while it checks and trains):

* a folder another process is writing is refused
  (:class:`~lenspair.model.training.run_files.RunLock`);
* a folder that already holds a run is resumed (``--resume``) or refused;
* a mid-epoch ``last.pt`` is resumed only at its batch size and seed
  (:func:`check_resume_batch`), and only on the same kind of data, real
  pairs or synthetic drops of the same preset (:func:`check_resume_mode`);
* a resume must leave the run within its budgets (:func:`check_resume_budget`),
  and train with the perceptual loss if the run did, and only then
  (:func:`check_resume_perceptual`);
* a run killed before its first ``last.pt`` starts over (``--resume``'s
  restart), unless its metrics say a ``last.pt`` existed and was removed;
* ``--init`` weights must be of the network this run builds, and finite
  (:func:`read_init`).

What a run restores once these have passed is
:mod:`lenspair.model.training.resume`.
"""

import dataclasses
from pathlib import Path
from typing import Any

import torch

from lenspair.core.wording import counted
from lenspair.model.checkpoint import (
    build_network,
    check_finite_weights,
    checkpoint_config,
    first_shape_difference,
    load_checkpoint,
)
from lenspair.model.errors import ModelError
from lenspair.model.networks.vgg import VGG19_WEIGHTS_ENV
from lenspair.model.training.config import RunConfig
from lenspair.model.training.config_loading import field_differences
from lenspair.model.training.run_files import RunPaths, read_metrics_rows


def open_run_folder(
    paths: RunPaths, config: RunConfig, *, resume: bool, restart: bool, synthetic: str | None
) -> tuple[dict[str, Any] | None, list[Path]]:
    """The checkpoint a run resumes from, and the files its restart replaces.

    Args:
        paths: the run folder.
        config: the configuration the run trains with (its budgets).
        resume: continue from ``last.pt`` (``--resume``).
        restart: start the run over when it has no ``last.pt`` (see
            :func:`~lenspair.model.training.loop.fit`).
        synthetic: drops preset when the data is synthetic.

    Returns:
        ``(checkpoint, stale)``: the loaded ``last.pt`` (``None`` for a new
        run), and the ``best.pt`` and ``metrics.csv`` paths a restart replaces
        (empty when it is no restart).

    Raises:
        ModelError: the folder holds a run and ``resume`` is off, or the
            resume or restart is refused (:func:`check_resume_mode`,
            :func:`check_resume_budget`).
    """
    checkpoint = load_checkpoint(paths.last) if resume else None
    if checkpoint is not None:
        check_resume_state(checkpoint, paths.last)
        check_resume_mode(checkpoint, paths.last, synthetic)
        check_resume_budget(checkpoint, paths.last, config)
    stale = [paths.best, paths.metrics] if restart and not paths.last.exists() else []
    if stale:
        _check_restart(paths)
    held = [
        p.name for p in (paths.last, paths.best, paths.metrics) if p.exists() and p not in stale
    ]
    if checkpoint is None and held:  # best.pt without last.pt is still another run's result
        raise ModelError(
            f"{paths.root} already holds a run ({', '.join(held)}); pass --resume to continue "
            "it, or choose another --out"
        )
    return checkpoint, stale


TRAINING_STATE = ("discriminator", "optimizer_g", "optimizer_d")
"""What a checkpoint holds beside the network's weights when a run can go on from it."""


def check_resume_state(checkpoint: dict[str, Any], path: Path) -> None:
    """Refuse to resume from weights alone (a shipped network, an export's checkpoint).

    Raises:
        ModelError: naming what is missing and how such weights are used instead.
    """
    missing = [key for key in TRAINING_STATE if key not in checkpoint]
    if missing:
        raise ModelError(
            f"--resume: {path} holds a network's weights but no training state "
            f"({', '.join(missing)}): start a new run from it with --init {path}"
        )


def check_resume_batch(checkpoint: dict[str, Any], path: Path, config: RunConfig) -> None:
    """Refuse to resume a checkpoint written mid-epoch at another ``train.batch_size``.

    A resumed epoch skips the pairs its checkpoint has seen, counted as
    ``step_in_epoch`` steps of the *current* batch size; at another batch
    size it would repeat or skip pairs. Refusing is simpler than storing the
    offset in pairs: that offset need not be a whole number of new steps, so
    the epoch's step count, its end and its loss means would all need
    reworking, for a change that is just as easy from a checkpoint at the end
    of an epoch (``step_in_epoch`` 0), where any batch size is fine.

    The number of processes may change: rank ``r`` of ``W`` draws the epoch's
    order at positions ``r, r + W, ...``, so ``k`` steps of a global batch
    ``B`` have used exactly its first ``k * B`` positions, whatever ``W``.

    Args:
        checkpoint: the loaded ``last.pt``.
        path: where it was read (named in the error).
        config: the configuration the run is resumed with.

    The seed is refused alike: it orders the epoch's pairs (and draws its
    crops), so the rest of the epoch under another seed would repeat or skip
    pairs too.

    Raises:
        ModelError: the checkpoint is mid-epoch and the batch sizes or seeds differ.

    """
    step_in_epoch = int(checkpoint.get("step_in_epoch", 0))
    before = checkpoint_config(checkpoint, path).train
    if step_in_epoch and config.train.seed != before.seed:
        raise ModelError(
            f"--resume: {path} stopped {step_in_epoch} steps into epoch "
            f"{int(checkpoint.get('epoch', 0)) + 1} with seed {before.seed}, which orders its "
            f"pairs; resuming it with seed {config.train.seed} would repeat or skip pairs of "
            f"that epoch: resume with seed {before.seed} (a checkpoint at an epoch's end "
            "takes any seed)"
        )
    stored = before.batch_size
    wanted = config.train.batch_size
    if step_in_epoch and wanted != stored:
        raise ModelError(
            f"--resume: {path} stopped {step_in_epoch} steps into epoch "
            f"{int(checkpoint.get('epoch', 0)) + 1} at batch size {stored}; resuming it at "
            f"batch size {wanted} would repeat or skip pairs of that epoch: resume at batch "
            f"size {stored} (a checkpoint at an epoch's end takes any batch size)"
        )


def check_resume_mode(checkpoint: dict[str, Any], path: Path, synthetic: str | None) -> None:
    """Refuse to resume a run on synthetic drops with real pairs, the reverse, or other drops.

    Its ``best.pt`` and early stopping compare validation PSNRs, which mean
    nothing across the two (a real pair scores some 10 dB above a synthetic
    one); pretraining followed by fine-tuning is a new run with ``--init``.
    Another drops preset (``--drops``) renders other drops on the held-out
    images, so its validation set is another one too.

    Raises:
        ModelError: naming the run's data and the data given.
    """
    before = checkpoint_config(checkpoint, path).runtime
    if before is None or before.synthetic == synthetic:
        return
    was = f"synthetic {before.synthetic} drops" if before.synthetic else "real pairs"
    now = f"synthetic {synthetic} drops" if synthetic else "real pairs"
    if before.synthetic is not None and synthetic is not None:
        raise ModelError(
            f"--resume: {path} trained on {was} ({before.data}); resuming it on {now} would "
            f"compare validation PSNRs of two validation sets: resume with --drops "
            f"{before.synthetic}, or start a new run with --init {path}"
        )
    raise ModelError(
        f"--resume: {path} trained on {was} ({before.data}); resuming it on {now} would compare "
        f"validation PSNRs across both: start a new run with --init {path}"
    )


def check_resume_budget(checkpoint: dict[str, Any], path: Path, config: RunConfig) -> None:
    """Refuse to resume a run with a budget it has already gone past.

    Nothing would train, yet ``config.yaml`` was rewritten with the smaller
    budget (``max_steps: 2`` beside a ``last.pt`` at step 6) and the run said
    "step budget of 2 reached; 6 steps". A budget the run has just reached
    (the one it stopped at) stays allowed: that is no contradiction. A run
    stopped by its time budget always ends a little past it, so a time
    budget is refused only when the resume changes it.

    Raises:
        ModelError: naming where the run is and the budget it is past.
    """
    train, before = config.train, checkpoint_config(checkpoint, path).train
    step, epoch = int(checkpoint.get("step", 0)), int(checkpoint.get("epoch", 0))
    step_in_epoch = int(checkpoint.get("step_in_epoch", 0))
    past = None
    if train.max_steps is not None and step > train.max_steps:
        past = f"at step {step}, past train.max_steps {train.max_steps} (--max-steps)"
    elif epoch > train.epochs or (epoch == train.epochs and step_in_epoch):
        where = f"{counted(epoch, 'epoch')} done"
        if step_in_epoch:
            where = f"{counted(step_in_epoch, 'step')} into epoch {epoch + 1}"
        past = f"{where}, past train.epochs {train.epochs} (--epochs)"
    elif (
        train.max_seconds is not None
        and train.max_seconds != before.max_seconds
        and "seconds" in checkpoint
        and float(checkpoint["seconds"]) > train.max_seconds
    ):
        past = (
            f"at {float(checkpoint['seconds']):.1f} s of training, past train.max_seconds "
            f"{train.max_seconds:g} (--max-seconds)"
        )
    if past is not None:
        raise ModelError(
            f"--resume: {path} is already {past}: nothing would train; give a larger budget "
            "to go on"
        )


def check_resume_perceptual(checkpoint: dict[str, Any], path: Path, status: str) -> None:
    """Refuse to resume a run with the perceptual loss switched on or off.

    Without its VGG19 weights a resumed run trained on without the term,
    said only by the general warning: ``config.yaml`` then said the whole run
    had, and the epoch's loss means divided the sums of steps that had the
    term by steps that had not. A run trains with it or without it
    throughout; switching is a new run with ``--init``.

    Args:
        checkpoint: the loaded ``last.pt``.
        path: where it was read (named in the error).
        status: the perceptual loss of this session
            (:attr:`~lenspair.model.training.step.Trainer.perceptual_status`).

    Raises:
        ModelError: naming what the run did, what this session would do, and
            how to go on.
    """
    before = checkpoint_config(checkpoint, path).runtime
    if before is None or not before.perceptual:  # written before it was recorded
        return
    was, now = before.perceptual.startswith("enabled"), status.startswith("enabled")
    if was == now:
        return
    if was:
        keep = (
            f"give its VGG19 weights ({VGG19_WEIGHTS_ENV} or train.vgg19_weights, and "
            "loss.perceptual > 0) to resume it with the loss"
        )
    elif "loss.perceptual = 0" in before.perceptual:
        keep = "resume it with loss.perceptual: 0, as it trained"
    else:
        keep = (
            f"resume it without VGG19 weights (unset {VGG19_WEIGHTS_ENV} and "
            "train.vgg19_weights), as it trained"
        )
    raise ModelError(
        f"--resume: {path} trained with the perceptual loss {before.perceptual}, and here it "
        f"is {status}; a run trains with it or without it throughout: {keep}, or start a new "
        f"run with --init {path}"
    )


def _check_restart(paths: RunPaths) -> None:
    """Refuse to start over a run whose ``last.pt`` was removed after it had been saved.

    A run killed before its first ``last.pt`` holds at most one metrics row (the
    first validation writes its row, then ``best.pt``, then ``last.pt``); more rows
    mean a ``last.pt`` existed, and starting over would replace that run's
    ``best.pt`` and ``metrics.csv``.
    """
    try:
        rows = len(read_metrics_rows(paths.metrics))
    except ModelError:  # not a metrics table: nothing a restart would lose
        return
    if rows > 1:
        raise ModelError(
            f"--resume: {paths.last} is missing, yet {paths.metrics} records {rows} "
            "validations, so the run had saved it; starting over would replace that run's "
            "best.pt and metrics.csv: put last.pt back, or move them aside to start over"
        )


def read_init(init: Path, config: RunConfig) -> tuple[Path, dict[str, Any]]:
    """``--init``'s checkpoint, checked to hold the network this run builds.

    Only the restoration network is loaded; the discriminator starts afresh,
    so its width may differ.

    Raises:
        ModelError: unreadable, another network (naming what differs), or
            weights holding NaN or Inf (naming the first such tensor).
    """
    data = load_checkpoint(init)
    source = checkpoint_config(data, init).model
    source = dataclasses.replace(source, discriminator_width=config.model.discriminator_width)
    if source != config.model:
        raise ModelError(
            f"--init {init}: it holds another network than this run builds "
            f"({_model_difference(source, config.model)}); the model sections must match"
        )
    # Checked here, before the run folder is made (load_weights checks too, too late):
    # such weights skip every step and the run ended blaming its validation pairs.
    weights = data.get("model")
    if isinstance(weights, dict):
        with torch.device("meta"):  # names and shapes only: no memory, no draws
            expected = build_network(config.model).state_dict()
        problem = first_shape_difference(expected, weights)
        if problem is not None:
            raise ModelError(f"--init {init}: weights do not fit the network: {problem}")
        check_finite_weights(weights, f"--init {init}")
    return init, data


def _model_difference(held: Any, built: Any) -> str:
    """What differs between two model sections, in words ("channels: 1 (mono) in it, ...")."""

    def shown(field: str, value: Any) -> str:
        if field == "channels" and value in (1, 3):
            return f"{value} ({'mono' if value == 1 else 'RGB'})"
        return repr(value)

    return "; ".join(
        f"{name}: {shown(name, before)} in it, {shown(name, after)} here"
        for name, before, after in field_differences(held, built)
    )
