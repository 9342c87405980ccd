"""Rebuild the shipped pretrained GEA weights and their model card.

    python -m benchmarks.pretrain_weights --channels 1 3 --minutes 11 --runs runs/pretrained

Pretrains GEA on ``ours`` drops over the bundled natural photographs
(:mod:`lenspair.model.training.pretrained`) for a wall-clock budget per
network, copies ``best.pt`` (float16 weights, no optimiser) into
``model/weights/`` and writes ``model/weights/MODEL_CARD.md`` and
``card.json`` with the budget, seed, validation figures (held-out images,
fixed drops; input PSNR beside output PSNR) and the network's CPU time. Not
part of ``python -m benchmarks``: it trains for minutes.
"""

import argparse
import json
import math
import statistics
import time
from pathlib import Path

import torch

from lenspair.model.checkpoint import load_model
from lenspair.model.evaluation.evaluate import score_tensors
from lenspair.model.training.config import DataConfig, RunConfig, TrainConfig
from lenspair.model.training.pretrained import (
    VALIDATION_DRAWS,
    WEIGHTS_DIR,
    WEIGHTS_FILES,
    pretrain_on_natural_images,
    ship_weights,
)
from lenspair.model.training.run_files import read_metrics_rows
from lenspair.model.training.synthetic import OUR_DROPS, SyntheticDrops
from lenspair.simulate.natural_images import HELD_OUT


def _config(minutes: float, seed: int) -> RunConfig:
    return RunConfig(
        data=DataConfig(crop_size=128),
        train=TrainConfig(
            max_seconds=minutes * 60.0,
            patience=10**6,  # the budget ends the run, not noise in a tiny validation set
            val_every=4,
            seed=seed,
            tensorboard=False,
        ),
    )


@torch.inference_mode()
def score_weights(weights: Path, clean_folder: Path, channels: int) -> dict[str, float]:
    """Held-out PSNR/SSIM of input and output, and the median CPU ms per 720x480 frame."""
    loaded = load_model(weights)
    files = sorted((clean_folder / "val").glob("*.png"))
    val = SyntheticDrops(files * VALIDATION_DRAWS, OUR_DROPS, channels, None, fixed=True)
    rows = []
    times = []
    for index in range(len(val)):
        sample = val[index]
        x, target = sample["input"][None], sample["target"][None]
        start = time.perf_counter()
        output = loaded.network(x)[1].float().clamp(0, 1)
        times.append(time.perf_counter() - start)
        rows.append(
            (
                score_tensors(x, target, "skimage-gaussian"),
                score_tensors(output, target, "skimage-gaussian"),
            )
        )
    return {
        "pairs": len(rows),
        "input_psnr": statistics.mean(r[0][0] for r in rows),
        "output_psnr": statistics.mean(r[1][0] for r in rows),
        "input_ssim": statistics.mean(r[0][1] for r in rows),
        "output_ssim": statistics.mean(r[1][1] for r in rows),
        "cpu_ms_median": 1000 * statistics.median(times[1:] or times),
    }


def main(argv: list[str] | None = None) -> int:
    """Pretrain, ship and describe; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.pretrain_weights", description=__doc__
    )
    parser.add_argument("--channels", type=int, nargs="+", default=[1, 3], choices=(1, 3))
    parser.add_argument("--minutes", type=float, default=11.0, help="training budget per network")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--runs", type=Path, default=Path("runs/pretrained"))
    parser.add_argument("--weights", type=Path, default=WEIGHTS_DIR, help="where to ship")
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    card_path = args.weights / "card.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    for channels in args.channels:
        label = "mono" if channels == 1 else "rgb"
        run = args.runs / label
        start = time.monotonic()
        summary = pretrain_on_natural_images(
            run, channels, _config(args.minutes, args.seed), torch.device("cpu")
        )
        wall = time.monotonic() - start
        destination = args.weights / WEIGHTS_FILES[channels]
        size = ship_weights(run / "checkpoints" / "best.pt", destination)
        scores = score_weights(destination, run / "clean", channels)
        curve = [
            (int(r["step"]), float(r["val_psnr"])) for r in read_metrics_rows(run / "metrics.csv")
        ]
        card[label] = {
            "file": destination.name,
            "bytes": size,
            "budget_minutes": args.minutes,
            "wall_seconds": round(wall, 1),
            "training_seconds": round(summary.seconds, 1),
            "steps": summary.steps,
            "epochs": summary.epochs,
            "best_epoch": summary.best_epoch,
            "best_val_psnr": round(summary.best_psnr, 3),
            "stop_reason": summary.stop_reason,
            "perceptual": summary.perceptual,
            "seed": args.seed,
            "held_out": list(HELD_OUT),
            "learning_curve": curve,
            **{
                k: (round(v, 4) if isinstance(v, float) and math.isfinite(v) else v)
                for k, v in scores.items()
            },
        }
        print(
            json.dumps(
                {label: {k: v for k, v in card[label].items() if k != "learning_curve"}}, indent=2
            )
        )
        card_path.write_text(json.dumps(card, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
