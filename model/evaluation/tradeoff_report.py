"""Write the accuracy-against-time comparison: Markdown, CSV and JSON table, and plot.

The rows come from :func:`lenspair.model.evaluation.tradeoff.run_tradeoff`
(:class:`~lenspair.model.evaluation.tradeoff_rows.TradeoffRow`, Pareto flags already set by
:func:`~lenspair.model.evaluation.tradeoff_rows.mark_pareto`); this module only
formats and writes them, with the measurement conditions (``meta``) named in the
table and the plot.

Files written by :func:`write_tradeoff` into ``OUT``::

    tradeoff.md    the table as Markdown, with its conditions and the input baseline
                   (and a warning when the networks trained on the scored pairs)
    tradeoff.csv   one row per checkpoint and precision (columns: COLUMNS)
    tradeoff.json  the conditions (and that warning) and the rows
    tradeoff.png   PSNR and SSIM against CPU time, Pareto fronts marked

An infinite PSNR is written as ``inf`` (the string ``"inf"`` in
``tradeoff.json``). An unknown time is empty in the CSV, ``null`` in the JSON,
``n/a`` in the Markdown, and its row is left out of the plot.
"""

import csv
import io
import json
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from lenspair.core.fsutil import atomic_write, atomic_write_text, json_safe
from lenspair.core.wording import counted
from lenspair.model.evaluation.plot_labels import ABOVE, BELOW, label_points
from lenspair.model.evaluation.tradeoff_rows import TradeoffRow
from lenspair.model.metrics import PSNR_CAP_DB


def _fmt(value: float | None, digits: int) -> str:
    if value is None:
        return ""
    if math.isinf(value):
        return "inf"
    return f"{value:.{digits}f}"


COLUMNS = (
    "name", "variant", "width", "num_blocks", "precision", "params", "gflops", "cpu_ms",
    "gpu_ms", "psnr_db", "ssim", "convention", "steps", "pareto_psnr", "pareto_ssim",
    "psnr_vs_fp32_db", "scored_step",
)  # fmt: skip


def trained_on_line(meta: dict[str, Any]) -> str | None:
    """The warning under a table whose scored pairs were trained on; None when they were not."""
    trained = meta.get("trained_on_scored_pairs")
    if not trained:
        return None
    line = (
        f"Warning: the networks trained on {trained} of the {meta['scored_pairs']} scored "
        "pairs, which flatter their scores"
    )
    if meta.get("int8_calibrated_on_scored"):
        line += "; the int8 row was calibrated on the training pairs, so on the scored ones too"
    return line + (
        "; score pairs they did not train on (leave --split out: the test split, or the "
        "held-out validation pairs)."
    )


def tradeoff_markdown(rows: Sequence[TradeoffRow], meta: dict[str, Any]) -> str:
    """The table as Markdown, with its measurement conditions."""
    lines = [
        "# Accuracy against inference time",
        "",
        f"- data: `{meta['dataset']}`, scored on {meta['evaluated_on']}"
        + (f" ({counted(meta['pairs_scored'], 'pair')})" if "pairs_scored" in meta else ""),
        f"- training budget per variant: {meta['budget']}",
        *([f"- scored: {meta['scored']}"] if "scored" in meta else []),
        f"- metric convention: {meta['convention']}",
        f"- latency: batch 1 at {meta['size']}, median after warm-up; CPU with "
        f"{meta['threads']} threads"
        + (f" of {meta['cpu']}" if meta.get("cpu") else "")
        + " (n/a at a precision the CPU only emulates); GPU column only when trained on CUDA"
        + (f", on {meta['gpu']}" if meta.get("gpu") else ""),
        "- Pareto: `*` = on the PSNR-vs-CPU-time front, `+` = on the SSIM-vs-CPU-time front "
        "(the input without restoration counts as a 0 ms choice); one training per network: "
        "a difference smaller than the spread over seeds may decide a mark (`--seeds 0,1,2` "
        "marks only differences beyond it)",
        "",
        "| name | precision | params | GFLOPs | CPU ms | GPU ms | PSNR (dB) | SSIM | "
        "convention | Pareto |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |",
    ]
    for r in rows:
        mark = ("*" if r.pareto_psnr else "") + ("+" if r.pareto_ssim else "")
        lines.append(
            f"| {r.name} | {r.precision_label()} | {r.params:,} | {r.gflops:.3f} | "
            f"{_fmt(r.cpu_ms, 2) or 'n/a'} | {_fmt(r.gpu_ms, 2) or 'n/a'} | "
            f"{_fmt(r.psnr_db, 2)} | {_fmt(r.ssim, 4)} | {r.convention} | {mark} |"
        )
    baseline = meta.get("input_baseline")
    if baseline:
        lines += [
            "",
            f"Input without restoration (the baseline to beat): PSNR "
            f"{_fmt(baseline['psnr_db'], 2)} dB, SSIM {_fmt(baseline['ssim'], 4)}.",
        ]
    if warning := trained_on_line(meta):
        lines += ["", warning]
    return "\n".join(lines) + "\n"


TABLE_FILES = ("tradeoff.md", "tradeoff.csv", "tradeoff.json", "tradeoff.png")
"""The table and plot :func:`write_tradeoff` writes in ``OUT``."""


def write_tradeoff(rows: Sequence[TradeoffRow], out_dir: Path, meta: dict[str, Any]) -> None:
    """Write ``tradeoff.md``, ``tradeoff.csv``, ``tradeoff.json`` and ``tradeoff.png``."""
    out_dir = Path(out_dir)
    atomic_write_text(out_dir / "tradeoff.md", tradeoff_markdown(rows, meta))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if v is None else v) for k, v in asdict(r).items()})
    atomic_write_text(out_dir / "tradeoff.csv", buffer.getvalue())
    warning = trained_on_line(meta)
    payload = {
        **meta,
        **({"warning": warning} if warning else {}),
        "rows": [asdict(r) for r in rows],
    }
    # non-finite floats become strings; text (paths, names) is written as it is
    text = json.dumps(json_safe(payload), indent=2, default=str, allow_nan=False)
    atomic_write_text(out_dir / "tradeoff.json", text + "\n")
    plot_tradeoff(rows, out_dir / "tradeoff.png", meta)


MARKERS = {"fp32": "o", "bf16": "s", "fp16": "D", "int8": "^"}
"""The plot's marker for each precision (matplotlib marker codes)."""
MARKER_NAMES = {"o": "circle", "s": "square", "D": "diamond", "^": "triangle"}


def _drawn(value: float) -> float:
    """Where the plot draws a score: an infinite PSNR (identical images) at the means' cap."""
    return min(value, PSNR_CAP_DB)


def plot_tradeoff(rows: Sequence[TradeoffRow], path: Path, meta: dict[str, Any]) -> None:
    """PSNR and SSIM against CPU time, one panel each, Pareto fronts drawn and ringed.

    Every point is named; the names are placed where they print over neither
    each other, the points nor the legend (:mod:`lenspair.model.evaluation.plot_labels`).
    """
    figure = Figure(figsize=(11, 4.5), dpi=110)
    canvas = FigureCanvasAgg(figure)
    panels = ((figure.add_subplot(1, 2, 1), "psnr_db", "PSNR (dB)", "pareto_psnr"),
              (figure.add_subplot(1, 2, 2), "ssim", "SSIM", "pareto_ssim"))  # fmt: skip
    timed = [(r.cpu_ms, r) for r in rows if r.cpu_ms is not None]
    labels = [f"{r.name} {r.precision}" for _, r in timed]
    # fp32 labels above, reduced precision below where free: the precisions of
    # one network score alike
    first_choice = [ABOVE if r.precision == "fp32" else BELOW for _, r in timed]
    plotted: dict[str, list[tuple[float, float]]] = {}  # each panel's points, for the labels
    for axes, key, label, flag in panels:
        plotted[key] = [(x, _drawn(getattr(r, key))) for x, r in timed]
        for (x, y), (_, r) in zip(plotted[key], timed, strict=True):
            axes.scatter([x], [y], marker=MARKERS[r.precision], color="tab:blue", zorder=3)
        front = sorted(((x, r) for x, r in timed if getattr(r, flag)), key=lambda p: p[0])
        if front:
            xs = [x for x, _ in front]
            ys = [_drawn(getattr(r, key)) for _, r in front]
            axes.plot(xs, ys, color="tab:red", linewidth=1.5, zorder=2, label="Pareto front")
            axes.scatter(xs, ys, s=140, facecolors="none", edgecolors="tab:red", zorder=4)
            axes.legend(loc="best", fontsize=8)  # where it hides the fewest points
        baseline = meta.get("input_baseline")
        if baseline:
            axes.axhline(_drawn(baseline[key]), color="grey", linestyle="--", linewidth=1,
                         label="input, no restoration")  # fmt: skip
            axes.legend(loc="best", fontsize=8)  # where it hides the fewest points
        axes.set_xlabel(f"CPU time per {meta['size']} frame (ms, batch 1)")
        axes.set_ylabel(f"{label}, {meta['convention']}")
        axes.grid(True, alpha=0.3)
    shown = [p for p in MARKERS if any(r.precision == p for _, r in timed)]
    key_text = ", ".join(f"{MARKER_NAMES[MARKERS[p]]} {p}" for p in shown)
    figure.suptitle(f"Accuracy vs CPU time ({meta['budget']} per variant; {key_text})")
    figure.tight_layout()
    canvas.draw()  # the limits, layout and legend are final: labels go where they clash least
    for axes, key, _, _ in panels:
        label_points(axes, plotted[key], labels, first_choice, canvas.get_renderer())

    def _write(tmp: Path) -> None:
        figure.savefig(tmp, format="png")

    atomic_write(Path(path), _write, suffix=".png")
