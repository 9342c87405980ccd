"""The training step of the shallow GAN: networks, optimisers, losses, NaN guard.

One step: the restoration network (G, E, A) maps the obstructed batch to
``(generator_out, enhanced_out)``; the conditional PatchGAN ``D`` scores
``cat(input, image)``. The network minimises, in one optimiser step,

    adversarial * LSGAN(D(gen)) + feature_matching * FM(D(gen), D(target))
    + perceptual * VGG19(enhanced, target) + fidelity * L2(enhanced, target)

and ``D`` takes its own LSGAN step on the detached outputs. ``D`` runs over
the real pairs once a step (its features of them serve feature matching too),
and its weights are frozen while it judges the network's output for the
network's loss, so it computes no weight gradient it would drop. Untrusted
pixels (``valid`` = 0) are left out of the fidelity term and replaced by the
(detached) output in the perceptual target, so they cost nothing.

Safety: a step whose losses or gradients are not finite updates nothing
(the NaN/Inf guard); ``train.nan_patience`` such steps in a row stop the run
with :class:`TrainingDivergedError`. The precision (``train.precision``) is
decided by :func:`lenspair.model.precision.choose_precision`: bf16 autocast
where the CPU or GPU runs bf16 natively, fp16 autocast with a ``GradScaler``
on CUDA devices with fp16 tensor cores only, fp32 otherwise.

Multi-GPU: under ``torchrun`` (``WORLD_SIZE`` > 1) both networks are wrapped
in ``DistributedDataParallel`` (the process group:
:mod:`lenspair.model.training.distributed`); the single-device path never
touches ``torch.distributed``. The loop over epochs is
:func:`lenspair.model.training.epochs.run_epochs`, started by
:func:`lenspair.model.training.loop.fit`.
"""

import contextlib
import logging
import math
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn
from torch.nn.parallel import DistributedDataParallel as DDP

from lenspair.core.config import config_path
from lenspair.model.checkpoint import build_network
from lenspair.model.errors import ModelError, TrainingDivergedError
from lenspair.model.networks.variants import build_discriminator
from lenspair.model.networks.vgg import VGG19_WEIGHTS_ENV, load_vgg19
from lenspair.model.precision import PrecisionDecision, choose_precision
from lenspair.model.training.config import UNTRAINED_WITHOUT, RunConfig, TrainConfig
from lenspair.model.training.distributed import Distributed, all_true, from_main
from lenspair.model.training.losses import (
    PerceptualLoss,
    discriminator_loss,
    feature_matching_loss,
    fidelity_loss,
    lsgan_loss,
)

log = logging.getLogger(__name__)

PERCEPTUAL_DISABLED = f"disabled (no VGG19 weights: set train.vgg19_weights or {VGG19_WEIGHTS_ENV})"


def training_precision(
    train: TrainConfig, device: torch.device, measure: bool = True
) -> PrecisionDecision:
    """The precision decision for training with ``train`` on ``device``.

    ``train.amp: false`` forces fp32; otherwise ``train.precision`` (``auto``
    by default) is resolved against the device's native precisions.

    Args:
        train: the training config.
        device: where the run trains.
        measure: whether ``auto`` may time bf16 against fp32 on a CPU with
            native bf16. Without it the decision is a placeholder that passes
            the same checks (and raises the same errors) but times nothing:
            what a ``torchrun`` process other than rank 0 computes before it
            takes rank 0's decision (:class:`Trainer`).

    Raises:
        ModelError: ``amp: false`` (``--no-amp``) beside a precision other than
            ``auto`` or ``fp32``: the two say opposite things.
    """
    if train.amp:
        unmeasured = None if measure else _not_measured
        return choose_precision(train.precision, device, "train", bf16_speed=unmeasured)
    if train.precision not in ("auto", "fp32"):
        raise ModelError(
            f"train.amp: false (--no-amp) trains at fp32, but train.precision (--precision) "
            f"is {train.precision}; give one of them"
        )
    decision = choose_precision("fp32", device, "train")
    return replace(decision, reason=f"train.amp: false (--no-amp); {decision.reason}")


def _not_measured(task: str) -> float:
    """A bf16 speed for a decision that rank 0's replaces: NaN, never compared true."""
    del task
    return math.nan


def describe_precision(precision: str) -> str:
    """``fp32``, ``bf16 autocast`` or ``fp16 autocast + GradScaler``."""
    return {"bf16": "bf16 autocast", "fp16": "fp16 autocast + GradScaler"}.get(precision, precision)


def vgg19_weights_path(configured: Path | None) -> Path | None:
    """The VGG19 weights file: the config's, else ``LENSPAIR_VGG19_WEIGHTS``, else None.

    ``~`` is expanded in either (:func:`lenspair.core.config.config_path`); a
    config file's relative path was read relative to its folder when loaded.
    """
    if configured is not None:
        return config_path(configured)
    env = os.environ.get(VGG19_WEIGHTS_ENV, "").strip()
    return config_path(env) if env else None


def trusted_target(target: Tensor, generated: Tensor, valid: Tensor) -> Tensor:
    """``target`` where it is trusted, the (detached) generated image where ``valid`` is 0.

    What the discriminator sees as real, in its own loss and in feature
    matching: a mask marks target pixels that misregistration or parallax make
    untrustworthy, and fidelity and the perceptual loss leave them out; shown
    to ``D`` as real they trained the network through feature matching
    (weight 10) as strongly as the trusted pixels. The generated pixels there
    make real and fake agree, so they teach nothing. Without a mask (``valid``
    all 1) this is ``target`` exactly.
    """
    valid = valid.to(target.dtype)
    return valid * target + (1 - valid) * generated.detach().to(target.dtype)


@dataclass
class StepResult:
    """Outcome of one training step.

    Attributes:
        losses: loss terms as floats (``loss_g``, ``loss_d``, and each term).
        skipped: the NaN/Inf guard skipped the update.

    """

    losses: dict[str, float]
    skipped: bool


@dataclass
class _Guard:
    consecutive: int = 0
    total: int = 0


def _unwrap(module: nn.Module) -> nn.Module:
    inner = getattr(module, "module", None)
    return inner if isinstance(inner, nn.Module) else module


def scheduled_lr(train: TrainConfig, step: int, total_steps: int) -> float:
    """The learning rate of optimiser step ``step`` (0-based) of a ``total_steps`` run.

    Constant at ``train.lr`` until the last ``train.lr_decay`` share of the
    run, then linear down to ``lr / decay_steps`` at the last step (never
    zero, never negative: a resumed run past its old end keeps the last
    rate). A function of the step alone, so a resumed run sets exactly the
    rates a straight run would.
    """
    decay_steps = train.lr_decay * total_steps
    if decay_steps <= 0:
        return train.lr
    remaining = max(total_steps - step, 1)
    return train.lr * min(1.0, remaining / decay_steps)


class Trainer:
    """Networks, optimisers, scaler and losses of one run, and its training step.

    Args:
        config: the resolved run configuration (``model.channels`` set).
        device: where to train.
        info: process-group position (default: single process).
        decision: the precision to train at (default: decided from
            ``config.train`` by :func:`training_precision`).

    Raises:
        ModelError: unresolved channels or an unreadable VGG19 weights file.

    """

    def __init__(
        self,
        config: RunConfig,
        device: torch.device,
        info: Distributed | None = None,
        decision: PrecisionDecision | None = None,
    ) -> None:
        self.config = config
        self.device = device
        self.info = info or Distributed()
        if config.model.channels is None:
            raise ModelError("model.channels must be resolved before training")
        self.channels = config.model.channels
        train = config.train
        # Initialisation draws from torch's global generator: seed it locally.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(train.seed)
            network = build_network(config.model)
            discriminator = build_discriminator(self.channels, config.model.discriminator_width)
        self.network: nn.Module = network.to(device)
        self.discriminator: nn.Module = discriminator.to(device)
        if self.info.active:
            ids = [device.index] if device.type == "cuda" else None
            self.network = DDP(self.network, device_ids=ids)
            self.discriminator = DDP(self.discriminator, device_ids=ids)
        betas = (train.beta1, train.beta2)
        self.opt_g = torch.optim.Adam(self.network.parameters(), lr=train.lr, betas=betas)
        self.opt_d = torch.optim.Adam(self.discriminator.parameters(), lr=train.lr, betas=betas)
        # auto times bf16 on rank 0 alone, while the other ranks wait at the broadcast
        # rather than load the cores it times on; every rank runs the config checks,
        # so a config error stops all of them, not rank 0 alone before the broadcast
        own = decision or training_precision(train, device, measure=self.info.is_main)
        self.decision = from_main(own, self.info)
        self.precision = describe_precision(self.decision.precision)
        self.amp_dtype = self.decision.autocast_dtype
        self.scaler = torch.amp.GradScaler(device.type, enabled=self.amp_dtype == torch.float16)
        self.vgg_path = vgg19_weights_path(train.vgg19_weights)
        # the config's file (~ expanded: a shell leaves --vgg19-weights=~/x as typed), else
        # None: load_vgg19 reads the variable itself, to name it
        configured = None if train.vgg19_weights is None else self.vgg_path
        self.vgg = None if config.loss.perceptual == 0 else load_vgg19(configured)
        self.perceptual: PerceptualLoss | None = None
        if self.vgg is not None:
            self.vgg = self.vgg.to(device)
            self.perceptual = PerceptualLoss(self.vgg, config.loss.perceptual_layers)
        if self.perceptual is None and not any(
            getattr(config.loss, name) > 0 for name in UNTRAINED_WITHOUT if name != "perceptual"
        ):
            raise ModelError(
                f"loss: perceptual is the only term with a weight, and it is {PERCEPTUAL_DISABLED}"
                "; without it the network would not train: give another term a weight above 0"
            )
        self.guard = _Guard()
        self.val_skipped: dict[int, str] = {}  # validation pairs that cannot be scored

    @property
    def perceptual_status(self) -> str:
        """``enabled (PATH)``, ``disabled (...)``: what the run config records."""
        if self.config.loss.perceptual == 0:
            return "disabled (loss.perceptual = 0)"
        if self.vgg is None:
            return PERCEPTUAL_DISABLED
        return f"enabled ({self.vgg_path})"

    @property
    def model(self) -> nn.Module:
        """The restoration network (unwrapped from DDP)."""
        return _unwrap(self.network)

    def _autocast(self) -> contextlib.AbstractContextManager[Any]:
        if self.amp_dtype is None:
            return contextlib.nullcontext()
        return torch.autocast(device_type=self.device.type, dtype=self.amp_dtype)

    def generate(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """The restoration network's ``(generator_out, enhanced_out)`` for ``x`` (autocast)."""
        with self._autocast():
            outputs = self.network(x)
        return outputs[0], outputs[1]

    def generator_terms(
        self,
        x: Tensor,
        target: Tensor,
        valid: Tensor,
        outputs: tuple[Tensor, Tensor] | None = None,
        real_features: list[Tensor] | None = None,
    ) -> tuple[Tensor, dict[str, Tensor], Tensor]:
        """The restoration network's loss terms (and its forward pass unless given).

        Args:
            x: the obstructed batch.
            target: the clean batch.
            valid: 1 where the target is trusted.
            outputs: :meth:`generate`'s result for ``x`` (default: computed here).
            real_features: ``D``'s features of the real pairs, as
                :meth:`discriminator_pass` returns them (default: computed here,
                without gradients).

        ``D``'s weights take no gradient from these terms (they are frozen for
        its pass over the generated pairs): only the restoration network learns
        from them, and ``D`` is spared computing weight gradients it would drop.

        Returns:
            ``(weighted sum, {term: value}, generator_out)``, losses in fp32.

        """
        weights = self.config.loss
        raw_d = _unwrap(self.discriminator)
        generated, enhanced = outputs if outputs is not None else self.generate(x)
        with self._autocast():
            if real_features is None:
                with torch.no_grad():
                    real_pairs = torch.cat([x, trusted_target(target, generated, valid)], 1)
                    real_features = raw_d(real_pairs)
            with frozen(raw_d):
                fake_features = raw_d(torch.cat([x, generated], dim=1))
        generated, enhanced = generated.float(), enhanced.float()
        fake = [f.float() for f in fake_features]
        real = [f.float() for f in real_features]
        terms: dict[str, Tensor] = {
            "adversarial": lsgan_loss(fake[-1], True),
            "feature_matching": feature_matching_loss(fake, real),
        }
        terms["fidelity"] = fidelity_loss(enhanced, target, valid)
        if self.perceptual is not None:
            trusted = trusted_target(target, enhanced, valid)
            with self._autocast():
                terms["perceptual"] = self.perceptual(enhanced, trusted).float()
        total = sum(
            (getattr(weights, name) * value for name, value in terms.items()),
            torch.zeros((), device=x.device),
        )
        return total, terms, generated

    def discriminator_pass(
        self, x: Tensor, target: Tensor, generated: Tensor, valid: Tensor | None = None
    ) -> tuple[Tensor, list[Tensor]]:
        """``D`` on the real and the (detached) generated pairs, in one forward pass.

        The real pairs' untrusted pixels (``valid`` 0) hold the generated ones,
        as :func:`trusted_target` gives feature matching.

        Returns:
            ``(LSGAN loss of D in fp32, the real pairs' features, detached)``:
            the features are what feature matching compares the generated
            pairs' with, so a step runs ``D`` over the real pairs once.
        """
        real = target if valid is None else trusted_target(target, generated, valid)
        pairs = torch.cat(
            [torch.cat([x, real], dim=1), torch.cat([x, generated.detach()], dim=1)], dim=0
        )
        with self._autocast():
            features = self.discriminator(pairs)
        half = x.shape[0]
        real_features = [f[:half].detach() for f in features]
        real_logits, fake_logits = features[-1].float().chunk(2, dim=0)
        return discriminator_loss(real_logits, fake_logits), real_features

    def discriminator_loss(
        self, x: Tensor, target: Tensor, generated: Tensor, valid: Tensor | None = None
    ) -> Tensor:
        """LSGAN loss of ``D`` on real pairs and detached generated pairs (fp32)."""
        return self.discriminator_pass(x, target, generated, valid)[0]

    def set_lr(self, lr: float) -> None:
        """Set the learning rate of both optimisers (the schedule: :func:`scheduled_lr`)."""
        for optimizer in (self.opt_g, self.opt_d):
            for group in optimizer.param_groups:
                group["lr"] = lr

    def train_step(self, batch: Mapping[str, Any]) -> StepResult:
        """One update of the restoration network and of ``D`` (or none, if not finite).

        Raises:
            TrainingDivergedError: ``train.nan_patience`` non-finite steps in a row.

        """
        self.network.train()
        self.discriminator.train()
        x = batch["input"].to(self.device, non_blocking=True)
        target = batch["target"].to(self.device, non_blocking=True)
        valid = batch["valid"].to(self.device, non_blocking=True)
        self.opt_g.zero_grad(set_to_none=True)
        self.opt_d.zero_grad(set_to_none=True)
        outputs = self.generate(x)
        # D first, on the real and the detached generated pairs: its backward frees its
        # graph before the network's, and its real features serve feature matching
        loss_d, real_features = self.discriminator_pass(x, target, outputs[0], valid)
        self.scaler.scale(loss_d).backward()
        loss_g, terms, _ = self.generator_terms(x, target, valid, outputs, real_features)
        self.scaler.scale(loss_g).backward()
        # Backward always runs (DDP needs every process to take part); the update may not.
        self.scaler.unscale_(self.opt_g)
        self.scaler.unscale_(self.opt_d)
        norm_g = _grad_norm(self.network, self.config.train.grad_clip, self.device)
        norm_d = _grad_norm(self.discriminator, None, self.device)
        checks = [loss_g.detach().float(), loss_d.detach().float()]
        if not self.scaler.is_enabled():  # with a scaler, inf gradients are its business
            checks += [norm_g, norm_d]
        finite = bool(torch.isfinite(torch.stack(checks)).all().item())
        finite = all_true(finite, self.info, self.device)
        if finite:
            self.scaler.step(self.opt_g)
            self.scaler.step(self.opt_d)
        else:
            self.opt_g.zero_grad(set_to_none=True)
            self.opt_d.zero_grad(set_to_none=True)
        self.scaler.update()
        losses = {"loss_g": float(loss_g.item()), "loss_d": float(loss_d.item())}
        losses.update({name: float(value.item()) for name, value in terms.items()})
        self._update_guard(finite, losses)
        return StepResult(losses=losses, skipped=not finite)

    def _update_guard(self, finite: bool, losses: dict[str, float]) -> None:
        if finite:
            self.guard.consecutive = 0
            return
        self.guard.consecutive += 1
        self.guard.total += 1
        shown = ", ".join(f"{k} {v:.4g}" for k, v in losses.items())
        log.warning(
            "non-finite loss or gradient: step skipped, no weight updated (%d in a row; %s)",
            self.guard.consecutive,
            shown,
        )
        patience = self.config.train.nan_patience
        if self.guard.consecutive >= patience:
            lr = float(self.opt_g.param_groups[0]["lr"])
            raise TrainingDivergedError(
                f"training diverged: {patience} consecutive steps with non-finite losses or "
                f"gradients ({shown}); lower train.lr (now {lr:g}), set "
                "train.grad_clip, or set train.amp: false, then restart or --resume from "
                "the last checkpoint"
            )

    def state_dict(self) -> dict[str, Any]:
        """Networks, optimisers and scaler state (tensors on their devices)."""
        return {
            "model": self.model.state_dict(),
            "discriminator": _unwrap(self.discriminator).state_dict(),
            "optimizer_g": self.opt_g.state_dict(),
            "optimizer_d": self.opt_d.state_dict(),
            "scaler": self.scaler.state_dict(),
            "skipped_steps": self.guard.total,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned (from a CPU checkpoint)."""
        self.model.load_state_dict(state["model"])
        _unwrap(self.discriminator).load_state_dict(state["discriminator"])
        for optimizer, key in ((self.opt_g, "optimizer_g"), (self.opt_d, "optimizer_d")):
            # the checkpoint's param_groups bring back its betas: a resume that changes
            # them (said as a config change) trained on with the old ones. The config's
            # are put back; the learning rate is set every step (Trainer.set_lr)
            betas = [group["betas"] for group in optimizer.param_groups]
            optimizer.load_state_dict(state[key])
            for group, configured in zip(optimizer.param_groups, betas, strict=True):
                group["betas"] = configured
        if state.get("scaler"):
            self.scaler.load_state_dict(state["scaler"])
        self.guard.total = int(state.get("skipped_steps", 0))


@contextlib.contextmanager
def frozen(module: nn.Module) -> Iterator[None]:
    """``module``'s trainable parameters take no gradient from what runs inside.

    Gradients still flow through the module to its inputs.
    """
    trainable = [p for p in module.parameters() if p.requires_grad]
    for parameter in trainable:
        parameter.requires_grad_(False)
    try:
        yield
    finally:
        for parameter in trainable:
            parameter.requires_grad_(True)


def _grad_norm(module: nn.Module, clip: float | None, device: torch.device) -> Tensor:
    """Total L2 norm of the gradients (clipped to ``clip`` when finite and set)."""
    grads = [p.grad for p in module.parameters() if p.grad is not None]
    if not grads:
        return torch.zeros((), device=device)
    norm = torch.nn.utils.get_total_norm(grads, error_if_nonfinite=False)
    if clip is not None and bool(torch.isfinite(norm)):
        torch.nn.utils.clip_grads_with_norm_(module.parameters(), clip, norm)
    return norm.detach().float()


def rng_state() -> dict[str, Any]:
    """Global torch CPU (and CUDA) generator states, for checkpoints."""
    state: dict[str, Any] = {"torch": torch.random.get_rng_state()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: Mapping[str, Any]) -> None:
    """Restore :func:`rng_state`'s result (CUDA states only where CUDA is present)."""
    if "torch" in state:
        torch.random.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(list(state["cuda"]))
