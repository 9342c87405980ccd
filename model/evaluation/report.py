"""Write an evaluation's reports: per-image CSV, JSON means, Markdown tables, contact sheet.

The scores come from :mod:`lenspair.model.evaluation.evaluate`
(:class:`~lenspair.model.evaluation.evaluate.EvalResult`);
this module only formats and writes them, with the same metric conventions and
PSNR cap (:data:`~lenspair.model.metrics.PSNR_CAP_DB`) named in every table.

Reports written by :func:`write_report` into ``EVAL_DIR``::

    per_image.csv      name, difficulty, height, width, psnr_db, ssim
    metrics.json       means overall and per difficulty, convention, latency,
                       the pairs that could not be read and why
    metrics.md         the same as Markdown tables
    contact_sheet.png  input | output | target for a few images (easy/medium/hard rows)

Non-finite floats (an infinite PSNR, a NaN mean) are written as the strings
``"inf"``/``"nan"`` so that ``metrics.json`` stays strict JSON.
"""

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from lenspair.core.contact_sheet import make_contact_sheet
from lenspair.core.fsutil import atomic_write_texts, json_safe
from lenspair.core.imagewrite import write_image
from lenspair.model.evaluation.evaluate import EvalResult
from lenspair.model.evaluation.summary import fmt_psnr
from lenspair.model.metrics import PSNR_CAP_DB

UNREAD_LISTED = 20
"""Unreadable pairs named in ``metrics.md``; ``metrics.json`` lists them all."""


def convention_note(convention: str) -> str:
    """One sentence naming a metric convention, for tables."""
    if convention == "deraindrop-y":
        return "deraindrop-y (uint8, Y channel, 7x7 uniform SSIM window: DeRaindrop's protocol)"
    return (
        "skimage-gaussian (scikit-image PSNR; SSIM with Gaussian weights, sigma 1.5, "
        "no sample covariance)"
    )


def markdown_report(result: EvalResult) -> str:
    """The report as Markdown: means, per-difficulty means, latency, conventions."""
    lines = [
        f"# Evaluation of `{result.checkpoint}`",
        "",
        f"- data: `{result.data}`",
        f"- metric convention: {convention_note(result.convention)}",
        f"- inference precision: {result.precision}"
        + (f" ({result.precision_reason})" if result.precision_reason else ""),
        *(
            [
                f"- agreement with the fp32 output ({result.precision} against fp32, "
                f"{_agreement_pairs(result.versus_fp32.pairs, result.overall.pairs)}): PSNR "
                f"{fmt_psnr(result.versus_fp32.psnr_db)} dB, SSIM {result.versus_fp32.ssim:.4f}"
            ]
            if result.versus_fp32 is not None
            else []
        ),
        *([f"- int8 calibrated on: {result.calibration}"] if result.calibration else []),
        *(
            [
                f"- **the checkpoint trained on {result.trained_on_scored} of the "
                f"{result.overall.pairs} scored pairs**, which flatter its scores: score pairs "
                "it did not train on (a test split) for its accuracy"
            ]
            if result.trained_on_scored
            else []
        ),
        *([f"- channels: {result.conversion}"] if result.conversion else []),
        "",
        "| subset | pairs | PSNR (dB) | SSIM | input PSNR (dB) | input SSIM | convention |",
        "| --- | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    subsets = {"all": result.overall, **result.by_difficulty}
    inputs = {"all": result.input_overall, **result.input_by_difficulty}
    for name, s in subsets.items():
        base = inputs.get(name)
        base_cells = "n/a | n/a" if base is None else f"{fmt_psnr(base.psnr_db)} | {base.ssim:.4f}"
        lines.append(
            f"| {name} | {s.pairs} | {fmt_psnr(s.psnr_db)} | {s.ssim:.4f} | {base_cells} | "
            f"{result.convention} |"
        )
    capped = result.overall.capped
    capped_inputs = result.input_overall.capped if result.input_overall is not None else 0
    lines += [
        "",
        f"PSNR means count identical images (PSNR = inf), and any above {PSNR_CAP_DB:g} dB, "
        f"as {PSNR_CAP_DB:g} dB; "
        f"{capped} output(s) and {capped_inputs} input(s) were capped. The input columns "
        "score the obstructed input itself against the target (no restoration): the "
        "baseline to beat.",
    ]
    if result.unread:
        lines += [
            "",
            f"## {len(result.unread)} pair(s) could not be read or scored (not in the means)",
            "",
        ]
        lines += [f"- pair {u.index}: {u.reason}" for u in result.unread[:UNREAD_LISTED]]
        if len(result.unread) > UNREAD_LISTED:
            lines.append(f"- and {len(result.unread) - UNREAD_LISTED} more (metrics.json)")
    if result.latency:
        lines += [
            "",
            "## Latency (batch 1, after warm-up)",
            "",
            "| device | precision | size | threads | median (ms) | p90 (ms) | runs |",
            "| --- | --- | --- | ---: | ---: | ---: | ---: |",
        ]
        for lat in result.latency:
            lines.append(
                f"| {lat.device} | {lat.precision} | {lat.size} | {lat.threads} | "
                f"{lat.median_ms:.2f} | {lat.p90_ms:.2f} | {lat.runs} |"
            )
    else:  # every accuracy figure comes with its time: its absence is said
        lines += ["", "## Latency", "", "Not timed (`--latency-runs 0`)."]
    return "\n".join(lines) + "\n"


def per_image_csv(result: EvalResult) -> str:
    """Per-image scores as CSV text (a ``convention`` column on every row)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(
        [
            "name", "difficulty", "height", "width", "psnr_db", "ssim",
            "input_psnr_db", "input_ssim", "convention",
        ]
    )  # fmt: skip
    for s in result.scores:
        writer.writerow(
            [
                s.name,
                s.difficulty or "",
                s.height,
                s.width,
                "inf" if math.isinf(s.psnr_db) else f"{s.psnr_db:.6f}",
                f"{s.ssim:.8f}",
                "inf" if math.isinf(s.input_psnr_db) else f"{s.input_psnr_db:.6f}",
                f"{s.input_ssim:.8f}",
                result.convention,
            ]
        )
    return buffer.getvalue()


def write_report(result: EvalResult, out_dir: Path) -> dict[str, Path]:
    """Write ``per_image.csv``, ``metrics.json``, ``metrics.md``, ``contact_sheet.png``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {
        "csv": out_dir / "per_image.csv",
        "json": out_dir / "metrics.json",
        "markdown": out_dir / "metrics.md",
        "contact_sheet": out_dir / "contact_sheet.png",
    }
    # an earlier run's sheet must not pass for this run's (killed before it is drawn, or
    # none drawn); the tables are written together, so a kill leaves no mix of two runs
    files["contact_sheet"].unlink(missing_ok=True)
    atomic_write_texts(
        {
            files["csv"]: per_image_csv(result),
            files["json"]: json.dumps(json_safe(result.as_dict()), indent=2) + "\n",
            files["markdown"]: markdown_report(result),
        }
    )
    if result.samples:
        rows: list[list[np.ndarray | None]] = [list(row.images) for row in result.samples]
        labels = [list(row.labels) for row in result.samples]
        title = f"{_tail(result.checkpoint)} on {_tail(result.data)}, PSNR {result.convention}"
        sheet = make_contact_sheet(rows, labels, title=title)
        write_image(files["contact_sheet"], sheet)
    else:
        del files["contact_sheet"]
    return files


def _tail(path: str, parts: int = 3) -> str:
    """The last ``parts`` components of a path, for titles that must fit an image."""
    return "/".join(Path(path).parts[-parts:])


def _agreement_pairs(agreed: int, scored: int) -> str:
    """Which pairs the agreement with fp32 covers: all, or how many of the scored ones."""
    if agreed == scored:
        return "all pairs"
    return f"{agreed} of the {scored} scored pairs: fp32 ran out of memory on the others"
