"""Write the README's "Measured results" section from files the commands wrote.

``python -m benchmarks.readme_results [--demo demo_out] [--bench bench_out]
[--readme README.md] [--check]`` (``make results`` runs the demo, the
benchmarks and then this). Every figure in the section is read from
``lenspair demo``'s outputs (tradeoff table and plot, eval metrics, stage
timings, calibration against the simulator's truth) and from the benchmarks'
JSON files; nothing is typed in by hand, so rerunning the commands on
another machine reproduces the section for that machine. The section lives
between :data:`BEGIN` and :data:`END`; the rest of the README is left alone.
The tradeoff plot and the evaluation contact sheet are copied to
``docs/results/`` so that the README can show them.

A missing input is not an error: its part of the section says which command
produces it; benchmark files of different runs are (:func:`benchmark_run`):
the speed table says its figures were measured in one run, so every file it
reads must carry the same run id, which ``python -m benchmarks`` writes into
them; each row gives its threads and timed runs where the file records them.
Rows at a precision the CPU does not run natively (bf16 under an ISA cap of
oneDNN, say) are marked emulated, and the cap is named. ``--check`` writes
nothing and exits 1 when the README's section differs from what the inputs
give.

The bundled detector's figures have their own section, between
:data:`DETECTOR_BEGIN` and :data:`DETECTOR_END` (under "How well it works"),
written from ``--detector`` (default ``docs/results/detector.json``, which
``benchmarks/train_bundled_detector.py`` writes beside its document):
``--detector-only`` rewrites just that one, since retraining the detector
does not rerun the demo.
"""

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from benchmarks.errors import ResultsError
from benchmarks.readme_demo import (
    SEEDED,
    calibration_section,
    eval_blocks,
    seeded_runs,
    stage_blocks,
    tradeoff_blocks,
)
from benchmarks.readme_format import FIGURES, Copies, not_measured, number
from benchmarks.readme_speed import bench_blocks
from lenspair.core.fsutil import atomic_write_bytes, atomic_write_text
from lenspair.core.report import Block, Heading, Paragraph, Table, to_markdown
from lenspair.demo_report import load_json

BEGIN = "<!-- results:begin (written by `make results`; do not edit by hand) -->"
END = "<!-- results:end -->"
DETECTOR_BEGIN = (
    "<!-- detector:begin (written by `python -m benchmarks.readme_results --detector-only`; "
    "do not edit by hand) -->"
)
DETECTOR_END = "<!-- detector:end -->"
PAPER = "https://arxiv.org/abs/2109.01889"


def section(
    demo: Path,
    bench: Path,
    copies: Copies,
    demo_fp32: Path | None = None,
    seeded: Sequence[Path] = SEEDED,
) -> str:
    """The Markdown between the markers (without them); pictures to copy go to ``copies``."""
    parts: list[tuple[str, Callable[[], list[Block]]]] = [
        ("Accuracy and its time (demo data)", lambda: tradeoff_blocks(demo, copies)),
        ("Accuracy over seeds (longer runs)", lambda: seeded_runs(seeded)),
        ("The fine-tuned network per difficulty", lambda: eval_blocks(demo, copies)),
        ("Pipeline stages", lambda: stage_blocks(demo, demo_fp32)),
        ("Calibration against the simulator's truth", lambda: calibration_section(demo)),
        ("Speed against the machine", lambda: bench_blocks(bench)),
    ]
    blocks: list[Block] = [
        Paragraph(
            "Everything below is written by `make results` from the outputs of `lenspair "
            "demo` and `python -m benchmarks` on the machine that ran them; rerun it to "
            "measure yours. The demo's data are simulated and its training budget is "
            "minutes on a CPU, so these figures show the pipeline working and what each "
            "network costs, not accuracy on real rain."
        ),
        Paragraph(
            f"Beside the paper ({PAPER}): its tables report PSNR/SSIM on the Raindrop test "
            "set and on the authors' rig data after full training, and GPU times. Those "
            "figures are not copied here: the comparable rows come from running the Raindrop "
            "recipe above (`lenspair train`, then `lenspair eval --convention deraindrop-y`, "
            "the paper's protocol), whose tables have the same columns as the ones below."
        ),
    ]
    for title, make in parts:
        blocks.append(Heading(title, 3))
        blocks += make()
    return to_markdown(blocks).rstrip("\n") + "\n"


def detector_section(figures_path: Path, bench: Path | None = None) -> str:
    """The bundled detector's held-out scores, hard cases and latency, from its JSON.

    Its time comes from ``bench/detector.json`` when the benchmark run holds
    one (``bench_detector`` times GEA as deployed, channels-last, in the run
    the rest of the README's figures come from); else from the training run's
    figures, whose GEA ran in NCHW (said, as it made the detector look about
    half as costly as it is).
    """
    figures = load_json(figures_path)
    if not figures:
        missing = not_measured("this section", "python -m benchmarks.train_bundled_detector")
        return to_markdown(missing).rstrip("\n") + "\n"
    training = figures["training"]
    rows = [
        [
            name,
            str(s["frames"]),
            str(s["positives"]),
            number(s["accuracy"], 3),
            number(s["f1"], 3),
            number(s["precision"], 3),
            number(s["recall"], 3),
            number(s["tile_iou"], 3),
        ]
        for name, s in figures["scores"].items()
    ]
    blocks: list[Block] = [
        Paragraph(
            f"The bundled detector ({training['steps']} steps in "
            f"{training['seconds'] / 60:.0f} min on `{figures['device']}`; "
            f"`{figures['command']}`), on sets held out by recording:"
        ),
        Table(
            [
                "held-out set",
                "frames",
                "obstructed",
                "accuracy",
                "F1",
                "precision",
                "recall",
                "tile IoU",
            ],
            rows,
        ),
        Table(
            ["hard case", "passed", "answer"],
            [
                [c["name"], "yes" if c["passed"] else "no", c["detail"]]
                for c in figures["hard_cases"]
            ],
        ),
    ]
    timed = load_json(bench / "detector.json") if bench is not None else None
    latency = timed if timed and "gea_layout" in timed else figures.get("latency")
    if latency:
        medians = latency["median_ms"]
        run = latency.get("benchmark_run") or {}
        where = f", benchmark run {run['id']} on {run['cpu']}" if run.get("id") else ""
        layout = latency.get("gea_layout", "NCHW")
        blocks.append(
            Paragraph(
                f"Its time per 540x360 frame (batch 1, fp32, {latency['threads']} thread, median "
                f"of {latency['runs']} interleaved runs{where}): {medians['judge']:.2f} ms with "
                f"its input preparation, {latency['ratio_judge_to_gea']:.3f}x GEA's "
                f"{medians['GEA']:.0f} ms ({layout}) measured in the same run "
                f"({latency['parameters']['detector']:,} parameters)."
            )
        )
    return to_markdown(blocks).rstrip("\n") + "\n"


def replace_section(readme: str, body: str, begin: str = BEGIN, end: str = END) -> str:
    """``readme`` with the text between the markers ``begin`` and ``end`` replaced by ``body``."""
    start, stop = readme.find(begin), readme.find(end)
    if start < 0 or stop < 0 or stop < start:
        raise ResultsError(f"README needs the markers {begin!r} and {end!r}, in that order")
    return readme[: start + len(begin)] + "\n\n" + body + "\n" + readme[stop:]


def main(argv: Sequence[str] | None = None) -> int:
    """Rewrite (or ``--check``) the README's results section; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.readme_results",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--demo", type=Path, default=Path("demo_out"), help="lenspair demo output")
    parser.add_argument(
        "--demo-fp32",
        type=Path,
        default=None,
        help="the same demo run under ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI (bf16 off), if any",
    )
    parser.add_argument(
        "--tradeoff-seeds",
        type=Path,
        nargs="+",
        default=list(SEEDED),
        help="tradeoff_seeds.md of longer `lenspair tradeoff --seeds` runs, shown in this "
        "order (default: %(default)s)",
    )
    parser.add_argument("--bench", type=Path, default=Path("bench_out"), help="benchmark JSON")
    parser.add_argument("--readme", type=Path, default=Path("README.md"), help="file to update")
    parser.add_argument(
        "--detector",
        type=Path,
        default=FIGURES / "detector.json",
        help="the bundled detector's figures (train_bundled_detector writes them)",
    )
    parser.add_argument(
        "--detector-only", action="store_true", help="rewrite only the detector's section"
    )
    parser.add_argument("--check", action="store_true", help="exit 1 if the README is stale")
    args = parser.parse_args(argv)
    text = args.readme.read_text(encoding="utf-8")
    copies: Copies = []
    try:
        updated = text
        if args.detector_only or DETECTOR_BEGIN in text:  # a README may show no detector
            body = detector_section(args.detector, args.bench)
            updated = replace_section(updated, body, DETECTOR_BEGIN, DETECTOR_END)
        if not args.detector_only:
            body = section(args.demo, args.bench, copies, args.demo_fp32, args.tradeoff_seeds)
            updated = replace_section(updated, body)
    except ResultsError as error:
        print(f"{args.readme}: {error}", file=sys.stderr)
        return 2
    if args.check:
        pictures_stale = any(
            not (args.readme.parent / name).is_file()
            or (args.readme.parent / name).read_bytes() != source.read_bytes()
            for source, name in copies
        )
        if updated != text or pictures_stale:
            print(f"{args.readme}: results section is stale; run `make results`", file=sys.stderr)
            return 1
        return 0
    for source, name in copies:
        target = args.readme.parent / name
        target.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(target, source.read_bytes())
    if updated != text:
        atomic_write_text(args.readme, updated)
    sources = (
        f"{args.detector} (its time from {args.bench / 'detector.json'} when there)"
        if args.detector_only
        else f"{args.demo}, {args.bench}"
    )
    print(f"{args.readme}: results written from {sources}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
