"""The tradeoff repeated over seeds: accuracy as mean +/- spread, a convergence check.

One training run per variant gives an accuracy figure whose run-to-run noise
can exceed the differences between variants. :func:`run_seeded_tradeoff`
runs :func:`~lenspair.model.evaluation.tradeoff.run_tradeoff` once per seed
(``OUT/seed<k>/``, each reusable on a rerun), then per network and
precision reports PSNR and SSIM as mean +/- spread over the seeds
(:mod:`lenspair.model.evaluation.seed_statistics`), the median CPU time,
whether training converged (over the last 20 % of the budget, validation
PSNR moved no more than the seed spread, checked on every seed's learning
curve ``runs/<variant>/metrics.csv``) and the Pareto front counted only
where a difference exceeds the spread. The paper's published rows are
printed beside, labelled. Files: ``OUT/tradeoff_seeds.md`` and ``.json``.

One output folder holds one kind of table. A single-seed tradeoff in ``OUT``
(``OUT/tradeoff.md`` + ``runs/``, seed k) that a seeded rerun includes is
moved into ``OUT/seed<k>/``, the same layout, and reused as that seed's
(:func:`adopt_single_seed`); a single-seed rerun into a seeded ``OUT`` is
refused (:func:`seeded_output_refusal`): its table would sit beside a
``tradeoff_seeds.md`` it is not part of, and its runs would train again
what ``OUT/seed<k>/runs/`` already holds.
"""

import logging
import os
import re
import statistics
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from lenspair.core.config import read_yaml
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import atomic_write_json, atomic_write_text
from lenspair.model.evaluation.seed_statistics import (
    converged,
    robust_pareto,
    summarise_seeds,
)
from lenspair.model.evaluation.tradeoff import TradeoffResult, run_tradeoff
from lenspair.model.evaluation.tradeoff_report import TABLE_FILES
from lenspair.model.evaluation.tradeoff_seeds_report import SeededRow, seeded_markdown
from lenspair.model.evaluation.tradeoff_variants import DEFAULT_VARIANTS, Budget, TradeoffVariant
from lenspair.model.training.config import RunConfig
from lenspair.model.training.run_files import read_metrics_rows

log = logging.getLogger(__name__)

SINGLE_SEED_FILES = (
    "runs",
    *TABLE_FILES,
    "tradeoff_config.yaml",  # last: while it is in OUT, a killed move is taken up again
)
"""What a single-seed tradeoff writes in ``OUT``; ``OUT/seed<k>/`` holds the same."""


def learning_curve(metrics_csv: Path, unit: str) -> list[tuple[float, float]]:
    """``(steps or seconds, validation PSNR)`` points of a run's ``metrics.csv``."""
    if not metrics_csv.is_file():
        return []
    column = "step" if unit == "steps" else "seconds"
    return [(float(row[column]), float(row["val_psnr"])) for row in read_metrics_rows(metrics_csv)]


def _convergence(
    out_dir: Path, seeds: Sequence[int], name: str, budget: Budget, spread: float
) -> tuple[bool | None, float | None]:
    unit = "steps" if budget.steps is not None else "seconds"
    limit = float(budget.steps if budget.steps is not None else budget.seconds or 0.0)
    checks = []
    for seed in seeds:
        curve = learning_curve(out_dir / f"seed{seed}" / "runs" / name / "metrics.csv", unit)
        check = converged(curve, limit, spread)
        if check is None:
            return None, None
        checks.append(check)
    largest = max((change for _, change in checks), key=abs)  # signed: a fall reads as one
    return all(held for held, _ in checks), largest


def aggregate(
    results: Sequence[TradeoffResult], out_dir: Path, seeds: Sequence[int], budget: Budget
) -> list[SeededRow]:
    """Group the per-seed rows by (name, precision) and summarise them.

    Convergence is a property of a training, not of a precision: each network's
    learning curves are checked once, against the seed spread of its fp32 row
    (the network as trained; its first row if it has none), and every precision
    of it gets that verdict. With fewer than two finite seeds there is no spread
    to compare with, so the check is not made.
    """
    keys: list[tuple[str, str]] = []
    for row in results[0].rows:
        keys.append((row.name, row.precision))
    grouped = {
        key: [r for result in results for r in result.rows if (r.name, r.precision) == key]
        for key in keys
    }
    psnrs = {key: summarise_seeds([r.psnr_db for r in same]) for key, same in grouped.items()}
    verdicts: dict[str, tuple[bool | None, float | None]] = {}
    for name, precision in keys:
        if name in verdicts and precision != "fp32":
            continue
        psnr = psnrs[(name, precision)]
        verdicts[name] = (
            _convergence(out_dir, seeds, name, budget, psnr.spread)
            if psnr.seeds >= 2
            else (None, None)
        )
    rows = []
    for (name, precision), same in grouped.items():
        cpu_times = [r.cpu_ms for r in same if r.cpu_ms is not None]
        gpu_times = [r.gpu_ms for r in same if r.gpu_ms is not None]
        psnr = psnrs[(name, precision)]
        ok, change = verdicts[name]
        rows.append(
            SeededRow(
                name=name,
                precision=precision,
                params=same[0].params,
                gflops=same[0].gflops,
                cpu_ms=statistics.median(cpu_times) if cpu_times else None,
                gpu_ms=statistics.median(gpu_times) if gpu_times else None,
                psnr=psnr,
                ssim=summarise_seeds([r.ssim for r in same]),
                converged=ok,
                tail_change_db=change,
            )
        )
    return mark_seeded(rows, results[0].meta.get("input_baseline"))


def mark_seeded(rows: Sequence[SeededRow], baseline: dict[str, float] | None) -> list[SeededRow]:
    """Set the spread-aware Pareto flags against CPU time.

    Args:
        rows: the seeded rows.
        baseline: the input without restoration (``psnr_db``, ``ssim``): it
            takes no time and scores the same in every seed (the same pairs),
            so it counts as exact; a row it beats by more than the row's
            spread is on no front (it is never marked itself).
    """
    row_times: list[float | None] = [r.cpu_ms for r in rows]
    psnr_rows, ssim_rows = [r.psnr for r in rows], [r.ssim for r in rows]
    if baseline and rows:
        times_seen = max(r.psnr.seeds for r in rows)
        row_times = [*row_times, 0.0]
        psnr_rows.append(summarise_seeds([baseline["psnr_db"]] * times_seen))
        ssim_rows.append(summarise_seeds([baseline["ssim"]] * times_seen))
    on_psnr = set(robust_pareto(row_times, psnr_rows)) - {len(rows)}
    on_ssim = set(robust_pareto(row_times, ssim_rows)) - {len(rows)}
    return [
        replace(row, pareto_psnr=i in on_psnr, pareto_ssim=i in on_ssim)
        for i, row in enumerate(rows)
    ]


def run_seeded_tradeoff(
    dataset: Path,
    out_dir: Path,
    device: torch.device,
    budget: Budget,
    base: RunConfig,
    seeds: Sequence[int],
    variants: Sequence[TradeoffVariant] = DEFAULT_VARIANTS,
    convention: str = "skimage-gaussian",
    split: str | None = None,
    latency_runs: int = 20,
    int8: bool = True,
) -> tuple[list[SeededRow], dict[str, Any]]:
    """Run the tradeoff once per seed and write ``tradeoff_seeds.md``/``.json``.

    The arguments are :func:`lenspair.model.evaluation.tradeoff.run_tradeoff`'s,
    plus ``seeds``: each seed trains every variant once (``out_dir/seed<k>/``).

    Returns:
        The seeded rows and the measurement conditions.

    """
    out_dir = Path(out_dir)
    adopt_single_seed(out_dir, seeds)
    results = []
    for seed in seeds:
        config = replace(base, train=replace(base.train, seed=seed))
        results.append(
            run_tradeoff(
                dataset, out_dir / f"seed{seed}", device, budget, config, variants,
                convention=convention, split=split, latency_runs=latency_runs, int8=int8,
            )
        )  # fmt: skip
    rows = aggregate(results, out_dir, seeds, budget)
    meta = dict(results[0].meta)
    meta.pop("seed", None)  # the first seed's; each seed<k>/tradeoff.json keeps its own
    meta["seeds"] = list(seeds)
    meta["training"] = {
        "crop_size": base.data.crop_size,
        "batch_size": base.train.batch_size,
        "lr": base.train.lr,
        "lr_decay": base.train.lr_decay,
    }
    baselines = [r.meta.get("input_baseline") for r in results]
    meta["input_baseline"] = baselines[0]
    atomic_write_text(out_dir / "tradeoff_seeds.md", seeded_markdown(rows, meta))
    atomic_write_json(
        out_dir / "tradeoff_seeds.json",
        {
            "meta": meta,
            "rows": [
                {
                    "name": r.name,
                    "precision": r.precision,
                    "params": r.params,
                    "gflops": r.gflops,
                    "cpu_ms": r.cpu_ms,
                    "gpu_ms": r.gpu_ms,
                    "psnr_db": list(r.psnr.values),
                    "ssim": list(r.ssim.values),
                    "converged": r.converged,
                    "tail_change_db": r.tail_change_db,
                    "pareto_psnr": r.pareto_psnr,
                    "pareto_ssim": r.pareto_ssim,
                }
                for r in rows
            ],
        },
    )
    return rows, meta


def seeded_output_refusal(out_dir: Path) -> str | None:
    """Why a single-seed tradeoff may not write into ``out_dir``, or ``None``.

    A seeded tradeoff's output (``tradeoff_seeds.json``, or a ``seed<k>/``
    table of one killed before it was written) is refused: rerun it with its
    seeds (its runs are reused), or write the single table elsewhere.
    """
    out_dir = Path(out_dir)
    seeded = sorted(
        path.name
        for path in (out_dir.iterdir() if out_dir.is_dir() else ())
        if re.fullmatch(r"seed\d+", path.name) and (path / "tradeoff_config.yaml").is_file()
    )
    if not seeded and not (out_dir / "tradeoff_seeds.json").is_file():
        return None
    held = f" ({', '.join(seeded)})" if seeded else ""
    return (
        f"{out_dir}: holds a tradeoff over several seeds{held}; a single-seed table "
        "would sit beside its tradeoff_seeds.md and train again what its seed folders "
        "hold. Rerun it with its --seeds (finished runs are reused) or choose another --out"
    )


def adopt_single_seed(out_dir: Path, seeds: Sequence[int]) -> None:
    """Move a single-seed tradeoff in ``out_dir`` into ``seed<k>/``, to be reused.

    Raises:
        ConfigError: ``out_dir`` holds a single-seed tradeoff whose seed is not
            among ``seeds``, whose seed cannot be read, or whose files clash
            with ``seed<k>/``'s: one folder must not hold two kinds of table.
    """
    config = out_dir / "tradeoff_config.yaml"
    if not config.is_file():
        return
    stored = read_yaml(config)
    seed = stored.get("seed") if isinstance(stored, dict) else None
    if not isinstance(seed, int) or seed not in seeds:
        which = f"seed {seed}" if isinstance(seed, int) else "its seed unreadable"
        raise ConfigError(
            f"{out_dir}: holds a single-seed tradeoff ({which}, tradeoff.md); include its "
            "seed in --seeds to reuse it as that seed's runs, or choose another --out"
        )
    target = out_dir / f"seed{seed}"
    clash = [n for n in SINGLE_SEED_FILES if (out_dir / n).exists() and (target / n).exists()]
    if clash:
        raise ConfigError(
            f"{out_dir}: holds a single-seed tradeoff (seed {seed}) and {target} both hold "
            f"{', '.join(clash)}; move one of them, or choose another --out"
        )
    target.mkdir(exist_ok=True)
    for name in SINGLE_SEED_FILES:
        if (out_dir / name).exists():
            os.replace(out_dir / name, target / name)
    log.info(
        "tradeoff: %s held a single-seed tradeoff (seed %d); moved it into %s, "
        "reused as that seed's",
        out_dir,
        seed,
        target,
    )
