"""The demo's results page: ``OUT/report.md`` and ``OUT/report.html``.

Everything on the page is read from files the stages wrote (calibration
report, ingest reports, dataset card, eval and tradeoff tables), and
compared with the simulator's ground truth where there is one; nothing is
typed in by hand.
"""

import json
import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lenspair import __version__
from lenspair.core.contact_sheet import make_contact_sheet
from lenspair.core.fsutil import atomic_write_text
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.core.report import Block, Code, Heading, Image, Paragraph, Table, to_html, to_markdown
from lenspair.model.training.config_loading import load_run_config
from lenspair.rectify.rig import read_kalibr

if TYPE_CHECKING:
    from lenspair.model.training.config import RuntimeInfo


def load_json(path: Path) -> Any:
    """The parsed JSON file at ``path``, or ``None`` when there is no such file."""
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


def markdown_file_blocks(path: Path) -> list[Block]:
    """Turn a Markdown file written by a lenspair stage into blocks.

    Tables become :class:`Table` blocks (so the HTML page shows real tables);
    headings and other lines become headings and paragraphs.
    """
    blocks: list[Block] = []
    table: list[list[str]] = []

    def flush() -> None:
        if table:
            header, *rows = table
            rows = [r for r in rows if not all(set(c) <= set("-: ") for c in r)]
            blocks.append(Table(header, rows))
            table.clear()

    for line in path.read_text(encoding="utf-8").splitlines():
        stripped = line.strip()
        if stripped.startswith("|"):
            table.append([c.strip() for c in stripped.strip("|").split("|")])
            continue
        flush()
        if stripped.startswith("#"):
            level = len(stripped) - len(stripped.lstrip("#"))
            blocks.append(Heading(stripped.lstrip("# "), min(level + 2, 6)))
        elif stripped:
            blocks.append(Paragraph(stripped))
    flush()
    return blocks


def _pct(estimate: float, truth: float) -> str:
    return f"{100.0 * (estimate - truth) / truth:+.3f} %"


def calibration_blocks(out: Path) -> list[Block]:
    """Calibration figures against the simulator's true camchain."""
    report = load_json(out / "calibration" / "camchain.report.json")
    if report is None:
        return [Paragraph("No calibration report found.")]
    estimate = read_kalibr(out / "calibration" / "camchain.yaml")
    truth = read_kalibr(out / "recordings" / "board" / "camchain.yaml")
    rows = []
    for name in ("cam0", "cam1"):
        est, tru = estimate.camera(name), truth.camera(name)
        for index, label in enumerate(("fx", "fy", "cx", "cy")):
            e, t = est.intrinsics[index], tru.intrinsics[index]
            error = _pct(e, t) if label in ("fx", "fy") else f"{e - t:+.3f} px"
            rows.append([f"{name} {label} (px)", f"{e:.3f}", f"{t:.3f}", error])
    rows.append(
        [
            "baseline (m)",
            f"{estimate.baseline_m:.5f}",
            f"{truth.baseline_m:.5f}",
            _pct(estimate.baseline_m, truth.baseline_m),
        ]
    )
    figures = [
        ["cam0 RMS reprojection", f"{report['cam0']['rms_px']:.3f} px"],
        ["cam1 RMS reprojection", f"{report['cam1']['rms_px']:.3f} px"],
        ["stereo RMS reprojection", f"{report['stereo']['rms_px']:.3f} px"],
        ["rectified row disagreement (RMS)", _px(report["row_disagreement_px"])],
        ["views used (stereo)", str(len(report["stereo"]["views"]))],
        ["views rejected", str(len(report["rejected"]))],
    ]
    blocks: list[Block] = [
        Paragraph(f"Board {report['board']}, model {report['model']}."),
        Table(["parameter", "estimated", "true (simulator)", "error"], rows),
        Table(["figure", "value"], figures),
    ]
    for rejected in report["rejected"]:
        blocks.append(Paragraph(f"Rejected view {rejected.get('name')}: {rejected.get('reason')}"))
    return blocks


def ingest_blocks(out: Path) -> list[Block]:
    """Counts, rejection reasons and QA sheets of each ingested recording."""
    blocks: list[Block] = []
    for folder in sorted((out / "ingested").glob("*/")):
        report = load_json(folder / "report.json")
        if report is None:
            continue
        blocks.append(Heading(f"Recording {report['recording_id']}", 3))
        blocks.append(
            Paragraph(
                f"Obstructed camera {report['obstructed']} ({', '.join(report['anomaly'])}); "
                f"calibration from {Path(report['calibration_source']).name}; "
                f"side check: {report.get('side_check', {}).get('message', 'n/a')}."
            )
        )
        counts = [[key, str(value)] for key, value in sorted(report["counts"].items())]
        blocks.append(Table(["count", "frames"], counts))
        if report.get("rejection_reasons"):
            reasons = [[r, str(n)] for r, n in sorted(report["rejection_reasons"].items())]
            blocks.append(Table(["rejection reason", "frames"], reasons))
        timings = report.get("timings_s", {})
        if timings:
            blocks.append(
                Table(["ingest step", "seconds"], [[k, f"{v:.2f}"] for k, v in timings.items()])
            )
        if (folder / "qa.png").is_file():
            blocks.append(
                Image(
                    str((folder / "qa.png").relative_to(out)),
                    "obstructed | clean registered | difference",
                )
            )
    return blocks or [Paragraph("No ingested recordings found.")]


def dataset_blocks(out: Path) -> list[Block]:
    """The dataset card's counts and the per-split contact sheets."""
    card = load_json(out / "dataset" / "dataset.json")
    if card is None:
        return [Paragraph("No dataset card found.")]
    splits = card.get("counts", {})
    rows = []
    for split in ("train", "val", "test"):
        info = splits.get(split, {})
        rows.append(
            [
                split,
                str(info.get("pairs", 0)),
                json.dumps(info.get("clean_side", {}), sort_keys=True),
                json.dumps(info.get("difficulty", {}), sort_keys=True),
                json.dumps(info.get("anomaly", {}), sort_keys=True),
            ]
        )
    blocks: list[Block] = [
        Table(["split", "pairs", "clean side", "difficulty", "anomaly"], rows),
    ]
    rules = [[r["rule"], str(r["removed"]), r["description"]] for r in card.get("curation", [])]
    if rules:
        blocks.append(Table(["curation rule", "pairs removed", "meaning"], rules))
    for split in ("train", "val", "test"):
        sheet = out / "dataset" / f"contact_{split}.png"
        if sheet.is_file():
            blocks.append(Image(str(sheet.relative_to(out)), f"{split}: input | target"))
    return blocks


def restore_blocks(out: Path, strips: int = 3) -> list[Block]:
    """Counts of the restore stage and a before/after strip of a few of its frames.

    The strip (``restore_before_after.png``) pairs frames of the raw
    recording's obstructed camera with the same frames in ``restored/``.
    """
    report = load_json(out / "restored" / "restore_report.json")
    if report is None:
        return [Paragraph("No restore report found.")]
    source = Path(report["input"])
    blocks: list[Block] = [
        Paragraph(f"`lenspair restore` on {source.name}: {report['model']}."),
        Table(
            ["frames read", "restored", "skipped", "failed", "seconds", "frames/s"],
            [
                [
                    str(report["frames_read"]),
                    str(report["restored"]),
                    str(report["skipped"]),
                    str(report["failed"]),
                    f"{report['seconds']:.1f}",
                    f"{report['frames_per_second']:.2f}",
                ]
            ],
        ),
    ]
    names = sorted(
        p.relative_to(out / "restored").as_posix()
        for camera in report["cameras"]
        for p in (out / "restored").glob(f"**/{camera}/data/*.png")
    )
    if not names:
        return blocks
    picks = [names[i] for i in np.linspace(0, len(names) - 1, min(strips, len(names))).astype(int)]
    rows = [[read_image(source / name), read_image(out / "restored" / name)] for name in picks]
    labels = [[f"before {Path(name).stem}", "after"] for name in picks]
    sheet = make_contact_sheet(rows, labels, title="restore: obstructed camera before | after")
    write_image(out / "restore_before_after.png", sheet)
    blocks.append(Image("restore_before_after.png", "before | after restore"))
    return blocks


def finetune_runtime(out: Path) -> "RuntimeInfo | None":
    """What the demo's fine-tuning ran on and at which precision (its ``config.yaml``), if any."""
    config = out / "runs" / "finetune" / "config.yaml"
    return load_run_config(config).runtime if config.is_file() else None


def machine_blocks(out: Path, timings: dict[str, dict[str, float | bool]]) -> list[Block]:
    """Where the demo ran and at which precision: read from the fine-tuning run's config."""
    # Imported here: it imports torch, which `lenspair --help` must not load.
    from lenspair.model.precision import read_cpu_flags

    total = sum(float(v["seconds"]) for v in timings.values())
    reused = [name for name, v in timings.items() if v["reused"]]
    if not reused:
        lines = [f"Total {total / 60:.1f} min on {read_cpu_flags()[0]}."]
    else:  # a rerun: the reused stages' times are the run that made them
        fresh = sum(float(v["seconds"]) for v in timings.values() if not v["reused"])
        lines = [
            f"Total {total / 60:.1f} min of stage time on {read_cpu_flags()[0]}; "
            f"{len(reused)} of {len(timings)} stages were reused from an earlier run "
            f"(their seconds are that run's), and this run spent {fresh / 60:.1f} min."
        ]
    runtime = finetune_runtime(out)
    if runtime is not None:
        lines.append(
            f"Training ran on {runtime.device} at {runtime.precision} "
            f"(natively: {', '.join(runtime.native_precisions)}): {runtime.precision_reason}."
        )
    return [Paragraph(" ".join(lines))]


def write_report(out: Path, timings: dict[str, dict[str, float | bool]], command: str = "") -> Path:
    """Write ``report.md`` and ``report.html`` under ``out``; returns the Markdown path.

    ``command`` is what made the run (``--quick`` included), for its "Reproduce" section.
    """
    command = command or f"lenspair demo --out {shlex.quote(str(out))}"
    blocks: list[Block] = [
        Heading("lenspair demo report", 1),
        Paragraph(
            f"Produced by `{command}` (lenspair {__version__}) on simulated "
            "recordings: the numbers show the pipeline working, not accuracy on real rain."
        ),
        Heading("Stages and their time"),
        Table(
            ["stage", "seconds (an earlier run's where reused)", "reused from an earlier run"],
            [
                [k, f"{v['seconds']:.1f}", "yes" if v["reused"] else "no"]
                for k, v in timings.items()
            ],
        ),
        *machine_blocks(out, timings),
        Heading("Calibration"),
        *calibration_blocks(out),
        Heading("Ingest"),
        *ingest_blocks(out),
        Heading("Dataset"),
        *dataset_blocks(out),
        Heading("Evaluation (fine-tuned GEA on the test split)"),
    ]
    metrics = out / "eval" / "metrics.md"
    blocks += markdown_file_blocks(metrics) if metrics.is_file() else [Paragraph("No metrics.")]
    if (out / "eval" / "contact_sheet.png").is_file():
        blocks.append(Image("eval/contact_sheet.png", "input | output | target"))
    blocks.append(Heading("Accuracy against time"))
    tradeoff = out / "tradeoff" / "tradeoff.md"
    blocks += markdown_file_blocks(tradeoff) if tradeoff.is_file() else [Paragraph("No tradeoff.")]
    if (out / "tradeoff" / "tradeoff.png").is_file():
        blocks.append(
            Image("tradeoff/tradeoff.png", "accuracy against CPU time, Pareto front marked")
        )
    blocks.append(Heading("Restore"))
    blocks += restore_blocks(out)
    blocks.append(Heading("Reproduce"))
    blocks.append(Code(f"{command}\n# each stage's command: .stages/*.json beside report.md"))
    markdown = out / "report.md"
    atomic_write_text(markdown, to_markdown(blocks))
    atomic_write_text(out / "report.html", to_html(blocks, "lenspair demo report"))
    return markdown


def _px(value: float | None) -> str:
    """A pixel figure; ``n/a`` where there is none (a rig not side by side is not rectified)."""
    return "n/a" if value is None else f"{value:.3f} px"
