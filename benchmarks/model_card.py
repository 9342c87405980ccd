"""Write ``model/weights/MODEL_CARD.md`` from ``card.json`` (written by pretrain_weights).

    python -m benchmarks.model_card [--weights model/weights]

Every figure in the card comes from ``card.json``; nothing is typed by hand.
"""

import argparse
import json
from pathlib import Path
from typing import Any

from lenspair.model.checkpoint import WEIGHTS_DIR

ROWS: list[tuple[str, str, str]] = [
    ("file", "file", "{}"),
    ("bytes", "size (bytes)", "{:,}"),
    ("budget_steps", "step budget (a cap; batch 8, 128 px crops)", "{}"),
    ("epochs", "epochs (the paper trains 200)", "{}"),
    ("steps", "optimiser steps taken", "{}"),
    ("stop_reason", "stopped because", "{}"),
    ("training_seconds", "training seconds", "{:.0f}"),
    ("training_load_average", "load average at the end of training", "{:.2f}"),
    ("precision", "training precision", "{}"),
    ("seed", "seed", "{}"),
    ("best_epoch", "epoch of the shipped checkpoint", "{}"),
    ("pairs", "held-out validation pairs", "{}"),
    ("input_psnr", "held-out input PSNR (dB)", "{:.2f}"),
    ("output_psnr", "held-out output PSNR (dB)", "{:.2f}"),
    ("input_ssim", "held-out input SSIM", "{:.4f}"),
    ("output_ssim", "held-out output SSIM", "{:.4f}"),
    ("clear_frames", "held-out frames through clear glass", "{}"),
    ("clear_psnr", "clear glass: output against input, least PSNR (dB)", "{:.2f}"),
    ("clear_change_codes", "clear glass: largest mean change (8-bit codes)", "{:.1f}"),
    ("cpu_ms_median", "CPU ms per 720x480 frame (median, 2 threads, fp32, as deployed)", "{:.0f}"),
    ("cpu_ms_p90", "CPU ms per 720x480 frame (90th percentile)", "{:.0f}"),
    ("load_average", "load average when timed", "{:.2f}"),
]
"""Card rows: ``card.json`` key, label, format."""

DEMO_ROWS: list[tuple[str, str, str]] = [
    ("pairs", "test pairs", "{}"),
    ("input_psnr", "input PSNR (dB)", "{:.2f}"),
    ("output_psnr", "output PSNR (dB)", "{:.2f}"),
    ("input_ssim", "input SSIM", "{:.4f}"),
    ("output_ssim", "output SSIM", "{:.4f}"),
    ("cpu_ms_median", "CPU ms per frame (median, 2 threads, fp32, as deployed)", "{:.0f}"),
]
"""Rows of the demo-test table (``card.json``'s ``demo_test``), as in :data:`ROWS`."""

NAMES = (("mono", "mono"), ("rgb", "RGB"))


def _table(entries: list[dict[str, Any]], rows: list[tuple[str, str, str]]) -> list[str]:
    lines = []
    for key, label, fmt in rows:
        cells = ["n/a" if e.get(key) is None else fmt.format(e[key]) for e in entries]
        lines.append(f"| {label} | {' | '.join(cells)} |")
    return lines


def _machine(present: list[tuple[str, str]], entries: list[dict[str, Any]]) -> str:
    """The training machine: its cores and the load average each run ended with."""
    cores = {e.get("cpu_count") for e in entries}
    size = f"a {cores.pop()}-core CPU" if len(cores) == 1 and None not in cores else "a CPU"
    loads = ", ".join(
        f"{label} {e['training_load_average']:.1f}"
        for (_, label), e in zip(present, entries, strict=True)
        if e.get("training_load_average") is not None
    )
    return f"{size} (load average at the end of training: {loads})" if loads else size


def _rebuild(present: list[tuple[str, str]], entries: list[dict[str, Any]]) -> str:
    """The pretraining command(s) that made these weights (one per budget)."""
    by_budget: dict[int, list[str]] = {}
    for (name, _), entry in zip(present, entries, strict=True):
        by_budget.setdefault(entry["budget_steps"], []).append("1" if name == "mono" else "3")
    return " and ".join(
        f"`python -m benchmarks.pretrain_weights --channels {' '.join(channels)} --steps {steps}`"
        for steps, channels in sorted(by_budget.items(), reverse=True)
    )


def card_markdown(card: dict[str, Any]) -> str:
    """The model card as Markdown (every figure from ``card``, the contents of card.json)."""
    present = [(name, label) for name, label in NAMES if card.get(name)]
    entries = [card[name] for name, _ in present]
    precisions = sorted({e["precision"] for e in entries})
    reasons = sorted({e["precision_reason"] for e in entries})
    lines = [
        "# Pretrained GEA weights shipped with lenspair",
        "",
        "`lenspair train DS --init pretrained` starts from these (mono or RGB, chosen by the "
        "data). They are ordinary lenspair checkpoints holding the GEA network's weights as "
        "float16 (no optimiser state), loaded with `weights_only=True`.",
        "",
        "- **Network**: GEA (generator + enhancer + aggregation), width 1, 9 residual blocks, "
        "the paper's architecture.",
        "- **Data**: `ours` synthetic drops (lenspair.model.training.synthetic.OUR_DROPS: "
        "power-law drop sizes, thin-lens glass defocus of an Alphasense-like camera, brightened "
        "drops, a veil) rendered on the fly over the natural photographs that scikit-image and "
        "matplotlib ship (lenspair.simulate.natural_images), at 720x480, as whole frames and "
        "1.5x zoomed views, and over four textureless scenes with sensor noise (a wall, a sky, "
        "a night, fog: lenspair.model.training.pretrained.PLAIN_SCENES); a share of the items "
        "is seen through clear glass, input = target (DataConfig.clear_share), so that the "
        "network learns to leave frames without an anomaly alone. `coffee`, `clock` and "
        "`plain_fog` are held out for validation (2 fixed drop draws each; the card also "
        "scores each through clear glass).",
        "- **Training**: the paper's losses and optimiser (Adam lr 2e-4, betas 0.5/0.999), "
        "LSGAN + feature matching + L2; no perceptual term (no VGG19 weights are shipped); "
        f"{' / '.join(precisions)} ({'; '.join(reasons)}) on {_machine(present, entries)}; "
        "the checkpoint with the best validation PSNR is shipped.",
        f"- **Rebuild**: {_rebuild(present, entries)}, then `python -m benchmarks.pretrain_weights "
        "--rescore --dataset DS` on a demo dataset (the demo-test table), then "
        "`python -m benchmarks.model_card`.",
        "",
        f"| figure | {' | '.join(label for _, label in present)} |",
        "|---|" + "---|" * len(present),
        *_table(entries, ROWS),
    ]
    demo = [
        (label, card[name]["demo_test"]) for name, label in present if "demo_test" in card[name]
    ]
    if demo:
        label, scores = demo[0]
        lines += [
            "",
            f"**As shipped, on the demo's test split** ({label} weights, no fine-tuning; "
            f"`lenspair demo`'s dataset, {scores['size']}, skimage-gaussian): what the starting "
            "point does to simulated recordings whose drops, dust and glass differ from `ours`.",
            "",
            f"| figure | {label} |",
            "|---|---|",
            *_table([scores], DEMO_ROWS),
        ]
    gains = [
        f"{label}: {e['steps']} steps, {e['output_psnr'] - e['input_psnr']:+.2f} dB"
        for (_, label), e in zip(present, entries, strict=True)
    ]
    lines += [
        "",
        "Metrics: skimage-gaussian convention (scikit-image PSNR, Gaussian SSIM), [0, 1] "
        "images. Learning curves (validation PSNR per validation) are in `card.json`. The "
        "budget is in epochs and steps, so the same command trains as long on any machine; "
        "training seconds depend on the machine and grow with whatever else ran (the precision "
        "auto picks does too). CPU times were taken when the card was "
        "last scored, with the load average beside them: compare them only with figures taken "
        "in the same run.",
        "",
        f"**Limits.** The paper's 200 epochs over 30 training views are a few hundred steps "
        f"({'; '.join(gains)} on the held-out pairs): a starting point, not a converged network, "
        "and a held-out set of 3 images under 2 drop draws is too small to rank them. A veil "
        "comes with every `ours` drop, and a network this shallow cannot tell a veiled frame "
        "from a clear one of low contrast, so it takes a share of a veil off clear frames too "
        "(the clear-glass rows: they darken by a few codes). Fine-tuning on your own pairs, "
        "which show your glass clear and wet, teaches the network which is which, and "
        "`lenspair restore --only-obstructed` copies the frames a detector calls clean; `make "
        "pretrained` with larger `--epochs` and `--steps` (on a GPU) trains longer.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write the card; returns the exit code."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.model_card", description=__doc__)
    parser.add_argument("--weights", type=Path, default=WEIGHTS_DIR)
    args = parser.parse_args(argv)
    card = json.loads((args.weights / "card.json").read_text())
    (args.weights / "MODEL_CARD.md").write_text(card_markdown(card))
    print(f"wrote {args.weights / 'MODEL_CARD.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
