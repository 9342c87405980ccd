"""Validation during training: whole-image scores, samples, best checkpoint.

Validation runs on rank 0 after every ``train.val_every`` epochs (and at a
budget stop) on whole images at fp32; its PSNR (convention
:data:`VAL_CONVENTION`) drives ``best.pt`` and early stopping
(``train.patience`` validations without improvement). After each validation
:func:`validate_and_save` writes ``last.pt``, ``best.pt`` when the PSNR
improved, ``samples.png`` and a row of ``metrics.csv``
(:mod:`lenspair.model.training.run_files`).

Only the scheduled validations (at the end of every ``val_every``-th epoch,
and of the last epoch) count for ``best.pt`` and early stopping. A budget
stop validates too, mid-epoch or at the end of an epoch off that schedule
(logged, in ``metrics.csv`` and ``last.pt``), but a straight run has no such
validation, so counting it would make a budget-stopped and resumed run keep
other weights and stop elsewhere. The one exception: a run with no best yet
(its budget ended before its first scheduled validation) takes ``best.pt``,
``best_psnr`` and ``best_epoch`` from its budget-stop validation, so that
every run leaves a usable ``best.pt`` (``lenspair train --max-steps`` and the
demo hand it on); a later scheduled validation of a resumed run then has to
beat that PSNR.
"""

import copy
import logging
import math
from typing import Any, Protocol

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from lenspair.core.contact_sheet import make_contact_sheet
from lenspair.core.errors import LenspairError
from lenspair.core.imagewrite import write_image
from lenspair.model.checkpoint import save_checkpoint
from lenspair.model.errors import ModelError, TrainingDivergedError
from lenspair.model.evaluation.scoring import score_tensors
from lenspair.model.evaluation.summary import mean_psnr
from lenspair.model.training.config import RunConfig
from lenspair.model.training.distributed import Distributed
from lenspair.model.training.pairs import Sample
from lenspair.model.training.run_files import RunPaths, metrics_row, write_metrics_rows
from lenspair.model.training.run_state import RunState
from lenspair.model.training.step import Trainer, rng_state

log = logging.getLogger(__name__)

VAL_CONVENTION = "skimage-gaussian"
"""Metric convention of the validation PSNR/SSIM that drives early stopping."""


class SampleSet(Protocol):
    """Indexable samples with a length, e.g. a validation set (of ``training.pairs``)."""

    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> Sample: ...


def validate_and_save(
    trainer: Trainer,
    config: RunConfig,
    val_set: SampleSet,
    paths: RunPaths,
    state: RunState,
    info: Distributed,
    means: dict[str, float],
    board: Any,
) -> None:
    """Validate on rank 0, update early stopping, write checkpoints and metrics.

    A validation off the schedule (mid-epoch, or after an epoch that is not a
    ``val_every``-th: a budget stop) leaves ``best.pt``, the best PSNR and
    early stopping alone unless the run has no best yet (module docstring).
    """
    improved = False
    val_psnr = val_ssim = math.nan
    if info.is_main:
        val_psnr, val_ssim, sheet = validate(
            trainer.model, val_set, trainer.device, skipped=trainer.val_skipped
        )
        end_of_epoch = state.step_in_epoch == 0
        train = config.train
        scheduled = end_of_epoch and (
            state.epoch % train.val_every == 0 or state.epoch >= train.epochs
        )
        # epochs count from 1, as the progress bar does: mid-epoch, the one under way
        epoch = state.epoch if end_of_epoch else state.epoch + 1
        improved = val_psnr > state.best_psnr and (scheduled or state.best_psnr == -math.inf)
        if improved:
            # a mid-epoch best lies in the epoch under way: 0 keeps meaning "no best yet"
            state.best_psnr = val_psnr
            state.best_epoch = epoch
            if scheduled:
                state.stale = 0
        elif scheduled:
            state.stale += 1
        note = ""
        if not scheduled:
            where = "mid-epoch" if not end_of_epoch else "off the val_every schedule"
            note = f"; {where}: " + ("the run's first best" if improved else "not counted")
        write_image(paths.samples, sheet)
        log.info(
            "epoch %d step %d: loss_g %.4g loss_d %.4g | validation PSNR %.2f dB, SSIM %.4f "
            "(%s%s) | best %.2f dB at epoch %d",
            epoch,
            state.step,
            means.get("loss_g", math.nan),
            means.get("loss_d", math.nan),
            val_psnr,
            val_ssim,
            VAL_CONVENTION,
            note,
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
    # last.pt is the commit point of a resume: everything it vouches for is
    # written first (a resume drops metrics rows past its step).
    state.rows.append(metrics_row(state, means, trainer.guard.total, val_psnr, val_ssim))
    write_metrics_rows(paths.metrics, state.rows)
    if improved:
        save_checkpoint(paths.best, payload, config)
    save_checkpoint(paths.last, payload, config)


def _broadcast_int(value: int, info: Distributed, device: torch.device) -> int:
    if not info.active:
        return value
    tensor = torch.tensor([value], device=device)
    dist.broadcast(tensor, src=0)
    return int(tensor.item())


@torch.inference_mode()
def validate(
    network: nn.Module,
    val_set: SampleSet,
    device: torch.device,
    samples: int = 3,
    skipped: dict[int, str] | None = None,
) -> tuple[float, float, np.ndarray]:
    """Mean PSNR and SSIM (``skimage-gaussian``) of whole validation images, at fp32.

    A pair that cannot be read or scored (a truncated file, an image under
    SSIM's 11x11 window) is left out with a warning, once per run when
    ``skipped`` (index -> reason) is kept between validations: one bad pair
    must not end a run at its first validation, after an epoch of training.

    A network whose output on a finite input holds NaN or Inf has diverged:
    that is no problem of the pair, and leaving the pairs out one by one ended
    the run blaming the validation data.

    Returns:
        ``(psnr_db, ssim, contact_sheet)``; PSNR means cap identical images at
        :data:`lenspair.model.evaluation.evaluate.PSNR_CAP_DB`.

    Raises:
        ModelError: no validation pair can be scored (naming the first problem).
        TrainingDivergedError: the network's output is not finite.

    """
    deployed = _as_deployed(network, device)
    skipped = {} if skipped is None else skipped
    psnrs, ssims = [], []
    rows: list[list[np.ndarray | None]] = []
    for index in range(len(val_set)):
        if index in skipped:
            continue
        sample: Sample | None = None
        try:
            sample = val_set[index]
            x = sample["input"][None].to(device)
            target = sample["target"][None].to(device)
            output = deployed(x)[1].float()
            # checked before the clamp, which turns Inf into 1 and lets NaN through
            if not bool(torch.isfinite(output).all()) and bool(torch.isfinite(x).all()):
                raise TrainingDivergedError(
                    f"training diverged: the network's output on validation pair "
                    f"{sample['name']} holds NaN or Inf; lower train.lr or set "
                    "train.grad_clip, and start a new run (--init an earlier checkpoint)"
                )
            output = output.clamp(0.0, 1.0)
            valid = sample["valid"][None].to(device)  # mask/'s pixels, out as in the loss
            psnr, ssim = score_tensors(output, target, VAL_CONVENTION, valid)
        except TrainingDivergedError:
            raise  # the network's problem, not the pair's
        except LenspairError as exc:
            skipped[index] = f"{sample['name']}: {exc}" if sample is not None else str(exc)
            log.warning("validation: left out for the rest of the run: %s", skipped[index])
            continue
        psnrs.append(psnr)
        ssims.append(ssim)
        if len(rows) < samples:
            rows.append([_hwc(x), _hwc(output), _hwc(target)])
    if not psnrs:
        raise ModelError(
            f"no validation pair can be scored; the first: {next(iter(skipped.values()))}"
        )
    labels = [["input", "output", "target"]] * len(rows)
    sheet = make_contact_sheet(rows, labels, title="validation samples")
    return mean_psnr(psnrs), float(np.mean(ssims)), sheet


def _as_deployed(network: nn.Module, device: torch.device) -> nn.Module:
    """An eval-mode copy of ``network`` laid out as ``restore`` runs it.

    On the CPU that is channels-last (:func:`lenspair.model.inference.backends.deploy`):
    1.7x faster than the training layout on whole 540x360 frames (GEA, fp32, 2
    threads: 147 against 250 ms), and validation of a small dataset costs as
    much as its epoch of training. A copy, so that the parameters the
    optimiser holds keep their layout and the network keeps its mode; and not
    ``deploy`` itself, which also retunes the whole process's allocator.
    """
    deployed = copy.deepcopy(network).eval()
    if device.type == "cpu":
        deployed.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    return deployed


def _hwc(batch: torch.Tensor) -> np.ndarray:
    array = batch[0].detach().float().cpu().numpy().transpose(1, 2, 0)
    return np.asarray(array)
