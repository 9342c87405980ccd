"""The training loop: epochs, validation, early stopping, checkpoints, logs.

:func:`fit` trains one run into a run folder and can be resumed exactly::

    RUN/config.yaml              resolved configuration (+ runtime: what really ran)
    RUN/checkpoints/last.pt      after every epoch (and at a budget stop)
    RUN/checkpoints/best.pt      best validation PSNR so far
    RUN/metrics.csv              one row per epoch
    RUN/train.log                the log, warnings included
    RUN/samples.png              input | output | target of a few validation images
    RUN/tensorboard/             when TensorBoard is installed

Epochs are passes over the training set in an order drawn from
``(seed, epoch)`` (``DistributedSampler``, also for a single process); the
items themselves are seeded by ``(seed, epoch, index)`` (:mod:`model.data`).
A checkpoint records the step within the epoch, so ``--resume`` skips exactly
the batches already seen and continues with bit-identical updates on the CPU.

Validation runs on rank 0 after every ``train.val_every`` epochs on whole
images at fp32; its PSNR (convention ``skimage-gaussian``) drives
``best.pt`` and early stopping (``train.patience`` validations without
improvement). Budgets (``train.max_steps``, ``train.max_seconds``) stop the
run mid-epoch after saving ``last.pt``.
"""

import contextlib
import csv
import dataclasses
import io
import logging
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader
from torch.utils.data.distributed import DistributedSampler

from lenspair.config import dump_yaml
from lenspair.fsutil import atomic_write_text
from lenspair.imageio import write_image
from lenspair.progress import progress
from model.checkpoint import (
    checkpoint_config,
    load_checkpoint,
    load_weights,
    save_checkpoint,
)
from model.config import RunConfig, RuntimeInfo, config_differences
from model.data import Sample
from model.errors import ModelError
from model.trainer import (
    Distributed,
    Trainer,
    all_true,
    init_distributed,
    rng_state,
    set_rng_state,
)
from model.vgg import VGG19_WEIGHTS_ENV

log = logging.getLogger(__name__)

METRICS_COLUMNS = (
    "epoch",
    "step",
    "seconds",
    "loss_g",
    "loss_d",
    "adversarial",
    "feature_matching",
    "perceptual",
    "fidelity",
    "skipped_steps",
    "val_psnr",
    "val_ssim",
    "best_psnr",
)
"""Columns of ``RUN/metrics.csv`` (one row per epoch, or per budget stop)."""

VAL_CONVENTION = "skimage-gaussian"
"""Metric convention of the validation PSNR/SSIM that drives early stopping."""


@dataclass(frozen=True)
class RunPaths:
    """The files of a run folder."""

    root: Path

    @property
    def config(self) -> Path:
        """``RUN/config.yaml``: the resolved configuration."""
        return self.root / "config.yaml"

    @property
    def last(self) -> Path:
        """``RUN/checkpoints/last.pt``."""
        return self.root / "checkpoints" / "last.pt"

    @property
    def best(self) -> Path:
        """``RUN/checkpoints/best.pt``."""
        return self.root / "checkpoints" / "best.pt"

    @property
    def metrics(self) -> Path:
        """``RUN/metrics.csv``."""
        return self.root / "metrics.csv"

    @property
    def log(self) -> Path:
        """``RUN/train.log``."""
        return self.root / "train.log"

    @property
    def samples(self) -> Path:
        """``RUN/samples.png``: input | output | target of a few validation images."""
        return self.root / "samples.png"

    @property
    def tensorboard(self) -> Path:
        """``RUN/tensorboard/`` (only when TensorBoard is installed)."""
        return self.root / "tensorboard"


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
    """A training set whose random choices depend on the epoch (:mod:`model.data`)."""

    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> Sample: ...
    def set_epoch(self, epoch: int) -> None:
        """Select the epoch."""


@dataclass
class _State:
    epoch: int = 0  # completed epochs
    step: int = 0
    step_in_epoch: int = 0
    best_psnr: float = -math.inf
    best_epoch: int = 0
    stale: int = 0  # validations without improvement
    seconds: float = 0.0
    rows: list[dict[str, str]] = field(default_factory=list)

    def payload(self) -> dict[str, Any]:
        return {
            "epoch": self.epoch,
            "step": self.step,
            "step_in_epoch": self.step_in_epoch,
            "best_metric": self.best_psnr,
            "best_epoch": self.best_epoch,
            "stale_validations": self.stale,
            "seconds": self.seconds,
        }

    @classmethod
    def from_checkpoint(cls, data: dict[str, Any]) -> "_State":
        return cls(
            epoch=int(data["epoch"]),
            step=int(data["step"]),
            step_in_epoch=int(data["step_in_epoch"]),
            best_psnr=float(data["best_metric"]),
            best_epoch=int(data["best_epoch"]),
            stale=int(data["stale_validations"]),
            seconds=float(data.get("seconds", 0.0)),
        )


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
        ModelError: no checkpoint, or the override changes the network.

    """
    paths = RunPaths(run)
    stored = checkpoint_config(load_checkpoint(paths.last), paths.last)
    stored = dataclasses.replace(stored, runtime=None)
    if override is None:
        return stored
    override = resolve_config(override, stored.model.channels or 1)
    if override.model != stored.model:
        raise ModelError(
            f"--resume: the network of {run} is {stored.model}; --config asks for "
            f"{override.model}; start a new run (or use --init) to change it"
        )
    for change in config_differences(stored, override):
        log.warning("--resume with a changed config: %s", change)
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

    Returns:
        A :class:`TrainSummary`.

    Raises:
        ModelError: existing run without ``resume``, incompatible ``init``,
            empty datasets; :class:`~model.trainer.TrainingDivergedError`.

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
    if checkpoint is None and paths.last.exists():
        raise ModelError(
            f"{paths.root} already holds a run; pass --resume to continue it, "
            "or choose another --out"
        )
    deterministic_before = torch.are_deterministic_algorithms_enabled()
    try:
        if train.deterministic:
            torch.use_deterministic_algorithms(True, warn_only=True)
            torch.backends.cudnn.benchmark = False
        trainer = Trainer(config, device, info)
        config = dataclasses.replace(
            config,
            runtime=RuntimeInfo(
                perceptual=trainer.perceptual_status,
                precision=trainer.precision,
                device=str(device),
                world_size=info.world_size,
                data=data_description,
                synthetic=synthetic,
                init=None if init is None else str(init),
                torch_version=str(torch.__version__),
            ),
        )
        if info.is_main:
            paths.root.mkdir(parents=True, exist_ok=True)
        with _run_logging(paths.log, info.is_main):
            state = _start(trainer, config, paths, checkpoint, init)
            if info.is_main:
                atomic_write_text(paths.config, dump_yaml(config))
            if trainer.vgg is None and config.loss.perceptual > 0:
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
            with _tensorboard(paths.tensorboard, info.is_main and train.tensorboard) as board:
                reason = _loop(trainer, config, train_set, val_set, paths, state, info, board)
            log.info(
                "stopped (%s) after %d epochs, %d steps, %.0f s; best validation PSNR %.2f dB "
                "at epoch %d; %d steps skipped as non-finite",
                reason,
                state.epoch,
                state.step,
                state.seconds,
                state.best_psnr,
                state.best_epoch,
                trainer.guard.total,
            )
            if trainer.vgg is None and config.loss.perceptual > 0:
                log.warning("reminder: this run trained WITHOUT the perceptual loss")
        return TrainSummary(
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
    finally:
        torch.use_deterministic_algorithms(deterministic_before)
        if info.active:
            torch.distributed.destroy_process_group()


def _start(
    trainer: Trainer,
    config: RunConfig,
    paths: RunPaths,
    checkpoint: dict[str, Any] | None,
    init: Path | None,
) -> _State:
    """Restore a resumed run, or load ``--init`` weights into a new one."""
    if checkpoint is not None:
        stored = checkpoint_config(checkpoint, paths.last)
        if stored.model != config.model:
            raise ModelError(
                f"{paths.last}: its network {stored.model} differs from {config.model}"
            )
        trainer.load_state_dict(checkpoint)
        set_rng_state(checkpoint.get("rng", {}))
        state = _State.from_checkpoint(checkpoint)
        state.rows = [row for row in _read_rows(paths.metrics) if int(row["step"]) <= state.step]
        log.info("resuming %s at epoch %d, step %d", paths.root, state.epoch + 1, state.step)
        return state
    if init is not None:
        data = load_checkpoint(init)
        source = checkpoint_config(data, init).model
        # Only the restoration network is loaded; the discriminator starts afresh.
        source = dataclasses.replace(source, discriminator_width=config.model.discriminator_width)
        if source != config.model:
            raise ModelError(
                f"--init {init}: it holds a {source} network, this run builds {config.model}; "
                "the model sections must match"
            )
        load_weights(trainer.model, data, init)
        log.info("initialised the network from %s (weights only)", init)
    return _State()


def _loop(
    trainer: Trainer,
    config: RunConfig,
    train_set: EpochDataset,
    val_set: EpochDataset,
    paths: RunPaths,
    state: _State,
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
    started = time.monotonic()
    session_start = state.seconds

    def elapsed() -> float:
        return session_start + time.monotonic() - started

    reason = _stop_reason(config, state, elapsed())
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
        )
        sums: dict[str, float] = {}
        counted = 0
        bar = progress(loader, f"epoch {epoch + 1}/{train.epochs}", total=len(loader), unit="step")
        for batch in bar if info.is_main else loader:
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
            state.seconds = elapsed()
            reason = _budget_reason(config, state)
            if not all_true(reason is None, info, trainer.device):
                reason = reason or "time budget reached on another process"
                break
        if state.step_in_epoch >= steps_per_epoch:
            state.epoch += 1
            state.step_in_epoch = 0
        means = {name: total / max(counted, 1) for name, total in sums.items()}
        finished = state.epoch >= train.epochs
        if (
            reason is not None
            or finished
            or (state.epoch % train.val_every == 0 and state.step_in_epoch == 0)
        ):
            _validate_and_save(trainer, config, val_set, paths, state, info, means, board)
        state.seconds = elapsed()
        reason = reason or _stop_reason(config, state, state.seconds)
        if not all_true(reason is None, info, trainer.device):  # stop together
            reason = reason or "stopped with the other processes"
    return reason


def _budget_reason(config: RunConfig, state: _State) -> str | None:
    train = config.train
    if train.max_steps is not None and state.step >= train.max_steps:
        return f"step budget of {train.max_steps} reached"
    if train.max_seconds is not None and state.seconds >= train.max_seconds:
        return f"time budget of {train.max_seconds:g} s reached"
    return None


def _stop_reason(config: RunConfig, state: _State, seconds: float) -> str | None:
    train = config.train
    if state.epoch >= train.epochs:
        return f"{train.epochs} epochs done"
    if train.patience and state.stale >= train.patience:
        return (
            f"early stopping: no better validation PSNR in {train.patience} validations "
            f"(best {state.best_psnr:.2f} dB at epoch {state.best_epoch})"
        )
    state.seconds = seconds
    return _budget_reason(config, state)


def _validate_and_save(
    trainer: Trainer,
    config: RunConfig,
    val_set: EpochDataset,
    paths: RunPaths,
    state: _State,
    info: Distributed,
    means: dict[str, float],
    board: Any,
) -> None:
    """Validate on rank 0, update early stopping, write checkpoints and metrics."""
    improved = False
    val_psnr = val_ssim = math.nan
    if info.is_main:
        val_psnr, val_ssim, sheet = validate(trainer.model, val_set, trainer.device)
        improved = val_psnr > state.best_psnr
        if improved:
            state.best_psnr, state.best_epoch, state.stale = val_psnr, state.epoch, 0
        elif state.step_in_epoch == 0:
            # Only end-of-epoch validations count towards early stopping, so that a
            # run stopped by a budget and resumed stops where a straight run would.
            state.stale += 1
        write_image(paths.samples, sheet)
        log.info(
            "epoch %d step %d: loss_g %.4g loss_d %.4g | validation PSNR %.2f dB, SSIM %.4f "
            "(%s) | best %.2f dB at epoch %d",
            state.epoch,
            state.step,
            means.get("loss_g", math.nan),
            means.get("loss_d", math.nan),
            val_psnr,
            val_ssim,
            VAL_CONVENTION,
            state.best_psnr,
            state.best_epoch,
        )
        if board is not None:
            board.add_scalar("val/psnr", val_psnr, state.step)
            board.add_scalar("val/ssim", val_ssim, state.step)
    state.stale = _broadcast_int(state.stale, info, trainer.device)
    if not info.is_main:
        return
    payload = {**trainer.state_dict(), **state.payload(), "rng": rng_state()}
    save_checkpoint(paths.last, payload, config)
    if improved:
        save_checkpoint(paths.best, payload, config)
    state.rows.append(_row(state, means, trainer.guard.total, val_psnr, val_ssim))
    _write_rows(paths.metrics, state.rows)


def _broadcast_int(value: int, info: Distributed, device: torch.device) -> int:
    if not info.active:
        return value
    import torch.distributed as dist

    tensor = torch.tensor([value], device=device)
    dist.broadcast(tensor, src=0)
    return int(tensor.item())


@torch.inference_mode()
def validate(
    network: nn.Module, val_set: EpochDataset, device: torch.device, samples: int = 3
) -> tuple[float, float, np.ndarray]:
    """Mean PSNR and SSIM (``skimage-gaussian``) of whole validation images, at fp32.

    Returns:
        ``(psnr_db, ssim, contact_sheet)``; PSNR means cap identical images at
        :data:`model.evaluation.PSNR_CAP_DB`.

    """
    from lenspair.contact_sheet import make_contact_sheet
    from model.evaluation import mean_psnr, score_tensors

    was_training = network.training
    network.eval()
    psnrs, ssims = [], []
    rows: list[list[np.ndarray | None]] = []
    for index in range(len(val_set)):
        sample = val_set[index]
        x = sample["input"][None].to(device)
        target = sample["target"][None].to(device)
        output = network(x)[1].float().clamp(0.0, 1.0)
        psnr, ssim = score_tensors(output, target, VAL_CONVENTION)
        psnrs.append(psnr)
        ssims.append(ssim)
        if len(rows) < samples:
            rows.append([_hwc(x), _hwc(output), _hwc(target)])
    network.train(was_training)
    labels = [["input", "output", "target"]] * len(rows)
    sheet = make_contact_sheet(rows, labels, title="validation samples")
    return mean_psnr(psnrs), float(np.mean(ssims)), sheet


def _hwc(batch: torch.Tensor) -> np.ndarray:
    array = batch[0].detach().float().cpu().numpy().transpose(1, 2, 0)
    return np.asarray(array)


def _row(
    state: _State, means: dict[str, float], skipped: int, val_psnr: float, val_ssim: float
) -> dict[str, str]:
    values: dict[str, object] = {
        "epoch": state.epoch,
        "step": state.step,
        "seconds": f"{state.seconds:.1f}",
        "skipped_steps": skipped,
        "val_psnr": f"{val_psnr:.4f}",
        "val_ssim": f"{val_ssim:.6f}",
        "best_psnr": f"{state.best_psnr:.4f}",
    }
    for name in ("loss_g", "loss_d", "adversarial", "feature_matching", "perceptual", "fidelity"):
        values[name] = f"{means[name]:.6g}" if name in means else ""
    return {column: str(values[column]) for column in METRICS_COLUMNS}


def _read_rows(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with path.open(newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def _write_rows(path: Path, rows: list[dict[str, str]]) -> None:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=METRICS_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({column: row.get(column, "") for column in METRICS_COLUMNS})
    atomic_write_text(path, buffer.getvalue())


@contextlib.contextmanager
def _run_logging(path: Path, enabled: bool) -> Iterator[None]:
    """Copy log records to ``RUN/train.log`` (INFO and up) while training.

    Processes other than rank 0 (``enabled=False``) log warnings and errors only.
    """
    package = logging.getLogger("model")
    old_level = package.level
    if not enabled:
        package.setLevel(logging.WARNING)
        try:
            yield
        finally:
            package.setLevel(old_level)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setLevel(logging.INFO)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    if package.getEffectiveLevel() > logging.INFO:
        package.setLevel(logging.INFO)
    root.addHandler(handler)
    try:
        yield
    finally:
        root.removeHandler(handler)
        handler.close()
        package.setLevel(old_level)


@contextlib.contextmanager
def _tensorboard(folder: Path, enabled: bool) -> Iterator[Any]:
    """A TensorBoard ``SummaryWriter`` when enabled and installed, else ``None``."""
    if not enabled:
        yield None
        return
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        log.info("TensorBoard is not installed; metrics go to metrics.csv only")
        yield None
        return
    writer = SummaryWriter(log_dir=str(folder))
    try:
        yield writer
    finally:
        writer.close()
