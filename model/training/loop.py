"""The training loop's entry points: :func:`fit`, and the configuration a run trains with.

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
its ``train.batch_size``
(:func:`~lenspair.model.training.start_checks.check_resume_batch`).

The checks before a run starts are :mod:`lenspair.model.training.start_checks`,
what a run restores is :mod:`lenspair.model.training.resume`, the loop over
epochs and steps is :mod:`lenspair.model.training.epochs`, the run folder's
files are :mod:`lenspair.model.training.run_files`, validation is
:mod:`lenspair.model.training.validation`, and the progress a checkpoint
records and the stop conditions are :mod:`lenspair.model.training.run_state`.
"""

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from lenspair.core.config import dump_yaml
from lenspair.core.fsutil import atomic_write_text
from lenspair.core.wording import counted
from lenspair.model.checkpoint import checkpoint_config, load_checkpoint
from lenspair.model.errors import ModelError
from lenspair.model.networks.vgg import VGG19_WEIGHTS_ENV
from lenspair.model.training.config import RunConfig, RuntimeInfo
from lenspair.model.training.config_loading import config_differences
from lenspair.model.training.distributed import (
    Distributed,
    all_true,
    distributed_from_env,
    init_distributed,
)
from lenspair.model.training.epochs import EpochDataset, run_epochs
from lenspair.model.training.resume import remove_partial_run, start_state, with_history
from lenspair.model.training.run_files import (
    RunLock,
    RunPaths,
    busy_message,
    remove_run_leftovers,
    run_logging,
    tensorboard_writer,
)
from lenspair.model.training.run_state import RunState
from lenspair.model.training.start_checks import (
    check_resume_batch,
    check_resume_budget,
    check_resume_perceptual,
    open_run_folder,
    read_init,
)
from lenspair.model.training.step import Trainer

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


def resolve_config(config: RunConfig, channels: int) -> RunConfig:
    """Fix ``model.channels`` from the data when the config leaves it open."""
    if config.model.channels is not None:
        return config
    return dataclasses.replace(config, model=dataclasses.replace(config.model, channels=channels))


def resume_config(
    run: Path, override: RunConfig | None, notes: list[str] | None = None
) -> RunConfig:
    """The configuration to resume ``run`` with.

    The run's ``last.pt`` holds the configuration it was started with; an
    ``override`` (``--config``) may change anything but the network, and
    each change is said as a warning: added to ``notes`` when given (for
    :func:`fit` to say once every check has passed, so that a refused resume
    does not first list changes that never apply), else logged now.

    Raises:
        ModelError: no checkpoint, the override changes the network or
            the batch size of a run stopped mid-epoch (:func:`check_resume_batch`),
            or sets a budget the run is past (:func:`check_resume_budget`).

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
            f"--resume: the network of {run} is {stored.model}; this command asks for "
            f"{override.model}; start a new run (or use --init) to change it"
        )
    check_resume_batch(checkpoint, paths.last, override)
    # fit refuses it too; here, before the changes are said as if they would apply
    check_resume_budget(checkpoint, paths.last, override)
    changes = [f"--resume with a changed config: {c}" for c in config_differences(stored, override)]
    if notes is not None:
        notes.extend(changes)
    elif distributed_from_env().is_main:  # torchrun: said once, by rank 0
        for change in changes:
            log.warning("%s", change)
    return override


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
            resume on other data is said and recorded,
            :func:`~lenspair.model.training.resume.with_history`).
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
            empty datasets, a mid-epoch resume at another batch size, a resume
            past its budget or with the perceptual loss switched on or off
            (:mod:`~lenspair.model.training.start_checks`);
            :class:`~lenspair.model.errors.TrainingDivergedError`.

    """
    if len(train_set) == 0 or len(val_set) == 0:
        raise ModelError("training needs at least one training and one validation pair")
    deterministic_before = torch.are_deterministic_algorithms_enabled()
    info, device = init_distributed(device)
    trainer: Trainer | None = None
    lock = RunLock(Path(run))
    # every refusal from here on runs the finally, so a refused run under torchrun tears
    # its process group down as a finished one does
    try:
        train = config.train
        if train.batch_size % info.world_size:
            raise ModelError(
                f"train.batch_size {train.batch_size} is not divisible by {info.world_size} "
                "processes"
            )
        paths = RunPaths(Path(run))
        _lock_run(lock, paths, info, device, made=False)  # before its files are read
        checkpoint, stale = open_run_folder(
            paths, config, resume=resume, restart=restart, synthetic=synthetic
        )
        # read and checked before the run folder is made: a refused --init leaves nothing behind
        start_from = None if init is None or checkpoint is not None else read_init(init, config)
        if train.deterministic:
            torch.use_deterministic_algorithms(True, warn_only=True)
            torch.backends.cudnn.benchmark = False
        trainer = Trainer(config, device, info)
        if checkpoint is not None:  # known once the trainer has looked for VGG19 weights
            check_resume_perceptual(checkpoint, paths.last, trainer.perceptual_status)
        if info.is_main and stale:  # every check passed (data, config, precision, batch)
            remove_partial_run(paths, stale)
        runtime = _runtime_info(
            trainer,
            device,
            info,
            data_description=data_description,
            synthetic=synthetic,
            init=init,
            data_path=data_path,
        )
        config = dataclasses.replace(config, runtime=runtime)
        if info.is_main:
            paths.root.mkdir(parents=True, exist_ok=True)
        _lock_run(lock, paths, info, device, made=True)  # if not held yet: a folder it made
        if info.is_main:
            remove_run_leftovers(paths)
        with run_logging(paths.log, info.is_main):
            if info.is_main:
                for note in notes:
                    log.warning("%s", note)
            state = start_state(trainer, config, paths, checkpoint, start_from)
            if checkpoint is not None:
                config = with_history(config, checkpoint, paths.last, state.step, warn=info.is_main)
            if info.is_main:
                atomic_write_text(paths.config, dump_yaml(config))
            _log_start(trainer, config, paths, device, info)
            first_step = state.step
            with tensorboard_writer(paths.tensorboard, info.is_main and train.tensorboard) as board:
                reason = run_epochs(trainer, config, train_set, val_set, paths, state, info, board)
            if checkpoint is not None and info.is_main and state.step == first_step:
                # a resume at the budget it had reached: config.yaml says what its
                # checkpoints ran, not a seed or a precision no step ran with (nor
                # what an earlier session stopped before its first checkpoint said)
                ran = checkpoint_config(checkpoint, paths.last)
                atomic_write_text(paths.config, dump_yaml(ran))
                log.warning(
                    "--resume: nothing was trained (%s at step %d): %s left as it was",
                    reason,
                    state.step,
                    paths.config,
                )
            _log_end(trainer, config, state, reason, info)
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
        lock.release()
        torch.use_deterministic_algorithms(deterministic_before)
        if info.active:
            # The trainer's DDP wrappers hold the group: free them first, so that
            # destroying it joins gloo's threads now, while Python still runs (see
            # lenspair.model.training.distributed.init_process_group for what they do at exit).
            trainer = None
            torch.distributed.destroy_process_group()


def _lock_run(
    lock: RunLock, paths: RunPaths, info: Distributed, device: torch.device, *, made: bool
) -> None:
    """Hold the run folder's lock (:class:`~lenspair.model.training.run_files.RunLock`).

    Only the writing rank (0) takes it, once the folder exists: before its
    files are read, or as soon as this run has made it (``made``): a run
    another process wrote into it meanwhile is refused then, too. Every rank
    learns the outcome (:func:`all_true`), so all refuse together and none is
    left waiting in a collective.

    Raises:
        ModelError: another process writes the folder, or wrote a run into it
            since this run's checks (one line naming it).
    """
    problem = None
    if info.is_main and not lock.held and paths.root.is_dir():
        if not lock.take():
            problem = busy_message(paths.root)
        elif made and (
            written := [p for p in (paths.last, paths.best, paths.metrics) if p.exists()]
        ):
            problem = (
                f"{paths.root}: another lenspair train wrote a run into it since this one "
                f"started ({', '.join(p.name for p in written)}); choose another --out"
            )
    if not all_true(problem is None, info, device):
        raise ModelError(problem or busy_message(paths.root))


def _runtime_info(
    trainer: Trainer,
    device: torch.device,
    info: Distributed,
    *,
    data_description: str,
    synthetic: str | None,
    init: Path | None,
    data_path: Path | None,
) -> RuntimeInfo:
    """What really runs, for ``config.yaml``'s runtime section (arguments as in :func:`fit`)."""
    return RuntimeInfo(
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
    )


def _log_start(
    trainer: Trainer, config: RunConfig, paths: RunPaths, device: torch.device, info: Distributed
) -> None:
    """Say what trains: the network, device and precision, and a missing perceptual loss."""
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


def _log_end(
    trainer: Trainer, config: RunConfig, state: RunState, reason: str, info: Distributed
) -> None:
    """Say why and where the run stopped, its best validation, and a missing perceptual loss."""
    best = (
        f"best validation PSNR {state.best_psnr:.2f} dB at epoch {state.best_epoch}"
        if state.best_epoch > 0
        else "not validated"  # "-inf dB at epoch 0" read as a diverged network
    )
    log.info(
        "stopped (%s) after %s, %s, %.0f s; %s; %d steps skipped as non-finite",
        reason,
        counted(state.epoch, "epoch"),
        counted(state.step, "step"),
        state.seconds,
        best,
        trainer.guard.total,
    )
    if info.is_main and trainer.vgg is None and config.loss.perceptual > 0:
        log.warning("reminder: this run trained WITHOUT the perceptual loss")
