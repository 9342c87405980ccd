"""The seeded tradeoff's rows and its Markdown table (``OUT/tradeoff_seeds.md``).

:class:`SeededRow` is one network at one precision over seeds;
:func:`seeded_markdown` writes the table with its measurement conditions,
the convergence verdict and the paper's published rows beside, labelled.
:mod:`lenspair.model.evaluation.tradeoff_seeds` measures what they hold.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from lenspair.core.wording import counted
from lenspair.model.evaluation.published import ABLATION, STATE_OF_THE_ART, published_markdown
from lenspair.model.evaluation.seed_statistics import CONVERGENCE_TAIL, SeedSummary
from lenspair.model.evaluation.tradeoff_report import trained_on_line


@dataclass(frozen=True)
class SeededRow:
    """One network at one precision, over seeds.

    Attributes:
        name: variant name.
        precision: ``fp32``, ``bf16``, ``fp16``.
        params: parameter count.
        gflops: GFLOPs per frame.
        cpu_ms: median over seeds of the median CPU ms per frame (None if unknown).
        gpu_ms: the same on the GPU (None unless trained on CUDA, or at a precision
            the GPU does not run).
        psnr: PSNR over seeds, dB.
        ssim: SSIM over seeds.
        converged: the convergence check held on every seed (None: not checkable).
        tail_change_db: the PSNR change over the last 20 % of the budget, signed, of the
            seed whose change was largest in size.
        pareto_psnr: on the spread-aware PSNR-vs-CPU-time front.
        pareto_ssim: on the spread-aware SSIM-vs-CPU-time front.

    """

    name: str
    precision: str
    params: int
    gflops: float
    cpu_ms: float | None
    psnr: SeedSummary
    ssim: SeedSummary
    converged: bool | None
    tail_change_db: float | None
    pareto_psnr: bool = False
    pareto_ssim: bool = False
    gpu_ms: float | None = None


def _schedule(training: dict[str, Any]) -> str:
    """Crops, batch and learning-rate schedule in words (what a budget of steps buys)."""
    decay = float(training["lr_decay"])
    rate = (
        f"falling linearly towards zero over the last {decay:.0%} of the budget"
        if decay > 0
        else "constant"
    )
    return (
        f"{training['crop_size']} px crops, batch {training['batch_size']}, learning rate "
        f"{training['lr']:g} {rate}"
    )


def seeded_markdown(rows: Sequence[SeededRow], meta: dict[str, Any]) -> str:
    """The table, its conditions, the convergence verdict and the published rows.

    A ``GPU ms`` column is there only when some row was timed on a GPU (a run
    trained on CUDA); a CPU run's table keeps the columns it always had.
    """
    tail = f"{CONVERGENCE_TAIL:.0%}"
    gpu = any(row.gpu_ms is not None for row in rows)
    lines = [
        "# Accuracy against inference time, over seeds",
        "",
        f"- data: `{meta['dataset']}`, scored on {meta['evaluated_on']}"
        + (f" ({counted(meta['pairs_scored'], 'pair')})" if "pairs_scored" in meta else ""),
        f"- training budget per variant and seed: {meta['budget']}; seeds {meta['seeds']}",
        *([f"- training: {_schedule(meta['training'])}"] if "training" in meta else []),
        *(
            [f"- scored: {meta['scored']} (per seed: seed<k>/tradeoff.json)"]
            if "scored" in meta
            else []
        ),
        f"- metric convention: {meta['convention']}; accuracy is mean +/- spread (sample "
        "standard deviation over seeds)",
        f"- CPU ms: median over seeds of the median per frame (batch 1, {meta['size']}"
        + (f", {meta['threads']} threads" if meta.get("threads") else "")
        + ")"
        + (f", on {meta['cpu']}" if meta.get("cpu") else ""),
        f"- converged: over the last {tail} of the budget (from the last validation at or "
        "before it) the trend (least-squares line) of validation PSNR moved no more than the "
        "seed spread of the network's fp32 PSNR, on every seed (the largest change, signed, "
        "in brackets; one verdict per network, whatever the precision)",
        *(
            [
                "- GPU ms: the same on "
                + (meta.get("gpu") or "the GPU")
                + " (n/a where the GPU did not run a precision); Pareto marks stay "
                "against CPU time"
            ]
            if gpu
            else []
        ),
        "- Pareto: `*` PSNR-vs-time, `+` SSIM-vs-time front; a row is dominated only by a "
        "row as fast that is better by more than either spread",
        "",
        f"| name | precision | params | GFLOPs | CPU ms |{' GPU ms |' if gpu else ''} "
        "PSNR (dB) | SSIM | converged | Pareto |",
        "|---|---|---|---|---|" + ("---|" if gpu else "") + "---|---|---|---|",
    ]
    baseline = meta.get("input_baseline")
    if baseline:
        lines.append(
            f"| input, no restoration | - | 0 | 0 | 0 |{' 0 |' if gpu else ''} "
            f"{baseline['psnr_db']:.2f} | {baseline['ssim']:.4f} | - | |"
        )
    for row in rows:
        cpu = "n/a" if row.cpu_ms is None else f"{row.cpu_ms:.1f}"
        if gpu:
            cpu += " | " + ("n/a" if row.gpu_ms is None else f"{row.gpu_ms:.2f}")
        if row.converged is None:
            verdict = "not checkable"
        else:
            verdict = f"{'yes' if row.converged else 'no'} ({row.tail_change_db:+.2f} dB)"
        marks = ("*" if row.pareto_psnr else "") + ("+" if row.pareto_ssim else "")
        lines.append(
            f"| {row.name} | {row.precision} | {row.params:,} | {row.gflops:.1f} | {cpu} | "
            f"{row.psnr.format(2)} | {row.ssim.format(4)} | {verdict} | {marks} |"
        )
    if all(row.converged is True for row in rows):
        verdict_text = (
            "The convergence check holds for every network: the accuracy columns compare "
            "converged networks."
        )
    elif any(row.converged is False for row in rows):
        verdict_text = (
            "The convergence check does NOT hold for every network: validation PSNR still "
            "moved over the budget's last fifth by more than the seed spread (under a "
            "decaying learning rate partly the settling as the rate falls; a run at another "
            "budget tells the two apart); read the accuracy columns as what this budget buys."
        )
    else:
        verdict_text = (
            "The convergence check could not be made for every network (too few seeds or "
            "validations): whether a longer budget would change the accuracy columns is "
            "not known."
        )
    lines += ["", verdict_text]
    if warning := trained_on_line(meta):  # the first seed's count: each seed trains on the same
        lines += ["", warning]
    lines += ["", published_markdown((ABLATION, STATE_OF_THE_ART))]
    return "\n".join(lines) + "\n"
