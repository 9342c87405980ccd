"""Accuracy against inference time: train variants under one budget, score and time them.

Every variant (:mod:`lenspair.model.evaluation.tradeoff_variants`) is trained
on the same data with the same budget (steps or seconds; early stopping off
so that budgets stay equal), then its ``best.pt`` (the checkpoint of the best
validation PSNR, as the paper's early stopping keeps) is scored on the
evaluation pairs and timed at batch 1 on the data's frame size. Scored on the
validation pairs themselves (a paired folder without a test split),
``last.pt`` is: a checkpoint those pairs chose would score a best of noisy
validations on them. Each row says the step of the checkpoint it scored
(``scored_step``). Each ``GEA``-family checkpoint is scored and timed again
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
everything that decides what it learns is unchanged; a larger budget
extends the run, anything else trains it again
(:mod:`lenspair.model.evaluation.tradeoff_reuse`).
"""

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from lenspair.core.config import dump_yaml, to_plain
from lenspair.core.fsutil import atomic_write_text, remove_path
from lenspair.model.checkpoint import load_model
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.latency import measure_latency
from lenspair.model.evaluation.scoring import agreement_with_fp32, score_pairs
from lenspair.model.evaluation.summary import ImageScore, Summary, summarize
from lenspair.model.evaluation.tradeoff_pairs import eval_pairs, note_trained_on
from lenspair.model.evaluation.tradeoff_report import TABLE_FILES, write_tradeoff
from lenspair.model.evaluation.tradeoff_reuse import MARKER_TEXT, RUN_MARKER, reusable
from lenspair.model.evaluation.tradeoff_rows import TradeoffRow, mark_pareto
from lenspair.model.evaluation.tradeoff_variants import (
    DEFAULT_VARIANTS,
    Budget,
    TradeoffVariant,
    precisions_for,
    variant_config,
)
from lenspair.model.networks.complexity import describe
from lenspair.model.precision import choose_precision, read_cpu_flags
from lenspair.model.training.config import RunConfig
from lenspair.model.training.datasets import TrainData, paired_training_data
from lenspair.model.training.loop import fit, resolve_config
from lenspair.model.training.pairs import Unread

log = logging.getLogger(__name__)


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
            budget, never the best of their own noisy validations. Pairs the
            networks trained on (``train``) are scored, and said so in the log
            and under the table (``trained_on_scored_pairs``: they flatter the
            scores, and the int8 row calibrated on them).
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
    chosen = eval_pairs(dataset, split, base.data, data, convention)
    pairs, pairs_text, checkpoint = chosen.pairs, chosen.text, chosen.checkpoint
    unread, view = chosen.unread, chosen.view
    size = tuple(pairs[0].input.shape[:2])
    out_dir.mkdir(parents=True, exist_ok=True)
    earlier_tradeoff = (out_dir / "tradeoff_config.yaml").is_file()  # before it is written
    meta = {
        "dataset": str(dataset),
        "evaluated_on": pairs_text,
        "pairs_scored": len(pairs),  # two draws of one dataset's name differ in it
        "budget": budget.describe(),
        "variants": [asdict(v) for v in variants],
        "device": str(device),
        "threads": torch.get_num_threads(),
        "cpu": read_cpu_flags()[0],  # the CPU of the CPU ms column (and of training on one)
        **({"gpu": torch.cuda.get_device_name(device)} if device.type == "cuda" else {}),
        "size": f"{size[1]}x{size[0]}",
        "convention": convention,
        "seed": base.train.seed,
        "scored": SCORED[checkpoint],
    }
    said = dump_yaml({"base": to_plain(resolve_config(base, data.channels)), **meta})
    earlier = out_dir / "tradeoff_config.yaml"
    if earlier_tradeoff and earlier.read_text(encoding="utf-8") != said:
        # the table of other settings goes now: a rerun stopped before its end left it
        # beside this config, its rows naming checkpoints the rerun had cleared
        for name in TABLE_FILES:
            remove_path(out_dir / name)
    atomic_write_text(earlier, said)
    rows = []
    baseline: Summary | None = None
    cpu_native = choose_precision("auto", torch.device("cpu"), "infer").native
    for variant in variants:
        run = out_dir / "runs" / variant.name
        steps = _train_variant(variant, base, budget, data, run, device, dataset, earlier_tradeoff)
        loaded = load_model(run / "checkpoints" / checkpoint, device)
        params, gflops = complexity(loaded.network, data.channels, (size[0], size[1]))
        for precision in precisions_for(variant.variant, device):
            if precision == "int8" and (
                not int8 or (variant.width, variant.num_blocks) != (1.0, 9)
            ):
                continue  # int8 for the paper's GEA only: each quantisation costs ~1 min
            trained_on = data.train.source  # type: ignore[union-attr]  # PairedCrops
            network = _at_precision(loaded.network, precision, pairs, trained_on, data.channels)
            scores, means, versus = _score(
                network, loaded.network, pairs, data.channels, device, convention, precision,
                view, unread,
            )  # fmt: skip
            baseline = baseline or summarize(scores, "input")
            cpu_ms, gpu_ms = _latencies(
                network, loaded.network, data.channels, device, (size[0], size[1]), precision,
                latency_runs, cpu_native,
            )  # fmt: skip
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
                    steps=steps,
                    psnr_vs_fp32_db=versus,
                    scored_step=loaded.step,
                )
            )
            log.info("tradeoff: %s", rows[-1].describe())
        if "trained_on_scored_pairs" not in meta:  # every variant trained on the same pairs
            note_trained_on(meta, loaded, chosen)
    if meta.get("trained_on_scored_pairs") and any(row.precision == "int8" for row in rows):
        meta["int8_calibrated_on_scored"] = True  # it calibrates on the training pairs
    if baseline is not None:
        meta["input_baseline"] = {"psnr_db": baseline.psnr_db, "ssim": baseline.ssim}
    if unread:
        meta["unread"] = [asdict(u) for u in unread]
        meta["evaluated_on"] = f"{pairs_text}; {len(unread)} pair(s) could not be read or " + (
            "scored and are left out (listed in tradeoff.json)"
        )
    rows = mark_pareto(rows, None if baseline is None else (baseline.psnr_db, baseline.ssim))
    write_tradeoff(rows, out_dir, meta)
    return TradeoffResult(rows, meta)


def _train_variant(
    variant: TradeoffVariant,
    base: RunConfig,
    budget: Budget,
    data: TrainData,
    run: Path,
    device: torch.device,
    dataset: Path,
    earlier_tradeoff: bool,
) -> int:
    """Train (or resume, :func:`reusable`) one variant's run in ``run``; returns its steps."""
    config = resolve_config(variant_config(base, variant, budget), data.channels)
    resume = reusable(run, config, device, data.description, earlier_tradeoff)
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
    if summary.steps == 0 and summary.best_epoch == 0:  # "best.pt: checkpoint not found" next
        raise ModelError(
            f"{variant.name}: {summary.stop_reason} before the first step: nothing was trained; "
            "give a larger --budget"
        )
    return summary.steps


def _score(
    network: torch.nn.Module,
    reference: torch.nn.Module,
    pairs: Any,
    channels: int,
    device: torch.device,
    convention: str,
    precision: str,
    view: list[int],
    unread: list[Unread],
) -> tuple[list[ImageScore], Summary, float | None]:
    """Score ``network`` at ``precision`` on ``pairs``; beside fp32 ``reference`` if reduced.

    Pairs that fail are added to ``unread`` by the split's own index (``view``
    maps the readable pairs' indices back to it), each once.

    Returns:
        The per-pair scores, their means, and the mean PSNR (dB) of the output
        against ``reference``'s (None at fp32).

    """
    scored = score_pairs(
        network, pairs, channels, device, convention, precision, 0, 0, skip_out_of_memory=False
    )
    for problem in scored.unread:  # indices of the view: back to the split's own
        index = view[problem.index] if view else problem.index
        if index not in {u.index for u in unread}:
            unread.append(Unread(index, problem.reason))
    means = summarize(scored.scores)
    versus = None
    if precision != "fp32":
        versus = agreement_with_fp32(
            network,
            reference,
            pairs,
            channels,
            device,
            convention,
            precision,
            skip_out_of_memory=False,
        ).psnr_db
    return scored.scores, means, versus


def _latencies(
    network: torch.nn.Module,
    reference: torch.nn.Module,
    channels: int,
    device: torch.device,
    size: tuple[int, int],
    precision: str,
    runs: int,
    cpu_native: Sequence[str],
) -> tuple[float | None, float | None]:
    """Median ms per ``size`` = (H, W) frame at batch 1: on the CPU, and on CUDA.

    ``network`` is timed on the CPU where ``precision`` is native there;
    ``reference`` (the torch network) on ``device`` when it is CUDA, but for int8.
    """
    cpu_ms = gpu_ms = None
    if precision in cpu_native:  # a CPU time at an emulated precision shows the emulation
        cpu = measure_latency(
            network, channels, torch.device("cpu"), size, precision, warmup=3, runs=runs
        )
        cpu_ms = cpu.median_ms
    if device.type == "cuda" and precision != "int8":
        gpu = measure_latency(reference, channels, device, size, precision, warmup=3, runs=runs)
        gpu_ms = gpu.median_ms
    return cpu_ms, gpu_ms


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


def complexity(network: torch.nn.Module, channels: int, size: tuple[int, int]) -> tuple[int, float]:
    """Parameter count and GFLOPs of one forward pass at ``size`` = (H, W)."""
    summary = describe(network, (channels, size[0], size[1]))
    return summary.parameters, summary.gflops
