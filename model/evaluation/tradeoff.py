"""Accuracy against inference time: train variants under one budget, score and time them.

Every variant is trained on the same data with the same budget (steps or
seconds; early stopping off so that budgets stay equal), then its
``best.pt`` (the checkpoint of the best validation PSNR, as the paper's early
stopping keeps) is scored on the evaluation pairs and timed at batch 1 on the
data's frame size. Scored on the validation pairs themselves (a paired
folder without a test split), ``last.pt`` is: a checkpoint those pairs chose
would score a best of noisy validations on them. Each row says the step of
the checkpoint it scored (``scored_step``). Each ``GEA``-family checkpoint is scored and timed again
at bf16 (and fp16 on CUDA), since reduced precision is the other lever on
speed. The result is ONE table (``tradeoff.md``, ``.csv``, ``.json``) and a
plot (``tradeoff.png``) of PSNR and SSIM against CPU time with the Pareto
front (no other row is both faster and more accurate) marked; those files
are written by :func:`lenspair.model.evaluation.tradeoff_report.write_tradeoff`.

Layout of ``OUT``::

    tradeoff.md / tradeoff.csv / tradeoff.json / tradeoff.png
    tradeoff_config.yaml     base run config, budget and variants
    runs/<variant>/          one run folder per variant (reused when rerun)

A rerun into the same ``OUT`` reuses (resumes) a variant's run only when
everything that decides what it learns is unchanged: the model, data, loss
and train sections (seed included), the dataset and whether the perceptual
loss runs. A larger budget extends the run; anything else clears the run
folder and trains it again, with one log line naming the first difference
(:func:`reuse_obstacle`).
"""

import logging
import shutil
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch

from lenspair.core.config import dump_yaml, to_plain
from lenspair.core.durations import steps_or_seconds
from lenspair.core.fsutil import atomic_write_text
from lenspair.dataset.readers import detect_layout
from lenspair.model.checkpoint import checkpoint_config, load_checkpoint, load_model
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.evaluate import (
    Summary,
    agreement_with_fp32,
    scorable_pairs,
    score_pairs,
    summarize,
)
from lenspair.model.evaluation.latency import measure_latency
from lenspair.model.evaluation.tradeoff_report import write_tradeoff
from lenspair.model.evaluation.tradeoff_rows import TradeoffRow as TradeoffRow
from lenspair.model.evaluation.tradeoff_rows import mark_pareto as mark_pareto
from lenspair.model.evaluation.tradeoff_rows import pareto_front as pareto_front
from lenspair.model.networks.complexity import describe
from lenspair.model.precision import choose_precision, read_cpu_flags
from lenspair.model.training.config import RunConfig, Variant, config_differences
from lenspair.model.training.datasets import paired_training_data
from lenspair.model.training.loop import fit, resolve_config
from lenspair.model.training.pairs import SubsetSource, Unread, open_eval_pairs
from lenspair.model.training.run_files import RunPaths
from lenspair.model.training.step import (
    describe_precision,
    training_precision,
    vgg19_weights_path,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TradeoffVariant:
    """One network in the comparison."""

    name: str
    variant: Variant
    width: float = 1.0
    num_blocks: int = 9


DEFAULT_VARIANTS: tuple[TradeoffVariant, ...] = (
    TradeoffVariant("G", "G"),
    TradeoffVariant("GE", "GE"),
    TradeoffVariant("GEA", "GEA"),
    TradeoffVariant("GEA-w0.5", "GEA", width=0.5),
    TradeoffVariant("GEA-w2", "GEA", width=2.0),
    TradeoffVariant("GEA-b3", "GEA", num_blocks=3),
)
"""G, GE, GEA, a narrower and a wider GEA, and a GEA with 3 residual blocks."""


@dataclass(frozen=True)
class Budget:
    """Training budget of each variant: optimiser steps or wall-clock seconds."""

    steps: int | None = None
    seconds: float | None = None

    def describe(self) -> str:
        """``60 steps`` or ``90 s``."""
        return f"{self.steps} steps" if self.steps is not None else f"{self.seconds:g} s"

    @classmethod
    def from_description(cls, text: str) -> "Budget | None":
        """The budget :meth:`describe` wrote as ``text`` (a run's ``meta``); None for other text."""
        number, _, unit = text.partition(" ")
        try:
            value = float(number)
        except ValueError:
            return None
        if unit == "steps" and value.is_integer():
            return cls(steps=int(value))
        return cls(seconds=value) if unit == "s" else None


def parse_budget(text: str) -> Budget:
    """``"60"`` -> 60 steps; ``"90s"``, ``"2m"``, ``"1h"`` -> seconds.

    Raises:
        ModelError: anything else, or a non-positive budget.

    """
    try:
        steps, seconds = steps_or_seconds(text)
    except ValueError as exc:
        raise ModelError(f"--budget: {exc}") from None
    return Budget(steps=steps) if steps is not None else Budget(seconds=seconds)


@dataclass(frozen=True)
class TradeoffResult:
    """The table rows (Pareto flags set) and the conditions they were measured under."""

    rows: list[TradeoffRow]
    meta: dict[str, Any]


SCORED = {
    "best.pt": "each network's checkpoint of best validation PSNR (its step: scored_step in "
    "tradeoff.csv and tradeoff.json)",
    "last.pt": "each network at the end of its budget (the validation pairs are the "
    "scored ones, so they choose no checkpoint)",
}
"""What ``meta["scored"]`` says for each checkpoint scored."""

DEFAULT_LR_DECAY = 0.5
"""``lenspair tradeoff``'s learning-rate decay: over the step budget's second half (pix2pix)."""


def variant_config(base: RunConfig, variant: TradeoffVariant, budget: Budget) -> RunConfig:
    """The run config of one variant: its network, the shared budget, no early stopping.

    ``train.lr_decay`` is kept for a step budget and set to 0 for a time
    budget, whose length in steps is not known in advance.
    """
    return replace(
        base,
        model=replace(
            base.model, variant=variant.variant, width=variant.width, num_blocks=variant.num_blocks
        ),
        train=replace(
            base.train,
            max_steps=budget.steps,
            max_seconds=budget.seconds,
            patience=0,
            lr_decay=base.train.lr_decay if budget.steps else 0.0,
            epochs=max(base.train.epochs, 10**6)
            if budget.steps or budget.seconds
            else base.train.epochs,
        ),
        runtime=None,
    )


def precisions_for(
    variant: str, device: torch.device, native: Sequence[str] | None = None
) -> list[str]:
    """fp32 for every variant; GEA checkpoints again at each native reduced precision.

    ``native`` is what :func:`lenspair.model.precision.native_precisions` found
    on ``device`` (default: probed now): bf16 where it is native (an emulated
    one would only show the emulation), fp16 on CUDA, and int8 (ONNX Runtime,
    CPU) where the CPU has VNNI.
    """
    if variant != "GEA":
        return ["fp32"]
    if native is None:
        native = choose_precision("auto", device, "infer").native
    order = ("bf16", "fp16", "int8") if device.type == "cuda" else ("bf16", "int8")
    reduced = [p for p in order if p in native and not (p == "int8" and device.type == "cuda")]
    return ["fp32", *reduced]


def run_tradeoff(
    dataset: Path,
    out_dir: Path,
    device: torch.device,
    budget: Budget,
    base: RunConfig,
    variants: Sequence[TradeoffVariant] = DEFAULT_VARIANTS,
    convention: str = "skimage-gaussian",
    split: str | None = None,
    latency_runs: int = 20,
    int8: bool = True,
) -> TradeoffResult:
    """Train, score and time every variant; write the table and the plot.

    Args:
        dataset: paired data (any layout); trained on its training split.
        out_dir: output folder (see the module docstring); reruns reuse runs.
        device: training and scoring device; CPU timings are always taken.
        budget: per-variant training budget.
        base: run config shared by all variants (crop, batch, seed, losses).
        variants: the networks to compare.
        convention: metric convention of the table.
        split: evaluation split of a dataset with splits (an error when it
            cannot be opened); ``None``: ``test`` (an error too when its folder
            is there but cannot be opened, as with an unpaired file), and where
            there is none (a single paired folder, a dataset without a test
            folder or with an empty one) the validation pairs held out of its
            training, never pairs it trained on. Pairs that chose the
            checkpoint (held out, or the validation split) score the end of the
            budget, never the best of their own noisy validations.
        latency_runs: timed runs per latency figure.
        int8: add the int8 row where the CPU has VNNI (quantising takes a while).

    Returns:
        The rows (Pareto flags set) and the measurement conditions.

    """
    out_dir = Path(out_dir)
    # The resolved path goes into each run's config (runtime.data), so that a
    # rerun from another folder tells the same dataset from another one.
    data = paired_training_data(
        Path(dataset).resolve(), base.data, base.model.channels, base.train.seed
    )
    pairs: Any = None
    # the checkpoint the validation pairs chose, scored on other pairs; scored on
    # those same pairs it would be a best of noisy validations: the budget's end then
    checkpoint = "best.pt"
    if detect_layout(Path(dataset)) is None:  # a dataset with splits: score on ``split``
        wanted = split or "test"
        # asked for, or there: its problems are the answer (an unpaired file, a bad pair),
        # never a quiet switch to other pairs; only a dataset without a test folder falls back
        if split is not None or (Path(dataset) / wanted).is_dir():
            pairs = open_eval_pairs(dataset, wanted)
            pairs_text = f"{dataset} split {wanted}"
            if wanted == base.data.val_split:  # the pairs that chose best.pt: its end instead
                checkpoint = "last.pt"
        if split is None and pairs is not None and len(pairs) == 0:
            pairs = None  # an empty test split (dataset-build left it empty): as if none
    if pairs is None:
        # One paired folder (input/ + target/, Raindrop's train/) trains on nine
        # tenths of itself: score on the held-out tenth, never on training pairs.
        pairs = getattr(data.val, "source", None)
        if pairs is None:
            raise ModelError(f"{dataset}: no test split and no held-out pairs to score")
        pairs_text = f"{dataset} held-out validation pairs ({len(pairs)}, not trained on)"
        checkpoint = "last.pt"
    if len(pairs) == 0:
        raise ModelError(
            f"{pairs_text}: no pairs to score; choose another --split (e.g. val) or rebuild "
            "the dataset with a non-empty one (dataset-build --splits)"
        )
    readable, unread = scorable_pairs(pairs, data.channels, convention)
    if len(readable) == 0:
        raise ModelError(
            f"{pairs_text}: none can be read and scored; the first: {unread[0].reason}"
        )
    # scoring indexes the readable pairs; problems are reported by the split's own index
    view = readable.indices if isinstance(readable, SubsetSource) and unread else []
    pairs = readable
    size = tuple(pairs[0].input.shape[:2])
    out_dir.mkdir(parents=True, exist_ok=True)
    earlier_tradeoff = (out_dir / "tradeoff_config.yaml").is_file()  # before it is written
    meta = {
        "dataset": str(dataset),
        "evaluated_on": pairs_text,
        "budget": budget.describe(),
        "variants": [asdict(v) for v in variants],
        "device": str(device),
        "threads": torch.get_num_threads(),
        "cpu": read_cpu_flags()[0],  # the CPU of the CPU ms column (and of training on one)
        "size": f"{size[1]}x{size[0]}",
        "convention": convention,
        "seed": base.train.seed,
        "scored": SCORED[checkpoint],
    }
    atomic_write_text(
        out_dir / "tradeoff_config.yaml",
        dump_yaml({"base": to_plain(resolve_config(base, data.channels)), **meta}),
    )
    rows = []
    baseline: Summary | None = None
    cpu_native = choose_precision("auto", torch.device("cpu"), "infer").native
    for variant in variants:
        config = resolve_config(variant_config(base, variant, budget), data.channels)
        run = out_dir / "runs" / variant.name
        resume = _reusable(run, config, device, data.description, earlier_tradeoff)
        if not resume:  # tradeoff's own from here on: a rerun may resume or replace it
            atomic_write_text(run / RUN_MARKER, MARKER_TEXT)
        log.info("tradeoff: training %s for %s", variant.name, budget.describe())
        summary = fit(
            config,
            data.train,
            data.val,
            run,
            device,
            data_description=data.description,
            resume=resume,
            data_path=Path(dataset),
        )
        loaded = load_model(run / "checkpoints" / checkpoint, device)
        params, gflops = complexity(loaded.network, data.channels, (size[0], size[1]))
        for precision in precisions_for(variant.variant, device):
            if precision == "int8" and (
                not int8 or (variant.width, variant.num_blocks) != (1.0, 9)
            ):
                continue  # int8 for the paper's GEA only: each quantisation costs ~1 min
            trained_on = data.train.source  # type: ignore[union-attr]  # PairedCrops
            network = _at_precision(loaded.network, precision, pairs, trained_on, data.channels)
            scored = score_pairs(network, pairs, data.channels, device, convention, precision, 0, 0)
            scores = scored.scores
            for problem in scored.unread:  # indices of the view: back to the split's own
                index = view[problem.index] if view else problem.index
                if index not in {u.index for u in unread}:
                    unread.append(Unread(index, problem.reason))
            means = summarize(scores)
            versus = None
            if precision != "fp32":
                versus = agreement_with_fp32(
                    network, loaded.network, pairs, data.channels, device, convention, precision
                ).psnr_db
            baseline = baseline or summarize(scores, "input")
            cpu_ms = gpu_ms = None
            if precision in cpu_native:  # a CPU time at an emulated precision shows the emulation
                cpu = measure_latency(
                    network, data.channels, torch.device("cpu"), (size[0], size[1]),
                    precision, warmup=3, runs=latency_runs,
                )  # fmt: skip
                cpu_ms = cpu.median_ms
            if device.type == "cuda" and precision != "int8":
                gpu = measure_latency(
                    loaded.network, data.channels, device, (size[0], size[1]), precision,
                    warmup=3, runs=latency_runs,
                )  # fmt: skip
                gpu_ms = gpu.median_ms
            loaded.network.to(device)
            rows.append(
                TradeoffRow(
                    name=variant.name,
                    variant=variant.variant,
                    width=variant.width,
                    num_blocks=variant.num_blocks,
                    precision=precision,
                    params=params,
                    gflops=gflops,
                    cpu_ms=cpu_ms,
                    gpu_ms=gpu_ms,
                    psnr_db=means.psnr_db,
                    ssim=means.ssim,
                    convention=convention,
                    steps=summary.steps,
                    psnr_vs_fp32_db=versus,
                    scored_step=loaded.step,
                )
            )
            log.info("tradeoff: %s", rows[-1].describe())
    if baseline is not None:
        meta["input_baseline"] = {"psnr_db": baseline.psnr_db, "ssim": baseline.ssim}
    if unread:
        meta["unread"] = [asdict(u) for u in unread]
        meta["evaluated_on"] = f"{pairs_text}; {len(unread)} pair(s) could not be read or " + (
            "scored and are left out (listed in tradeoff.json)"
        )
    rows = mark_pareto(rows)
    write_tradeoff(rows, out_dir, meta)
    return TradeoffResult(rows, meta)


def _at_precision(
    network: torch.nn.Module, precision: str, pairs: Any, trained_on: Any, channels: int
) -> torch.nn.Module:
    """``network`` itself, or for int8 its ONNX Runtime quantisation.

    int8 calibrates on the pairs the network trained on (``trained_on``: a
    dataset's training split, or a paired folder less its held-out pairs),
    never on the scored ``pairs``, which would flatter its accuracy, at the
    evaluated frame size.
    """
    if precision != "int8":
        return network
    # here, not at the top: only int8 needs ONNX Runtime, which is slow to import
    from lenspair.model.evaluation.quantize import Int8Network, calibration_images

    size = (int(pairs[0].input.shape[0]), int(pairs[0].input.shape[1]))
    return Int8Network(network, channels, calibration_images(trained_on, channels, size))


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


def _reusable(
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
            shutil.rmtree(run)
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
    shutil.rmtree(run)
    return False


def _owned(run: Path, earlier_tradeoff: bool) -> bool:
    """Whether the run folder ``run`` is tradeoff's to resume or clear.

    Its marker says so. A folder without one (tradeoff before the marker, or
    killed before writing it) is adopted, marker written, when an earlier
    tradeoff wrote the output and the folder holds only what training writes;
    a note or any other file of the user's keeps it the user's.
    """
    if (run / RUN_MARKER).is_file():
        return True
    paths = RunPaths(run)  # what training writes: its files, checkpoints/, tensorboard/
    trained = (paths.config, paths.last.parent, paths.metrics, paths.log, paths.samples)
    written = {path.name for path in (*trained, paths.tensorboard)}
    theirs = [p.name for p in run.iterdir() if p.name not in written and not p.name.startswith(".")]
    if not earlier_tradeoff or theirs:
        return False
    atomic_write_text(run / RUN_MARKER, MARKER_TEXT)
    return True


def complexity(network: torch.nn.Module, channels: int, size: tuple[int, int]) -> tuple[int, float]:
    """Parameter count and GFLOPs of one forward pass at ``size`` = (H, W)."""
    summary = describe(network, (channels, size[0], size[1]))
    return summary.parameters, summary.gflops
