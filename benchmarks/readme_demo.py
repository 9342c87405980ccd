"""The parts of the README's results section read from ``lenspair demo``'s outputs.

The demo's tradeoff table and plot, the longer tradeoffs over seeds
(``lenspair tradeoff --seeds``, as the command wrote each), the evaluation of
the fine-tuned network per difficulty, the wall time of each demo stage, and
the calibration against the simulator's truth. Each function returns the
blocks of one part; pictures to show are added to ``copies``.
"""

import re
from collections.abc import Sequence
from itertools import chain
from pathlib import Path

from benchmarks.readme_format import FIGURES, Copies, not_measured, number
from lenspair.core.report import Block, Heading, Image, Paragraph, Table
from lenspair.demo import Budget, plan
from lenspair.demo_report import (
    calibration_blocks,
    finetune_runtime,
    load_json,
    markdown_file_blocks,
)


def tradeoff_blocks(demo: Path, copies: Copies) -> list[Block]:
    """The paper's G/GE/GEA ablation and the width/depth variants: accuracy with its time."""
    data = load_json(demo / "tradeoff" / "tradeoff.json")
    if data is None:
        return not_measured("the accuracy-against-time table", "lenspair demo --out demo_out")
    rows: list[list[str]] = []
    baseline = data.get("input_baseline")
    if baseline:
        rows.append(
            [
                "input, no restoration",
                "-",
                "0",
                "0",
                "0",
                number(baseline["psnr_db"], 2),
                number(baseline["ssim"], 4),
                "",
            ]
        )
    for r in data["rows"]:
        mark = ("PSNR " if r["pareto_psnr"] else "") + ("SSIM" if r["pareto_ssim"] else "")
        rows.append(
            [
                r["name"],
                r["precision"],
                f"{r['params']:,}",
                number(r["gflops"], 1),
                number(r["cpu_ms"], 1),
                number(r["psnr_db"], 2),
                number(r["ssim"], 4),
                mark.strip(),
            ]
        )
    blocks: list[Block] = [
        Paragraph(
            f"`lenspair tradeoff` as the demo runs it: every network trained for "
            f"{data['budget']} from scratch on the demo dataset, scored on "
            f"{Path(str(data['evaluated_on'])).name} with the {data['convention']} convention; "
            f"CPU time is the median for one {data['size']} frame, batch 1, "
            f"{data['threads']} threads, channels-last with the allocator tuned "
            "(model/evaluation/latency.py). G, GE and GEA are the paper's ablation; the "
            "w (width) and b (residual blocks) variants trade accuracy for time. "
            "Pareto marks the PSNR-vs-time and SSIM-vs-time fronts."
        ),
        Table(
            ["network", "precision", "params", "GFLOPs", "CPU ms", "PSNR (dB)", "SSIM", "Pareto"],
            rows,
        ),
    ]
    blocks += _figure(demo / "tradeoff" / "tradeoff.png", copies, "tradeoff.png",
                      "accuracy against CPU time per frame; dashed: the input itself")  # fmt: skip
    return blocks


def _figure(source: Path, copies: Copies, name: str, caption: str) -> list[Block]:
    if not source.is_file():
        return []
    copies.append((source, FIGURES / name))
    return [Image((FIGURES / name).as_posix(), caption)]


def eval_blocks(demo: Path, copies: Copies) -> list[Block]:
    """The fine-tuned GEA on the test split, per difficulty, against the input."""
    data = load_json(demo / "eval" / "metrics.json")
    if data is None:
        return not_measured("the evaluation", "lenspair demo --out demo_out")
    inputs = data.get("input", {})
    subsets = {"all": data["overall"], **data["by_difficulty"]}
    input_subsets = {"all": inputs.get("overall"), **inputs.get("by_difficulty", {})}
    rows = []
    for name, s in subsets.items():
        base = input_subsets.get(name) or {}
        rows.append(
            [
                name,
                str(s["pairs"]),
                number(base.get("psnr_db"), 2),
                number(s["psnr_db"], 2),
                number(base.get("ssim"), 4),
                number(s["ssim"], 4),
            ]
        )
    blocks: list[Block] = [
        Paragraph(
            "`lenspair eval` of the demo's fine-tuned GEA (synthetic pretraining, then "
            f"fine-tuning on the pairs) on the test split, {data['convention']} convention; "
            "difficulty is the input-vs-target PSNR band that dataset-build assigned."
        ),
        Table(["subset", "pairs", "input PSNR", "output PSNR", "input SSIM", "output SSIM"], rows),
    ]
    latency = [
        [lat["device"], lat["precision"], lat["size"], str(lat["threads"]),
         number(lat["median_ms"], 1), number(lat["p90_ms"], 1)]
        for lat in data.get("latency", [])
    ]  # fmt: skip
    if latency:
        blocks.append(
            Table(["device", "precision", "size", "threads", "median ms", "p90 ms"], latency)
        )
    blocks += _figure(demo / "eval" / "contact_sheet.png", copies, "contact_sheet.png",
                      "test pairs per difficulty: input | GEA output | target")  # fmt: skip
    return blocks


SEEDED = (
    FIGURES / "tradeoff_seeds_cpu.md",
    FIGURES / "tradeoff_seeds_cpu_4000steps.md",
    FIGURES / "tradeoff_seeds_cpu_8000steps.md",
    FIGURES / "tradeoff_seeds_h100.md",
)
"""The longer tradeoffs over seeds (``tradeoff_seeds.md`` as the command wrote each): three
trained on this project's 2-core CPUs with the decaying schedule (2000 steps, 4000 and 8000 for
G, GE, GEA and GEA-w0.5, which ``benchmarks.tradeoff_budgets`` compares), one on a lent H100."""


def seeded_blocks(path: Path, published: bool = True) -> list[Block]:
    """The tradeoff over seeds, as ``lenspair tradeoff --seeds`` wrote it, with where it ran.

    Its own heading is dropped (the section gives one); the device comes from
    the ``.json`` the command writes beside the ``.md``. ``published=False``
    also drops the paper's published rows (shown once, after the last run).
    """
    if not path.is_file():
        return not_measured("the tradeoff over seeds", "lenspair tradeoff DS --seeds 0,1,2")
    meta = (load_json(path.with_suffix(".json")) or {}).get("meta", {})
    device = meta.get("device", "a device not recorded")
    cpu = f" ({meta['cpu']})" if meta.get("cpu") else ""
    blocks = [_rebased(b, path.parent) for b in markdown_file_blocks(path)]
    blocks = [b for b in blocks if not isinstance(b, Heading)]
    if not published:
        starts = [
            i for i, b in enumerate(blocks)
            if isinstance(b, Paragraph) and b.text.startswith("Published figures")
        ]  # fmt: skip
        blocks = blocks[: starts[0]] if starts else blocks
    intro = Paragraph(
        f"A longer run than the demo's: `lenspair tradeoff DS --seeds 0,1,2 --budget N` "
        f"(`make tradeoff-seeds`), trained on {device}, CPU times from that machine's CPU{cpu}; "
        f"written by the command to `{path.as_posix()}`. Read the accuracy columns with "
        "the convergence column beside them. Its dataset is not the demo's (its data line "
        "names it), so its input row differs from the demo table's above."
    )
    return [intro, *blocks]


_RELATIVE_LINK = re.compile(r"\]\((?![a-z][a-z0-9+.-]*:|#|/)([^)\s]+)\)")
"""A Markdown link to a file relative to the page it is on (not a URL, an anchor, or absolute)."""


def _rebased(block: Block, folder: Path) -> Block:
    """``block`` of a page in ``folder`` (beside the README), its relative links made the README's.

    ``[gpu_h100.md](gpu_h100.md)`` in ``docs/results/tradeoff_seeds_h100.md``
    pointed at a file beside the README, where there is none.
    """
    if not isinstance(block, Paragraph):
        return block
    text = _RELATIVE_LINK.sub(lambda m: f"]({(folder / m[1]).as_posix()})", block.text)
    return Paragraph(text)


def seeded_runs(paths: Sequence[Path]) -> list[Block]:
    """Each longer run's table in turn; the paper's published rows once, after the last."""
    last = len(paths) - 1
    return [*chain(*(seeded_blocks(path, i == last) for i, path in enumerate(paths)))]


DEMO_TARGET_MINUTES = 15.0
"""Issue 11: the demo finishes within 15 minutes on 2 CPU cores, with or without native bf16."""


def _training_line(demo: Path) -> str:
    """How the demo's fine-tuning ran (precision and why), read from its ``config.yaml``."""
    runtime = finetune_runtime(demo)
    if runtime is None:
        return "training precision not recorded"
    return f"trained at {runtime.precision} ({runtime.precision_reason})"


def stage_blocks(demo: Path, demo_fp32: Path | None = None) -> list[Block]:
    """Wall time of each demo stage; beside it a second demo run without native bf16, if any.

    ``demo_fp32`` is the same demo run on the same machine under
    ``ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI`` (``make results`` does it where bf16
    is native): the demo's time on a CPU whose bf16 would be emulated.
    """
    timings = load_json(demo / "timings.json")
    if timings is None:
        return not_measured("the stage timings", "lenspair demo --out demo_out")
    runs = [(demo, timings)]
    other = load_json(demo_fp32 / "timings.json") if demo_fp32 is not None else None
    if demo_fp32 is not None and other is not None:
        runs.append((demo_fp32, other))
    order = [stage.name for stage in plan(demo, Budget())]
    names = {name for _, t in runs for name in t}
    ranked = sorted(names, key=lambda n: order.index(n) if n in order else len(order))
    rows = [
        [name, *(number(t[name]["seconds"], 1) if name in t else "-" for _, t in runs)]
        for name in ranked
    ]
    totals = [sum(float(s["seconds"]) for s in t.values()) for _, t in runs]
    rows.append(["total", *(number(total, 1) for total in totals)])
    reused = ", ".join(
        name for name in ranked if any(t.get(name, {}).get("reused") for _, t in runs)
    )
    note = f" Reused from an earlier run, with that run's time: {reused}." if reused else ""
    headers = ["stage", f"seconds ({demo.name})"]
    lines = [f"`{demo.name}`: {totals[0] / 60:.1f} min, {_training_line(demo)}."]
    for (extra, _), total in zip(runs[1:], totals[1:], strict=True):
        headers.append(f"seconds ({extra.name}, bf16 off)")
        lines.append(
            f"`{extra.name}`: the same demo under `ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI`, "
            f"as on a CPU without native bf16: {total / 60:.1f} min, "
            f"{_training_line(extra)}."
        )
    within = all(total <= DEMO_TARGET_MINUTES * 60 for total in totals)
    lines.append(
        f"Target: within {DEMO_TARGET_MINUTES:.0f} min on a 2-core CPU; on this machine "
        + ("met." if within else "NOT met.")
    )
    return [
        Paragraph(f"`lenspair demo`, seconds per stage (wall clock).{note}"),
        Table(headers, rows),
        Paragraph(" ".join(lines)),
    ]


def calibration_section(demo: Path) -> list[Block]:
    """The demo's calibration against the simulator's true camchain."""
    if not (demo / "calibration" / "camchain.report.json").is_file():
        return not_measured("the calibration", "lenspair demo --out demo_out")
    return [
        Paragraph("`lenspair calibrate` on the demo's simulated board session, against truth."),
        *calibration_blocks(demo),
    ]
