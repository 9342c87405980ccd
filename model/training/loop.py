"""The training loop: epochs, validation, early stopping, checkpoints, logs.

:func:`fit` trains one run into a run folder and can be resumed exactly::

    RUN/config.yaml              resolved configuration (+ runtime: what really ran)
    RUN/checkpoints/last.pt      after every epoch, at a budget stop, and every
                                 train.checkpoint_every_seconds/_steps within one
    RUN/checkpoints/best.pt      best validation PSNR so far
    RUN/metrics.csv              one row per validation
    RUN/train.log                the log, warnings included
    RUN/samples.png              input | output | target of a few validation images
    RUN/tensorboard/             when TensorBoard is installed

Epochs are passes over the training set in an order drawn from
``(seed, epoch)`` (``DistributedSampler``, also for a single process); the
items themselves are seeded by ``(seed, epoch, index)`` (:mod:`lenspair.model.training.pairs`).
A checkpoint records the step within the epoch, so ``--resume`` skips exactly
the batches already seen and continues with bit-identical updates on the CPU.

Validation runs on rank 0 after every ``train.val_every`` epochs on whole
images at fp32; its PSNR (convention ``skimage-gaussian``) drives
``best.pt`` and early stopping (``train.patience`` validations without
improvement). Budgets (``train.max_steps``, ``train.max_seconds``) stop the
run mid-epoch after a validation and saving ``last.pt``; that validation
counts for ``best.pt`` only in a run that has none yet
(:mod:`lenspair.model.training.validation`). A run resumed mid-epoch keeps
its ``train.batch_size`` (:func:`check_resume_batch`).

The run folder's files are :mod:`lenspair.model.training.run_files`, validation is
:mod:`lenspair.model.training.validation`, and the progress a checkpoint records and the stop
conditions are :mod:`lenspair.model.training.run_state`.
"""

import dataclasses
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import torch
from torch.utils.data import DataLoader
from torch.utils.data.distributed import DistributedSampler

from lenspair.core.config import dump_yaml
from lenspair.core.fsutil import atomic_write_text
from lenspair.core.progress import progress
from lenspair.core.wording import counted
from lenspair.model.checkpoint import (
    check_finite_weights,
    checkpoint_config,
    load_checkpoint,
    load_weights,
)
from lenspair.model.errors import ModelError
from lenspair.model.networks.vgg import VGG19_WEIGHTS_ENV
from lenspair.model.training.config import (
    RunConfig,
    RuntimeInfo,
    TrainConfig,
    config_differences,
    field_differences,
)
from lenspair.model.training.datasets import NAMES_DIGEST
from lenspair.model.training.pairs import Sample
from lenspair.model.training.periodic import CheckpointClock, save_progress
from lenspair.model.training.run_files import (
    RunPaths,
    read_metrics_rows,
    remove_run_leftovers,
    run_logging,
    tensorboard_writer,
)
from lenspair.model.training.run_state import RunState, budget_reason, stop_reason
from lenspair.model.training.step import (
    Distributed,
    Trainer,
    all_true,
    distributed_from_env,
    init_distributed,
    scheduled_lr,
    set_rng_state,
)
from lenspair.model.training.validation import validate_and_save

log = logging.getLogger(__name__)


@dataclass
class TrainSummary:
    """What :func:`fit` did.

    Attributes:
        run: the run folder.
        epochs: completed epochs.
        steps: optimiser steps taken (skipped ones included).
        best_psnr: best validation PSNR, dB (``-inf`` if never validated).
        best_epoch: epoch of ``best.pt`` (0 if none).
        stop_reason: why the loop ended.
        seconds: training wall time over all sessions of the run.
        skipped_steps: steps the NaN/Inf guard skipped.
        perceptual: whether the perceptual loss ran (and why not).

    """

    run: Path
    epochs: int
    steps: int
    best_psnr: float
    best_epoch: int
    stop_reason: str
    seconds: float
    skipped_steps: int
    perceptual: str


class EpochDataset(Protocol):
    """A training set whose random choices depend on the epoch (as in ``training.pairs``)."""

    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> Sample: ...
    def set_epoch(self, epoch: int) -> None:
        """Select the epoch."""


def resolve_config(config: RunConfig, channels: int) -> RunConfig:
    """Fix ``model.channels`` from the data when the config leaves it open."""
    if config.model.channels is not None:
        return config
    return dataclasses.replace(config, model=dataclasses.replace(config.model, channels=channels))


def resume_config(run: Path, override: RunConfig | None) -> RunConfig:
    """The configuration to resume ``run`` with.

    The run's ``last.pt`` holds the configuration it was started with; an
    ``override`` (``--config``) may change anything but the network, and
    each change is logged as a warning.

    Raises:
        ModelError: no checkpoint, the override changes the network, or
            the batch size of a run stopped mid-epoch (:func:`check_resume_batch`).

    """
    paths = RunPaths(run)
    checkpoint = load_checkpoint(paths.last)
    stored = checkpoint_config(checkpoint, paths.last)
    stored = dataclasses.replace(stored, runtime=None)
    if override is None:
        return stored
    override = resolve_config(override, stored.model.channels or 1)
    if override.model != stored.model:
        raise ModelError(
            f"--resume: the network of {run} is {stored.model}; --config asks for "
            f"{override.model}; start a new run (or use --init) to change it"
        )
    check_resume_batch(checkpoint, paths.last, override)
    if distributed_from_env().is_main:  # torchrun: said once, by rank 0
        for change in config_differences(stored, override):
            log.warning("--resume with a changed config: %s", change)
    return override


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


def fit(
    config: RunConfig,
    train_set: EpochDataset,
    val_set: EpochDataset,
    run: Path,
    device: torch.device,
    *,
    data_description: str = "",
    synthetic: str | None = None,
    init: Path | None = None,
    resume: bool = False,
    data_path: Path | None = None,
    restart: bool = False,
    notes: Sequence[str] = (),
) -> TrainSummary:
    """Train into the run folder ``run`` (see the module docstring).

    Args:
        config: resolved configuration (``model.channels`` set).
        train_set: training samples (random crops), with ``set_epoch``.
        val_set: validation samples (whole images).
        run: run folder; created if missing.
        device: training device (resolved by the CLI).
        data_description: what the data is, for ``config.yaml``'s runtime section.
        synthetic: drops preset when the data is synthetic.
        init: initialise the network's weights from this checkpoint.
        resume: continue from ``run/checkpoints/last.pt``.
        data_path: the dataset or clean-image folder (recorded resolved; a
            resume on other data is said and recorded, :func:`_with_history`).
        restart: start ``run`` over (``--resume`` of a run killed before its
            first ``last.pt``): its partial ``best.pt`` and ``metrics.csv`` are
            replaced, once every check before training has passed.
        notes: warnings found before the run (about the data: the ``notes`` of
            :func:`~lenspair.model.training.datasets.paired_training_data`), said
            here, into ``train.log``, by the main process alone.

    Returns:
        A :class:`TrainSummary`.

    Raises:
        ModelError: existing run without ``resume``, incompatible ``init``,
            empty datasets, a mid-epoch resume at another batch size;
            :class:`~lenspair.model.errors.TrainingDivergedError`.

    """
    if len(train_set) == 0 or len(val_set) == 0:
        raise ModelError("training needs at least one training and one validation pair")
    info, device = init_distributed(device)
    train = config.train
    if train.batch_size % info.world_size:
        raise ModelError(
            f"train.batch_size {train.batch_size} is not divisible by {info.world_size} processes"
        )
    paths = RunPaths(Path(run))
    checkpoint = load_checkpoint(paths.last) if resume else None
    if checkpoint is not None:
        check_resume_mode(checkpoint, paths.last, synthetic)
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
    # read and checked before the run folder is made: a refused --init leaves nothing behind
    start_from = None if init is None or checkpoint is not None else _read_init(init, config)
    deterministic_before = torch.are_deterministic_algorithms_enabled()
    trainer: Trainer | None = None
    try:
        if train.deterministic:
            torch.use_deterministic_algorithms(True, warn_only=True)
            torch.backends.cudnn.benchmark = False
        trainer = Trainer(config, device, info)
        if info.is_main and stale:  # every check passed (data, config, precision, batch)
            replaced = [p for p in stale if p.exists()]
            log.warning(
                "%s has no last.pt to resume from; starting the run again from step 0%s",
                paths.root,
                f" (replacing its {', '.join(p.name for p in replaced)})" if replaced else "",
            )
            for path in replaced:
                path.unlink()
        config = dataclasses.replace(
            config,
            runtime=RuntimeInfo(
                perceptual=trainer.perceptual_status,
                precision=trainer.precision,
                precision_reason=trainer.decision.reason,
                native_precisions=trainer.decision.native,
                device=str(device),
                world_size=info.world_size,
                data=data_description,
                synthetic=synthetic,
                init=None if init is None else str(init),
                torch_version=str(torch.__version__),
                data_path="" if data_path is None else str(Path(data_path).resolve()),
            ),
        )
        if info.is_main:
            paths.root.mkdir(parents=True, exist_ok=True)
            remove_run_leftovers(paths)
        with run_logging(paths.log, info.is_main):
            if info.is_main:
                for note in notes:
                    log.warning("%s", note)
            state = _start(trainer, config, paths, checkpoint, start_from)
            if checkpoint is not None:
                config = _with_history(
                    config, checkpoint, paths.last, state.step, warn=info.is_main
                )
            if info.is_main:
                atomic_write_text(paths.config, dump_yaml(config))
            if info.is_main and trainer.vgg is None and config.loss.perceptual > 0:
                log.warning(
                    "PERCEPTUAL LOSS DISABLED: no VGG19 weights (set train.vgg19_weights or "
                    "%s); training with the adversarial, feature-matching and L2 terms only",
                    VGG19_WEIGHTS_ENV,
                )
            log.info(
                "training %s (%s, width %g, %d blocks, %d channels) on %s, %s, perceptual %s",
                config.model.variant,
                paths.root,
                config.model.width,
                config.model.num_blocks,
                trainer.channels,
                device,
                trainer.precision,
                trainer.perceptual_status,
            )
            log.info("%s", trainer.decision.summary())
            with tensorboard_writer(paths.tensorboard, info.is_main and train.tensorboard) as board:
                reason = _loop(trainer, config, train_set, val_set, paths, state, info, board)
            log.info(
                "stopped (%s) after %s, %s, %.0f s; best validation PSNR %.2f dB "
                "at epoch %d; %d steps skipped as non-finite",
                reason,
                counted(state.epoch, "epoch"),
                counted(state.step, "step"),
                state.seconds,
                state.best_psnr,
                state.best_epoch,
                trainer.guard.total,
            )
            if info.is_main and trainer.vgg is None and config.loss.perceptual > 0:
                log.warning("reminder: this run trained WITHOUT the perceptual loss")
        summary = TrainSummary(
            run=paths.root,
            epochs=state.epoch,
            steps=state.step,
            best_psnr=state.best_psnr,
            best_epoch=state.best_epoch,
            stop_reason=reason,
            seconds=state.seconds,
            skipped_steps=trainer.guard.total,
            perceptual=trainer.perceptual_status,
        )
        if info.active:
            # every rank done with its collectives before any tears the group down
            torch.distributed.barrier()
        return summary
    finally:
        torch.use_deterministic_algorithms(deterministic_before)
        if info.active:
            # The trainer's DDP wrappers hold the group: free them first, so that
            # destroying it joins gloo's threads now, while Python still runs (see
            # lenspair.model.training.step.init_process_group for what they do at exit).
            trainer = None
            torch.distributed.destroy_process_group()


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


def check_resume_mode(checkpoint: dict[str, Any], path: Path, synthetic: str | None) -> None:
    """Refuse to resume a run on synthetic drops with real pairs, or the reverse.

    Its ``best.pt`` and early stopping compare validation PSNRs, which mean
    nothing across the two (a real pair scores some 10 dB above a synthetic
    one); pretraining followed by fine-tuning is a new run with ``--init``.

    Raises:
        ModelError: naming the run's data and the data given.
    """
    before = checkpoint_config(checkpoint, path).runtime
    if before is None or (before.synthetic is None) == (synthetic is None):
        return
    was = f"synthetic {before.synthetic} drops" if before.synthetic else "real pairs"
    now = f"synthetic {synthetic} drops" if synthetic else "real pairs"
    raise ModelError(
        f"--resume: {path} trained on {was} ({before.data}); resuming it on {now} would compare "
        f"validation PSNRs across both: start a new run with --init {path}"
    )


def _with_history(
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
        earlier_precisions = (*earlier_precisions, f"{before.precision} until step {step}")
        if warn:
            log.warning(
                "resuming at %s; the first %d steps trained at %s",
                runtime.precision,
                step,
                before.precision,
            )
    if before.data_path and runtime.data_path and before.data_path != runtime.data_path:
        earlier_data = (*earlier_data, f"{before.data_path} until step {step}")
        if warn:
            log.warning(
                "resuming on %s; the first %d steps trained on %s (its validation PSNRs and "
                "best.pt were measured there)",
                runtime.data_path,
                step,
                before.data_path,
            )
    elif (then := _digest(before.data)) and (now := _digest(runtime.data)) and then != now:
        earlier_data = (*earlier_data, f"{before.data} until step {step}")
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


def _digest(data: str) -> str | None:
    """The pair-name digest in a run's data line, if it has one.

    (:func:`lenspair.model.training.datasets.names_digest` writes it.)

    Only it tells whether the pairs changed: the line also holds counts that
    other settings change (``data.max_val_images``).
    """
    _, found, rest = data.partition(NAMES_DIGEST + " ")
    return rest.split(")")[0].split(";")[0].strip() if found else None


def _resumed_rows(path: Path, state: RunState) -> list[dict[str, str]]:
    """The rows of ``metrics.csv`` that ``last.pt`` (``state``) vouches for.

    None past its step, and none of an epoch it has not completed (a
    checkpoint written on an epoch's last step precedes that epoch's
    validation row, which has the same step). A run that has validated but
    whose file is gone loses those rows: said as a warning.

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
    if not path.exists() and state.best_epoch:
        log.warning(
            "%s is missing: the rows of the run's first %d steps are lost", path, state.step
        )
    return kept


def _start(
    trainer: Trainer,
    config: RunConfig,
    paths: RunPaths,
    checkpoint: dict[str, Any] | None,
    init: tuple[Path, dict[str, Any]] | None,
) -> RunState:
    """Restore a resumed run, or load ``--init`` weights (:func:`_read_init`) into a new one."""
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
            # a best PSNR whose checkpoint is gone would never be written again
            log.warning(
                "%s %s: its best validation (%.2f dB, epoch %d) is forgotten, and the next "
                "validation writes a new one",
                paths.best,
                problem,
                state.best_psnr,
                state.best_epoch,
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


def _read_init(init: Path, config: RunConfig) -> tuple[Path, dict[str, Any]]:
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


def _loop(
    trainer: Trainer,
    config: RunConfig,
    train_set: EpochDataset,
    val_set: EpochDataset,
    paths: RunPaths,
    state: RunState,
    info: Distributed,
    board: Any,
) -> str:
    """Epochs until done, early-stopped, out of budget; returns the reason."""
    train = config.train
    per_rank = train.batch_size // info.world_size
    sampler: DistributedSampler[int] = DistributedSampler(
        train_set,  # type: ignore[arg-type]
        num_replicas=info.world_size,
        rank=info.rank,
        shuffle=True,
        seed=train.seed,
    )
    steps_per_epoch = math.ceil(len(sampler) / per_rank)
    # the run's length in steps: whichever budget ends it first (a time budget aside)
    total_steps = min(train.max_steps or math.inf, train.epochs * steps_per_epoch)
    total_steps = int(total_steps)
    if train.lr_decay > 0 and info.is_main:
        log.info(
            "learning rate %g, falling linearly over the last %d of %d steps",
            train.lr,
            round(train.lr_decay * total_steps),
            total_steps,
        )
    started = time.monotonic()
    session_start = state.seconds

    def elapsed() -> float:
        return session_start + time.monotonic() - started

    reason = stop_reason(config, state, elapsed())
    clock = CheckpointClock.start(train, state)
    while reason is None:
        epoch = state.epoch
        train_set.set_epoch(epoch)
        sampler.set_epoch(epoch)
        order = list(sampler)[state.step_in_epoch * per_rank :]
        loader: DataLoader[Sample] = DataLoader(
            train_set,  # type: ignore[arg-type]
            batch_size=per_rank,
            sampler=order,
            num_workers=config.data.num_workers,
            pin_memory=trainer.device.type == "cuda",
            # Its own generator: each DataLoader draws a base seed, which must not
            # advance the global RNG (a resumed run makes one DataLoader more).
            generator=torch.Generator().manual_seed(train.seed * 100_003 + epoch),
        )
        # A resumed epoch goes on from the sums its checkpoint recorded.
        sums, counted = dict(state.loss_sums), state.loss_steps
        bar = progress(loader, _epoch_label(epoch, train), total=len(loader), unit="step")
        for batch in bar if info.is_main else loader:
            # every step, also at a constant rate: a resumed run's optimiser state
            # carries the rate it was saved with, and the config may have changed it
            trainer.set_lr(scheduled_lr(train, state.step, total_steps))
            result = trainer.train_step(batch)
            state.step += 1
            state.step_in_epoch += 1
            if not result.skipped:
                counted += 1
                for name, value in result.losses.items():
                    sums[name] = sums.get(name, 0.0) + value
                if board is not None and state.step % train.log_every == 0:
                    for name, value in result.losses.items():
                        board.add_scalar(f"train/{name}", value, state.step)
                    lr = trainer.opt_g.param_groups[0]["lr"]
                    board.add_scalar("train/lr", lr, state.step)
            state.seconds = elapsed()
            reason = budget_reason(config, state)
            if reason is None and clock.due(state):  # a kill now loses little
                state.loss_sums, state.loss_steps = dict(sums), counted
                save_progress(trainer, config, paths, state, info)
                clock.reset(state)
            if not all_true(reason is None, info, trainer.device):
                reason = reason or "time budget reached on another process"
                break
        state.loss_sums, state.loss_steps = dict(sums), counted  # for a budget-stop checkpoint
        if state.step_in_epoch >= steps_per_epoch:
            state.epoch += 1
            state.step_in_epoch = 0
            state.loss_sums, state.loss_steps = {}, 0
        means = {name: total / max(counted, 1) for name, total in sums.items()}
        finished = state.epoch >= train.epochs
        if (
            reason is not None
            or finished
            or (state.epoch % train.val_every == 0 and state.step_in_epoch == 0)
        ):
            validate_and_save(trainer, config, val_set, paths, state, info, means, board)
            clock.reset(state)
        elif state.step_in_epoch == 0:  # an epoch between validations: a kill loses none of it
            save_progress(trainer, config, paths, state, info)
            clock.reset(state)
        state.seconds = elapsed()
        reason = reason or stop_reason(config, state, state.seconds)
        if not all_true(reason is None, info, trainer.device):  # stop together
            reason = reason or "stopped with the other processes"
    return reason


def _epoch_label(epoch: int, train: TrainConfig) -> str:
    """Progress label: ``epoch 3/200``, or ``epoch 3 (budget 400 steps)`` when a budget binds."""
    budgets = [f"{train.max_steps} steps"] if train.max_steps else []
    budgets += [f"{train.max_seconds:g} s"] if train.max_seconds else []
    if budgets:
        return f"epoch {epoch + 1} (budget {' or '.join(budgets)})"
    return f"epoch {epoch + 1}/{train.epochs}"
