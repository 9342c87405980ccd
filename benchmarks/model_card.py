"""Write ``model/weights/MODEL_CARD.md`` from ``card.json`` (written by pretrain_weights).

    python -m benchmarks.model_card [--weights model/weights]

Every figure in the card comes from ``card.json``; nothing is typed by hand.
"""

import argparse
import json
from pathlib import Path
from typing import Any

from lenspair.model.training.pretrained import WEIGHTS_DIR


def card_markdown(card: dict[str, Any]) -> str:
    """The model card as Markdown."""
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
        "1.5x zoomed views; `coffee` and `clock` are held out for validation (2 fixed drop "
        "draws each).",
        "- **Training**: the paper's losses and optimiser (Adam lr 2e-4, betas 0.5/0.999), "
        "LSGAN + feature matching + L2; no perceptual term (no VGG19 weights are shipped); "
        "bf16 autocast on a 2-core CPU shared with other jobs; the checkpoint with the best "
        "validation PSNR is shipped.",
        "- **Rebuild**: `python -m benchmarks.pretrain_weights --channels 1 3 --minutes 11` "
        "then `python -m benchmarks.model_card`.",
        "",
        "| figure | mono | RGB |",
        "|---|---|---|",
    ]
    keys = [
        ("file", "file", "{}"),
        ("bytes", "size (bytes)", "{:,}"),
        ("budget_minutes", "training budget (wall-clock minutes)", "{:g}"),
        ("training_seconds", "training seconds used", "{:.0f}"),
        ("steps", "optimiser steps (batch 8, 128 px crops)", "{}"),
        ("seed", "seed", "{}"),
        ("best_epoch", "epoch of the shipped checkpoint", "{}"),
        ("pairs", "held-out validation pairs", "{}"),
        ("input_psnr", "held-out input PSNR (dB)", "{:.2f}"),
        ("output_psnr", "held-out output PSNR (dB)", "{:.2f}"),
        ("input_ssim", "held-out input SSIM", "{:.4f}"),
        ("output_ssim", "held-out output SSIM", "{:.4f}"),
        ("cpu_ms_median", "CPU ms per 720x480 frame (median, 2 threads, loaded machine)", "{:.0f}"),
    ]
    for key, label, fmt in keys:
        cells = []
        for name in ("mono", "rgb"):
            value = card.get(name, {}).get(key)
            cells.append("n/a" if value is None else fmt.format(value))
        lines.append(f"| {label} | {cells[0]} | {cells[1]} |")
    gains = []
    for name, label in (("mono", "mono"), ("rgb", "RGB")):
        entry = card.get(name)
        if entry:
            gain = entry["output_psnr"] - entry["input_psnr"]
            gains.append(f"{label}: {entry['steps']} steps, {gain:+.2f} dB on the held-out pairs")
    lines += [
        "",
        "Metrics: skimage-gaussian convention (scikit-image PSNR, Gaussian SSIM), [0, 1] "
        "images. Learning curves (validation PSNR per validation) are in `card.json`. The CPU "
        "time was taken on a machine whose 2 cores were shared with several other jobs (load "
        "average above 10): compare it only with figures taken in the same run.",
        "",
        "**Limits.** The budget is minutes on a shared 2-core CPU, so these networks are barely "
        f"trained ({'; '.join(gains)}): they are a starting point, not a converged network, and "
        "a held-out set of 2 images under 2 drop draws is too small to rank them. Fine-tune on "
        "your own pairs; a GPU run of `make pretrained` with a longer `--minutes` gives better "
        "weights.",
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
