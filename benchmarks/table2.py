"""The paper's Table 2 on what runs here: which pretraining helps fine-tuning?

    python -m benchmarks.table2 --out table2_out --pretrain-steps 60 --finetune-steps 60 \\
        --seeds 0 1 2

1. A dataset of simulated recording pairs: the demo's (``lenspair demo``
   stages up to ``dataset-build``, ``--frames`` per recording), or ``--dataset DS``.
2. Pretraining, once per preset (seed 0, the same budget and data for both):
   GEA on ``ours`` and on ``sharp`` drops rendered over the bundled natural
   photographs (``lenspair train --synthetic``).
3. Fine-tuning on the same dataset from each start (``ours``, ``sharp``,
   ``random`` initialisation), once per seed, same budget.
4. Scoring every fine-tuned network on the same held-out test pairs
   (skimage-gaussian convention), reported as mean +/- spread over seeds
   (sample standard deviation); a difference is claimed only when larger
   than the spread of both sides.

Writes ``OUT/table2.md`` and ``table2.json``. The paper's published
initialisation rows (its rig data, GPU, full training) are printed beside,
labelled.

Reruns into the same ``--out``: a run is reused only when it finished (its
``last.pt`` exists and records a stop: the step budget reached, or early
stopping where a ``--config`` turns it on) and its ``config.yaml`` is what
this invocation would train: the same resolved configuration (steps, crop,
batch, seed and every key of the ``--config`` file) on the same data. A run
of that configuration that did not finish (killed; ``best.pt`` exists after
its first validation, but that is not a finished run) is trained again with
``lenspair train --resume``, which continues from its ``last.pt`` or starts
it over without one, and one log line says so. A run folder that holds a run
of another configuration (``--pretrain-steps 1`` then ``500`` into the same
``--out``) is refused before anything trains, naming the keys that differ:
its training is not thrown away, so choose another ``--out`` or move the
folder aside. Fine-tuned runs whose pretraining has still to finish are
refused alike, since they started from its unfinished weights.
"""

import argparse
import dataclasses
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import torch

from lenspair.cli import main as cli_main
from lenspair.commands import train as train_command
from lenspair.commands.argtypes import positive_int, random_seed
from lenspair.demo import Budget, plan
from lenspair.demo_stages import run_stages
from lenspair.model.checkpoint import load_checkpoint, load_model
from lenspair.model.evaluation.published import INITIALISATION, published_markdown
from lenspair.model.evaluation.scoring import score_pairs
from lenspair.model.evaluation.seed_statistics import (
    SeedSummary,
    clearly_better,
    summarise_seeds,
)
from lenspair.model.evaluation.summary import summarize
from lenspair.model.training.config import RunConfig
from lenspair.model.training.config_loading import config_differences, load_run_config
from lenspair.model.training.loop import resolve_config
from lenspair.model.training.pairs import open_eval_pairs
from lenspair.model.training.pretrained import write_natural_images
from lenspair.model.training.run_files import read_metrics_rows
from lenspair.model.training.run_state import RunState, stop_reason

INITS = ("random", "sharp", "ours")
NEW, FINISHED, UNFINISHED = "new", "finished", "unfinished"
"""What :func:`run_status` finds in a run folder."""
Job = tuple[list[str], Path, str]
"""``(lenspair train argv, run folder, status)`` of one training run."""


def _dataset(out: Path, frames: int, splits: str | None = None) -> Path:
    """The demo's simulated dataset, built (or reused) under ``out/demo``.

    ``splits``: train,val,test fractions for ``dataset-build`` (None: the demo's).
    """
    demo = out / "demo"
    stages = plan(demo, Budget(frames=frames))
    stages = stages[: [s.name for s in stages].index("dataset-build") + 1]
    if splits is not None:
        argv = list(stages[-1].argv)
        argv[argv.index("--splits") + 1] = splits
        stages[-1] = dataclasses.replace(stages[-1], argv=tuple(argv))
    demo.mkdir(parents=True, exist_ok=True)
    segment = max(2, frames // 12)
    (demo / "dataset_config.yaml").write_text(
        f"split:\n  group_by: segment\n  segment_frames: {segment}\n  segment_gap_frames: 1\n"
    )
    run_stages(demo, stages, cli_main)
    return demo / "dataset"


def _without_init(argv: list[str]) -> list[str]:
    """``argv`` without its ``--init CKPT`` (a resumed run keeps its own start)."""
    if "--init" not in argv:
        return list(argv)
    index = argv.index("--init")
    return argv[:index] + argv[index + 2 :]


def wanted_config(argv: list[str], run: Path, channels: int) -> RunConfig:
    """The configuration ``lenspair train ARGV`` would train, as its ``config.yaml`` records it.

    Read with ``train``'s own parser and overrides, so that every option
    table2 passes counts (``--init`` is left out: it names weights, not settings).
    """
    parser = argparse.ArgumentParser(add_help=False)
    train_command.add_arguments(parser)
    args = parser.parse_args([*_without_init(argv), "--out", str(run)])
    config = train_command.with_options(load_run_config(args.config, given=True), args)
    return resolve_config(config, channels)


def _refuse(run: Path, why: str) -> SystemExit:
    return SystemExit(
        f"table2: {run} {why}; its training is kept: choose another --out, or move {run} "
        "aside to train it again"
    )


def _same_data(stored: Path, data: Path, out: Path) -> bool:
    """Whether a run that trained on ``stored`` trained on ``data``.

    Data that table2 makes inside ``out`` (the demo's dataset, the natural
    images) is compared by its place in ``out``, so that an ``--out`` folder
    moved elsewhere keeps its runs; a ``--dataset`` elsewhere by its path.
    """
    data, out = data.resolve(), out.resolve()
    if not data.is_relative_to(out):
        return stored == data
    inside = data.relative_to(out).parts
    return stored.parts[-len(inside) :] == inside


def run_status(run: Path, wanted: RunConfig, data: Path) -> str:
    """:data:`NEW`, :data:`FINISHED` or :data:`UNFINISHED` (see the module docstring).

    Raises:
        SystemExit: ``run`` holds a run of another configuration or other data.

    """
    files = [run / "config.yaml", *(run / "checkpoints" / n for n in ("last.pt", "best.pt"))]
    if not any(path.is_file() for path in [*files, run / "metrics.csv"]):
        return NEW
    if not files[0].is_file():
        raise _refuse(run, "holds a run without its config.yaml, so what it trained is unknown")
    stored = load_run_config(files[0], stored=True)
    differences = config_differences(stored, wanted)
    stored_data = stored.runtime.data_path if stored.runtime is not None else ""
    if stored_data and not _same_data(Path(stored_data), data, run.parent):
        differences.append(f"data: {stored_data} -> {data.resolve()}")
    if differences:
        raise _refuse(
            run,
            "was trained with another configuration than this invocation's "
            f"({'; '.join(differences)})",
        )
    if not files[1].is_file():
        return UNFINISHED
    state = RunState.from_checkpoint(load_checkpoint(files[1]))
    return FINISHED if stop_reason(stored, state, state.seconds) is not None else UNFINISHED


def _train(argv: list[str], run: Path, device: str, status: str = NEW) -> float:
    """Run ``lenspair train`` unless ``run`` already finished; returns seconds spent.

    Each run is its own process (``python -m lenspair train``), so runs can go
    side by side (``--jobs``) without sharing torch's global seed or threads.
    An :data:`UNFINISHED` run is resumed (``--resume``), said in one line.
    """
    if status == FINISHED:
        return 0.0
    if status == UNFINISHED:
        print(f"table2: {run} did not finish; training it again (--resume)", flush=True)
        argv = [*_without_init(argv), "--resume"]
    start = time.monotonic()
    command = [sys.executable, "-m", "lenspair", "train", *argv, "--out", str(run)]
    code = subprocess.run([*command, "--device", device], check=False).returncode
    if code != 0:
        raise SystemExit(f"table2: training {run} failed (exit {code})")
    return time.monotonic() - start


def _parallel(jobs: int, work: dict[str, Job], device: str) -> dict[str, float]:
    """Train every ``name: (argv, run, status)`` of ``work``, ``jobs`` at a time; seconds each."""
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {
            name: pool.submit(_train, argv, run, device, status)
            for name, (argv, run, status) in work.items()
        }
        return {name: future.result() for name, future in futures.items()}


def _statuses(work: dict[str, tuple[list[str], Path, Path]], channels: int) -> dict[str, Job]:
    """Each ``name: (argv, run, data)`` with its :func:`run_status` (refusals before any work)."""
    return {
        name: (argv, run, run_status(run, wanted_config(argv, run, channels), data))
        for name, (argv, run, data) in work.items()
    }


def _check_starts(pretrain: dict[str, Job], finetune: dict[str, Job]) -> None:
    """Refuse fine-tuned runs that started from a pretraining that has not finished."""
    for name, (_, run, status) in pretrain.items():
        if status == FINISHED:
            continue
        preset = name.removeprefix("pretrain-")
        for _, started, held in finetune.values():
            if started.name.startswith(f"finetune-{preset}-") and held != NEW:
                raise _refuse(started, f"was fine-tuned from {run}, which has not finished")


@torch.inference_mode()
def _score(checkpoint: Path, dataset: Path, device: str) -> tuple[float, float, float, float]:
    """Output PSNR/SSIM and input PSNR/SSIM on the test split."""
    loaded = load_model(checkpoint, torch.device(device))
    channels = loaded.config.model.channels or 1
    pairs = open_eval_pairs(dataset, "test")
    scores = score_pairs(
        loaded.network, pairs, channels, torch.device(device), max_samples=0
    ).scores
    out, inp = summarize(scores), summarize(scores, "input")
    return out.psnr_db, out.ssim, inp.psnr_db, inp.ssim


def _training_seconds(run: Path) -> float:
    """Training time of a finished run: its last ``metrics.csv`` row (0 without one)."""
    rows = read_metrics_rows(run / "metrics.csv")
    return float(rows[-1]["seconds"]) if rows else 0.0


def _device_name(device: str) -> str:
    return torch.cuda.get_device_name(0) if device == "cuda" else "CPU"


def _claims(psnr: dict[str, SeedSummary]) -> list[str]:
    lines = []
    for first in INITS:
        for second in INITS:
            if first != second and clearly_better(psnr[first], psnr[second]):
                gap = psnr[first].mean - psnr[second].mean
                lines.append(f"- {first} beats {second} by {gap:.2f} dB (beyond the spread)")
    return lines or ["- no difference larger than the seed spread: nothing is claimed"]


def main(argv: list[str] | None = None) -> int:
    """Build, pretrain, fine-tune, score, tabulate; returns the exit code."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.table2", description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("table2_out"))
    parser.add_argument("--dataset", type=Path, help="paired dataset (default: the demo's)")
    parser.add_argument("--frames", type=positive_int, default=60, help="frames per demo recording")
    parser.add_argument(
        "--splits", help="train,val,test fractions of the demo dataset (default: the demo's)"
    )
    parser.add_argument("--pretrain-steps", type=positive_int, default=60)
    parser.add_argument("--finetune-steps", type=positive_int, default=60)
    parser.add_argument("--seeds", type=random_seed, nargs="+", default=[0, 1, 2])
    parser.add_argument("--crop-size", type=positive_int, default=128)
    parser.add_argument("--batch-size", type=positive_int, default=4)
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument(
        "--jobs", type=positive_int, default=1, help="training runs side by side (1)"
    )
    parser.add_argument(
        "--config", type=Path, help="run config for every `train` (default: early stopping off)"
    )
    parser.add_argument(
        "--data-only",
        action="store_true",
        help="build (or reuse) the demo dataset under OUT/demo, print its path and stop "
        "(`make tradeoff-seeds` trains its variants on it)",
    )
    args = parser.parse_args(argv)
    if len(set(args.seeds)) != len(args.seeds):
        # a repeated seed trained once and was scored twice: a spread of 0 claimed everything
        parser.error(f"--seeds: each seed once, got {' '.join(map(str, args.seeds))}")
    if args.data_only:
        print(_dataset(args.out.resolve(), args.frames, args.splits))
        return 0
    command = "python -m benchmarks.table2 " + " ".join(sys.argv[1:] if argv is None else argv)
    torch.set_num_threads(2)
    out = args.out.resolve()
    started = time.monotonic()
    dataset = args.dataset or _dataset(out, args.frames, args.splits)
    pairs = open_eval_pairs(dataset, "test")
    channels = 1 if pairs[0].input.ndim == 2 else 3
    natural = out / "natural"
    if not (natural / "train").is_dir():
        write_natural_images(natural, channels)
    # --epochs far above the step budget: --max-steps, not the epoch count, ends every run
    common = ["--crop-size", str(args.crop_size), "--batch-size", str(args.batch_size)]
    common += ["--epochs", "1000000"]
    config = args.config.resolve() if args.config else out / "table2_train.yaml"
    if not args.config:  # equal budgets: early stopping off (a --config must say so itself)
        config.write_text("train:\n  patience: 0\n")
    common += ["--config", str(config)]
    pretraining = {}
    for preset in ("ours", "sharp"):
        argv = ["--synthetic", str(natural / "train"), "--drops", preset, "--seed", "0"]
        argv += ["--max-steps", str(args.pretrain_steps), *common]
        pretraining[f"pretrain-{preset}"] = (argv, out / f"pretrain-{preset}", natural / "train")
    finetuning = {}
    for seed in args.seeds:
        for init in INITS:
            pretrained = out / f"pretrain-{init}" / "checkpoints" / "best.pt"
            start = [] if init == "random" else ["--init", str(pretrained)]
            budget = ["--seed", str(seed), "--max-steps", str(args.finetune_steps)]
            name = f"finetune-{init}-seed{seed}"
            finetuning[name] = ([str(dataset), *start, *budget, *common], out / name, dataset)
    # every run folder checked before anything trains: a refusal costs no training
    pretrain = _statuses(pretraining, channels)
    finetune = _statuses(finetuning, channels)
    _check_starts(pretrain, finetune)
    seconds = _parallel(args.jobs, pretrain, args.device)
    seconds |= _parallel(args.jobs, finetune, args.device)
    psnr: dict[str, list[float]] = {name: [] for name in INITS}
    ssim: dict[str, list[float]] = {name: [] for name in INITS}
    inputs: tuple[float, float] = (float("nan"), float("nan"))
    for seed in args.seeds:
        for init in INITS:
            run = out / f"finetune-{init}-seed{seed}"
            best = run / "checkpoints" / "best.pt"
            out_psnr, out_ssim, in_psnr, in_ssim = _score(best, dataset, args.device)
            psnr[init].append(out_psnr)
            ssim[init].append(out_ssim)
            inputs = (in_psnr, in_ssim)
    psnr_summary = {name: summarise_seeds(values) for name, values in psnr.items()}
    ssim_summary = {name: summarise_seeds(values) for name, values in ssim.items()}
    total = time.monotonic() - started
    # the runs' own training time (metrics.csv), also when a rerun reused them
    runs = [out / name for name in (*pretrain, *finetune)]
    trained = sum(_training_seconds(run) for run in runs)
    lines = [
        "| initialisation | PSNR (dB), mean +/- spread | SSIM, mean +/- spread | seeds |",
        "|---|---|---|---|",
        f"| raw input | {inputs[0]:.2f} | {inputs[1]:.4f} | - |",
    ]
    for name in INITS:
        lines.append(
            f"| {name} | {psnr_summary[name].format(2)} | {ssim_summary[name].format(4)} | "
            f"{psnr_summary[name].seeds} |"
        )
    text = "\n".join(
        [
            f"Table 2 on simulated recording pairs ({dataset}, test split, skimage-gaussian): "
            f"pretraining {args.pretrain_steps} steps on bundled natural photographs, then "
            f"fine-tuning {args.finetune_steps} steps per seed; crop {args.crop_size}, batch "
            f"{args.batch_size}, {_device_name(args.device)}, {args.jobs} run(s) side by side; "
            f"training {trained / 60:.1f} min over the {len(runs)} runs; this invocation "
            f"{total / 60:.1f} min wall clock.",
            "",
            f"Command: `{command}`",
            "",
            *lines,
            "",
            *_claims(psnr_summary),
            "",
            published_markdown((INITIALISATION,)),
        ]
    )
    print(text)
    (out / "table2.md").write_text(text + "\n")
    payload = {
        "psnr": {k: list(v.values) for k, v in psnr_summary.items()},
        "ssim": {k: list(v.values) for k, v in ssim_summary.items()},
        "input": inputs,
        "args": {k: str(v) for k, v in vars(args).items()},
        "seconds": seconds,
        "total_seconds": total,
        "training_seconds": trained,
    }
    (out / "table2.json").write_text(json.dumps(payload, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
