"""Rebuild the shipped pretrained GEA weights and their model card.

    python -m benchmarks.pretrain_weights --channels 1 3 --steps 1500 --runs runs/pretrained
    python -m benchmarks.pretrain_weights --rescore --dataset demo_out/dataset

Pretrains GEA on ``ours`` drops over the bundled natural photographs and a
few textureless scenes, a share of the items through clear glass
(:mod:`lenspair.model.training.pretrained`), for ``--epochs`` (the paper's
200 by default: 27 photographic views and 3 textureless scenes make an epoch
4 steps of batch 8, so 800 steps), capped by ``--steps`` optimiser steps
(the same data on every machine; ``--minutes`` adds a wall-clock cap).
It copies ``best.pt`` (float16 weights, no optimiser) into
``model/weights/`` and writes ``card.json`` with the budget, seed, the
machine's load, validation figures (held-out images under fixed drops, input
PSNR beside output PSNR; the same images through clear glass, output against
input) and the network's CPU time as deployed
(:func:`lenspair.model.evaluation.latency.measure_latency`).
``--dataset DS`` also scores the shipped weights on DS's test split (the
demo's, for the card), and ``--rescore`` only rescores what ships.
``python -m benchmarks.model_card`` turns ``card.json`` into ``MODEL_CARD.md``.
Not part of ``python -m benchmarks``: it trains for tens of minutes.
"""

import argparse
import json
import math
import os
import statistics
import time
from pathlib import Path
from typing import Any

import torch
import yaml

from lenspair.commands.argtypes import positive_int
from lenspair.core.imageio import read_image
from lenspair.model.checkpoint import WEIGHTS_DIR, WEIGHTS_FILES, load_model
from lenspair.model.evaluation.evaluate import evaluate_checkpoint
from lenspair.model.evaluation.latency import measure_latency
from lenspair.model.evaluation.scoring import score_tensors
from lenspair.model.training.config import DataConfig, RunConfig, TrainConfig
from lenspair.model.training.pretrained import (
    FRAME,
    HELD_OUT_PLAIN,
    pretrain_on_natural_images,
    ship_weights,
    validation_drops,
    write_natural_images,
)
from lenspair.model.training.run_files import read_metrics_rows
from lenspair.simulate.natural_images import HELD_OUT

THREADS = 2
"""CPU threads for training and timing (the project's 2-core reference machine)."""
LATENCY_RUNS = 20
"""Timed runs per latency figure of the card (median and p90)."""


def _config(epochs: int, steps: int, minutes: float | None, seed: int) -> RunConfig:
    return RunConfig(
        data=DataConfig(crop_size=128),
        train=TrainConfig(
            epochs=epochs,
            max_steps=steps,
            max_seconds=None if minutes is None else minutes * 60.0,
            patience=10**6,  # the budget ends the run, not noise in a tiny validation set
            val_every=4,
            seed=seed,
            tensorboard=False,
        ),
    )


@torch.inference_mode()
def score_weights(weights: Path, clean_folder: Path, channels: int) -> dict[str, float]:
    """Held-out figures of ``weights`` and their CPU ms per 720x480 frame as deployed.

    Through drops: input and output PSNR/SSIM against the clean image. Through
    clear glass: the output against its own input (``clear_psnr``, the least
    of the held-out frames, and the largest mean change, ``clear_change_codes``,
    in 8-bit codes), which a network that leaves clear frames alone keeps high
    and small.
    """
    loaded = load_model(weights)
    val = validation_drops(sorted((clean_folder / "val").glob("*.png")), channels, clear=True)
    rows, clear = [], []
    for index in range(len(val)):
        sample = val[index]
        x, target = sample["input"][None], sample["target"][None]
        output = loaded.network(x)[1].float().clamp(0, 1)
        if val.clear(index):
            change = float((output - x).abs().mean()) * 255.0
            clear.append((score_tensors(output, x, "skimage-gaussian")[0], change))
            continue
        rows.append(
            (
                score_tensors(x, target, "skimage-gaussian"),
                score_tensors(output, target, "skimage-gaussian"),
            )
        )
    latency = measure_latency(
        loaded.network, channels, torch.device("cpu"), FRAME, runs=LATENCY_RUNS, threads=THREADS
    )
    return {
        "pairs": len(rows),
        "input_psnr": statistics.mean(r[0][0] for r in rows),
        "output_psnr": statistics.mean(r[1][0] for r in rows),
        "input_ssim": statistics.mean(r[0][1] for r in rows),
        "output_ssim": statistics.mean(r[1][1] for r in rows),
        "clear_frames": len(clear),
        "clear_psnr": min(c[0] for c in clear),
        "clear_change_codes": max(c[1] for c in clear),
        "cpu_ms_median": latency.median_ms,
        "cpu_ms_p90": latency.p90_ms,
        "load_average": os.getloadavg()[0],
    }


def score_on_dataset(weights: Path, dataset: Path) -> dict[str, Any]:
    """The shipped weights as they are on ``dataset``'s test split, with their CPU time."""
    result = evaluate_checkpoint(
        weights, dataset, "test", torch.device("cpu"), latency_runs=LATENCY_RUNS
    )
    assert result.input_overall is not None  # evaluate_checkpoint always scores the inputs
    cpu = next(lat for lat in result.latency if lat.device == "cpu")
    return {
        "dataset": str(dataset),
        "pairs": result.overall.pairs,
        "input_psnr": result.input_overall.psnr_db,
        "output_psnr": result.overall.psnr_db,
        "input_ssim": result.input_overall.ssim,
        "output_ssim": result.overall.ssim,
        "size": cpu.size,
        "cpu_ms_median": cpu.median_ms,
    }


def _rounded(values: dict[str, Any]) -> dict[str, Any]:
    return {
        k: (round(v, 4) if isinstance(v, float) and math.isfinite(v) else v)
        for k, v in values.items()
    }


def main(argv: list[str] | None = None) -> int:
    """Pretrain, ship and describe; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.pretrain_weights",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--channels", type=int, nargs="+", default=[1, 3], choices=(1, 3))
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=1500,
        help="cap on optimiser steps per network (1500); training also ends after --epochs",
    )
    parser.add_argument(
        "--epochs", type=int, default=200, help="epochs per network (200, the paper's)"
    )
    parser.add_argument(
        "--minutes", type=float, default=None, help="also stop after this wall-clock time"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--runs", type=Path, default=Path("runs/pretrained"))
    parser.add_argument("--weights", type=Path, default=WEIGHTS_DIR, help="where to ship")
    parser.add_argument(
        "--dataset", type=Path, help="also score the shipped weights on this dataset's test split"
    )
    parser.add_argument(
        "--rescore", action="store_true", help="do not train: rescore the weights that ship"
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(THREADS)
    card_path = args.weights / "card.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    for channels in args.channels:
        label = "mono" if channels == 1 else "rgb"
        run = args.runs / label
        destination = args.weights / WEIGHTS_FILES[channels]
        entry = card.setdefault(label, {})
        if args.rescore:
            write_natural_images(run / "clean", channels)
        else:
            start = time.monotonic()
            summary = pretrain_on_natural_images(
                run,
                channels,
                _config(args.epochs, args.steps, args.minutes, args.seed),
                torch.device("cpu"),
            )
            wall = time.monotonic() - start
            curve = [
                (int(r["step"]), float(r["val_psnr"]))
                for r in read_metrics_rows(run / "metrics.csv")
            ]
            entry.clear()
            entry.update(
                file=destination.name,
                bytes=ship_weights(run / "checkpoints" / "best.pt", destination),
                budget_steps=args.steps,
                budget_minutes=args.minutes,
                wall_seconds=round(wall, 1),
                training_seconds=round(summary.seconds, 1),
                training_load_average=round(os.getloadavg()[0], 2),
                steps=summary.steps,
                epochs=summary.epochs,
                best_epoch=summary.best_epoch,
                best_val_psnr=round(summary.best_psnr, 3),
                stop_reason=summary.stop_reason,
                perceptual=summary.perceptual,
                **_precision(run / "config.yaml"),
                cpu_count=os.cpu_count(),
                seed=args.seed,
                held_out=[*HELD_OUT, HELD_OUT_PLAIN],
                learning_curve=curve,
            )
        entry.update(_rounded(score_weights(destination, run / "clean", channels)))
        channels_match = args.dataset is not None and _channels(args.dataset) == channels
        if channels_match:
            entry["demo_test"] = _rounded(score_on_dataset(destination, args.dataset))
        print(json.dumps({label: {k: v for k, v in entry.items() if k != "learning_curve"}}))
        card_path.write_text(json.dumps(card, indent=2) + "\n")
    return 0


def _precision(config: Path) -> dict[str, str]:
    """The precision the run trained at, and why (its ``config.yaml``'s runtime section)."""
    runtime = yaml.safe_load(config.read_text(encoding="utf-8"))["runtime"]
    return {"precision": runtime["precision"], "precision_reason": runtime["precision_reason"]}


def _channels(dataset: Path) -> int:
    """Channels of a dataset's pairs (its first test input)."""
    first = next(iter(sorted((dataset / "test" / "input").glob("*.png"))), None)
    if first is None:
        raise SystemExit(f"{dataset}: no test/input/*.png (is it a lenspair dataset?)")
    return 1 if read_image(first).ndim == 2 else 3


if __name__ == "__main__":
    raise SystemExit(main())
