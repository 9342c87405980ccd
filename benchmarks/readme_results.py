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
import math
import sys
from collections.abc import Callable, Sequence
from itertools import chain
from pathlib import Path
from typing import Any

from benchmarks import RUN_KEY
from lenspair.core.fsutil import atomic_write_bytes, atomic_write_text
from lenspair.core.report import Block, Heading, Image, Paragraph, Table, to_markdown
from lenspair.demo import Budget, plan
from lenspair.demo_report import (
    calibration_blocks,
    finetune_runtime,
    load_json,
    markdown_file_blocks,
)

BEGIN = "<!-- results:begin (written by `make results`; do not edit by hand) -->"
END = "<!-- results:end -->"
DETECTOR_BEGIN = (
    "<!-- detector:begin (written by `python -m benchmarks.readme_results --detector-only`; "
    "do not edit by hand) -->"
)
DETECTOR_END = "<!-- detector:end -->"
FIGURES = Path("docs") / "results"
PAPER = "https://arxiv.org/abs/2109.01889"


Copies = list[tuple[Path, Path]]
"""(source, destination) of the pictures the section shows, copied by :func:`main`."""


class ResultsError(Exception):
    """The section cannot be written: README markers, or benchmark files of several runs.

    The README's markers are missing or out of order, or the benchmark files
    come from different runs (:func:`benchmark_run`).
    """


def _settings(threads: Any = None, runs: Any = None, unit: str = "run") -> str:
    """``2 threads, 40 runs``: the settings of a row, the parts not recorded left out."""
    parts = []
    if threads is not None:
        parts.append(f"{int(threads)} thread" + "s" * (int(threads) != 1))
    if runs is not None:
        parts.append(f"{int(runs)} {unit}" + "s" * (int(runs) != 1))
    return ", ".join(parts)


def _cap(record: dict[str, Any] | None, run: dict[str, Any] | None = None) -> str | None:
    """oneDNN's ISA cap a benchmark ran under (``ONEDNN_MAX_CPU_ISA``), or None."""
    return (record or {}).get("onednn_max_cpu_isa") or (run or {}).get("onednn_max_cpu_isa")


def _emulated_note(precision: str, cap: str | None) -> str:
    """``, emulated (bf16 not native under ONEDNN_MAX_CPU_ISA=AVX2)``."""
    under = f" under ONEDNN_MAX_CPU_ISA={cap}" if cap else ""
    return f", emulated ({precision} not native{under})"


def _emulated(precision: str, native: Sequence[str] | None, cap: str | None) -> str:
    """:func:`_emulated_note` for a precision not in ``native``; ``""`` if native or unknown."""
    return "" if native is None or precision in native else _emulated_note(precision, cap)


def _isa_cap_rows(isa_cap: dict[str, Any] | None) -> list[list[str]]:
    """bf16 against fp32 as the CPU is and with oneDNN capped below bf16 (bench_isa_cap)."""
    if not isa_cap:
        return []
    rows = []
    for row in isa_cap["rows"]:
        medians = row["median_ms"]
        rows.append(
            [
                f"{isa_cap['kernel']}, oneDNN {row['cap'] or 'as the CPU is'}",
                f"bf16 {_num(medians['bf16'], 2)} ms / fp32 {_num(medians['fp32'], 2)} ms",
                f"fp32 in the same run; auto trains at {row['auto']}",
                f"{_num(row['bf16_over_fp32'], 2)}x (bf16 / fp32)",
                _settings(1, isa_cap.get("runs")),
            ]
        )
    return rows


def _precision_rows(
    model: dict[str, Any] | None, int8: dict[str, Any] | None, run: dict[str, Any] | None = None
) -> list[list[str]]:
    """Rows for int8 inference (bench_int8), GEA vs DeRaindrop and the native precisions."""
    rows = []
    if int8:
        # against the fp32 torch timed beside it in bench_int8, not the fp32 row above
        # (bench_model's, another benchmark): its time is shown, so the ratio can be checked
        fp32 = int8["medians_ms"].get("fp32 torch")
        beside = "fp32 torch timed beside it" + (f" ({_num(fp32, 1)} ms)" if fp32 else "")
        native = (int8.get("precision") or {}).get("native")
        for name, ms in int8["medians_ms"].items():
            if name == "fp32 torch":
                continue
            rows.append(
                [
                    f"GEA 540x360 batch 1, {name}" + _emulated("int8", native, _cap(int8, run)),
                    f"{_num(ms, 1)} ms",
                    f"PSNR against fp32 output {_num(int8['psnr_vs_fp32_db'][name], 1)} dB; "
                    f"quantise/compile {_num(int8['setup_seconds'].get(name, 0.0), 0)} s",
                    _speed(int8["speed_vs_fp32"][name], beside),
                    _settings(int8.get("threads"), int8.get("runs")),
                ]
            )
    model = model or {}
    deraindrop = model.get("deraindrop_720x480_rgb") or {}
    if deraindrop:
        rows.append(
            [
                "720x480 RGB batch 1 fp32: GEA / DeRaindrop's generator (same run)",
                f"{_num(deraindrop['gea_ms'], 0)} ms / {_num(deraindrop['deraindrop_ms'], 0)} ms",
                "DeRaindrop re-implemented layer for layer (the paper: 8x)",
                f"{_num(deraindrop['speedup'], 1)}x faster",
                _settings(model.get("threads"), deraindrop.get("runs")),
            ]
        )
    decision = model.get("precision") or {}
    if decision.get("native"):
        cap = _cap(model, run)
        capped = f", oneDNN capped: ONEDNN_MAX_CPU_ISA={cap}" if cap else ""
        rows.append(
            [
                f"precisions native on this CPU{capped}",
                ", ".join(decision["native"]),
                "lenspair.model.precision (auto never picks an emulated one): "
                + str(decision.get("reason", "reason not recorded")),
                f"auto: {decision['precision']}",
                "",
            ]
        )
    return rows


def _speed(ratio: float, than: str) -> str:
    """``1.43x faster than fp32``, or ``1.18x slower than fp32`` for a ratio below 1."""
    if ratio >= 1.0:
        return f"{_num(ratio, 2)}x faster than {than}"
    return f"{_num(1.0 / ratio, 2)}x slower than {than}"


def _num(value: Any, digits: int) -> str:
    if value is None:
        return "n/a"
    value = float(value)
    if math.isinf(value):
        return "inf"
    return f"{value:.{digits}f}"


def _missing(what: str, command: str) -> list[Block]:
    return [Paragraph(f"Not measured yet: {what} comes from `{command}`.")]


def tradeoff_blocks(demo: Path, copies: Copies) -> list[Block]:
    """The paper's G/GE/GEA ablation and the width/depth variants: accuracy with its time."""
    data = load_json(demo / "tradeoff" / "tradeoff.json")
    if data is None:
        return _missing("the accuracy-against-time table", "lenspair demo --out demo_out")
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
                _num(baseline["psnr_db"], 2),
                _num(baseline["ssim"], 4),
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
                _num(r["gflops"], 1),
                _num(r["cpu_ms"], 1),
                _num(r["psnr_db"], 2),
                _num(r["ssim"], 4),
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
        return _missing("the evaluation", "lenspair demo --out demo_out")
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
                _num(base.get("psnr_db"), 2),
                _num(s["psnr_db"], 2),
                _num(base.get("ssim"), 4),
                _num(s["ssim"], 4),
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
         _num(lat["median_ms"], 1), _num(lat["p90_ms"], 1)]
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
        return _missing("the tradeoff over seeds", "lenspair tradeoff DS --seeds 0,1,2")
    meta = (load_json(path.with_suffix(".json")) or {}).get("meta", {})
    device = meta.get("device", "a device not recorded")
    cpu = f" ({meta['cpu']})" if meta.get("cpu") else ""
    blocks = [b for b in markdown_file_blocks(path) if not isinstance(b, Heading)]
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
        return _missing("the stage timings", "lenspair demo --out demo_out")
    runs = [(demo, timings)]
    other = load_json(demo_fp32 / "timings.json") if demo_fp32 is not None else None
    if demo_fp32 is not None and other is not None:
        runs.append((demo_fp32, other))
    order = [stage.name for stage in plan(demo, Budget())]
    names = {name for _, t in runs for name in t}
    ranked = sorted(names, key=lambda n: order.index(n) if n in order else len(order))
    rows = [
        [name, *(_num(t[name]["seconds"], 1) if name in t else "-" for _, t in runs)]
        for name in ranked
    ]
    totals = [sum(float(s["seconds"]) for s in t.values()) for _, t in runs]
    rows.append(["total", *(_num(total, 1) for total in totals)])
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
        return _missing("the calibration", "lenspair demo --out demo_out")
    return [
        Paragraph("`lenspair calibrate` on the demo's simulated board session, against truth."),
        *calibration_blocks(demo),
    ]


BENCH_FILES = (
    "model.json",
    "training.json",
    "int8.json",
    "isa_cap.json",
    "effects.json",
    "ingest.json",
    "dataset.json",
    "memory.json",
    "calibration.json",
)
"""The benchmark outputs the speed table reads, all from one ``python -m benchmarks`` run."""


def benchmark_run(bench: Path) -> dict[str, Any] | None:
    """The ``benchmark_run`` entry that every file of :data:`BENCH_FILES` in ``bench`` shares.

    ``None`` when there is none of them. The table says its figures were
    measured in the same run; files of different runs (a model.json from a
    run under an ISA cap beside an int8.json from a benchmark run alone)
    would make that untrue.

    Raises:
        ResultsError: the files carry different run ids, or one carries none
            (written by a benchmark run on its own, or before run ids).

    """
    records = {name: load_json(bench / name) for name in BENCH_FILES}
    runs = {
        name: (record.get(RUN_KEY) or {}) if isinstance(record, dict) else {}
        for name, record in records.items()
        if record is not None
    }
    if not runs:
        return None
    ids = {name: run.get("id") for name, run in runs.items()}
    if None in ids.values() or len(set(ids.values())) > 1:
        listing = ", ".join(f"{name} ({ids[name] or 'no run id'})" for name in sorted(ids))
        raise ResultsError(
            f"{bench}: benchmark files of different runs, refused (the table would say they "
            f"were measured in one): {listing}; rerun `python -m benchmarks --out {bench}`"
        )
    return next(iter(runs.values()))


def _model_rows(model: dict[str, Any], run: dict[str, Any] | None) -> list[list[str]]:
    """bench_model's best fp32 and bf16 configurations."""
    fp32, bf16 = model["fp32_best"], model["bf16_best"]
    native = (model.get("precision") or {}).get("native")
    if model.get("emulated") is not None:  # recorded per configuration
        mark = _emulated_note("bf16", _cap(model, run)) if bf16 in model["emulated"] else ""
    else:  # a model.json from before: the native precisions tell
        mark = _emulated("bf16", native, _cap(model, run))
    frame = f"GEA {model['size'][1]}x{model['size'][0]} batch 1"
    threads = model.get("threads")
    return [
        [
            f"{frame}, {fp32}",
            f"{_num(model['fp32_ms'], 1)} ms",
            f"fp32 roofline {_num(model['roofline_ms'], 1)} ms (peak "
            f"{_num(model['peak_gflops'], 0)} GFLOP/s, {model['peak_kernel']})",
            f"{_num(model['fp32_roofline_ratio'], 2)}x",
            _settings(threads, model.get("runs")),
        ],
        [
            f"{frame}, {bf16}{mark}",
            f"{_num(model['bf16_ms'], 1)} ms",
            f"PSNR against fp32 output {_num(model['bf16_psnr_vs_fp32_db'][bf16], 1)} dB",
            _speed(model["fp32_ms"] / model["bf16_ms"], "fp32"),
            _settings(threads, model.get("bf16_runs", model.get("runs"))),
        ],
    ]


def _calibration_row(case: dict[str, Any]) -> list[str]:
    """One board/model case of bench_calibration: detection + calibration time, accuracy."""
    if "detect_calibrate_ms" in case:  # the median of each run's detection + calibration
        median = f"{_num(case['detect_calibrate_ms'], 0)} ms"
    else:  # an older calibration.json: two medians added, which is not a median
        median = (
            f"{_num(case['detect_ms'] + case['calibrate_ms'], 0)} ms (sum of the detection "
            "and calibration medians)"
        )
    return [
        f"calibrate {case['board'].split(':')[0]} {case['model']}, {case['views']} views: "
        "detection + calibration",
        median,
        f"focal error {_num(case['focal_error_pct'], 3)} %, baseline "
        f"{_num(case['baseline_error_pct'], 3)} %, "
        f"rows {_num(case['row_disagreement_px'], 3)} px",
        f"stereo RMS {_num(case['stereo_rms_px'], 3)} px",
        _settings(case.get("opencv_threads"), case.get("repeats")),
    ]


def _bench_rows(bench: Path, run: dict[str, Any] | None = None) -> list[list[str]]:
    rows: list[list[str]] = []
    model = load_json(bench / "model.json")
    if model:
        rows += _model_rows(model, run)
    training = load_json(bench / "training.json")
    if training:
        steps = training["steps_per_second"]
        native = (training.get("precision_auto") or {}).get("native")
        cap = _cap(training, run)
        rows.append(
            [
                f"GEA training step, batch {training['batch']}, crop {training['crop']}",
                " / ".join(
                    f"{k}{_emulated(k.split()[0], native, cap)} {_num(v, 2)} steps/s"
                    for k, v in steps.items()
                ),
                "fp32 step",
                " / ".join(
                    f"{name} {_num(speed, 2)}x"
                    for name, speed in training.get(
                        "speed_vs_fp32", {"mixed": training.get("mixed_over_fp32_speed")}
                    ).items()
                )
                + " (speed vs fp32)",
                _settings(training.get("threads"), training.get("steps"), "step"),
            ]
        )
    rows += _precision_rows(model, load_json(bench / "int8.json"), run)
    rows += _isa_cap_rows(load_json(bench / "isa_cap.json"))
    effects = load_json(bench / "effects.json")
    if effects:
        for name, target in effects["targets"].items():
            rows.append(
                [
                    f"simulate {name}, {effects['frame']} frame",
                    f"{_num(target['worst_render_ms'], 2)} ms",
                    f"target < {_num(target['target_ms'], 0)} ms",
                    "met" if target["met"] else "missed",
                    _settings(effects.get("opencv_threads"), effects.get("runs")),
                ]
            )
    ingest = load_json(bench / "ingest.json")
    if ingest:
        rows.append(
            [
                f"capture-ingest, {ingest['pairs']} pairs, 1 worker",
                f"{_num(ingest['ingest_w1_ms_per_pair'], 1)} ms/pair",
                f"decode + remap + encode floor {_num(ingest['io_floor_ms_per_pair'], 1)} ms/pair",
                f"{_num(ingest['ratio_w1_to_floor'], 2)}x",
                _settings(None, ingest.get("runs")),
            ]
        )
    dataset = load_json(bench / "dataset.json")
    if dataset:
        rows.append(
            [
                f"dataset-build, {dataset['pairs']} pairs",
                f"{_num(dataset['build_pairs_per_s'], 0)} pairs/s",
                f"PNG decode floor {_num(dataset['decode_floor_pairs_per_s'], 0)} pairs/s; "
                f"read + hash + link floor {_num(dataset['io_floor_pairs_per_s'], 0)} pairs/s",
                f"{_num(dataset['build_over_decode_floor'], 2)}x / "
                f"{_num(dataset['build_over_io_floor'], 1)}x",
                _settings(dataset.get("workers"), dataset.get("runs")),
            ]
        )
    memory = load_json(bench / "memory.json")
    if memory:
        counts = sorted({row["frames"] for row in memory["rows"]})
        most = {
            row["command"]: row["peak_mib"] for row in memory["rows"] if row["frames"] == counts[-1]
        }
        ratios = memory["ratios"]
        rows.append(
            [
                f"peak memory at {counts[-1]} frames: ingest / dataset-build / restore",
                " / ".join(f"{_num(most[c], 0)} MiB" for c in ratios),
                f"the same at {counts[0]} frames (target <= {memory['target_ratio']}x)",
                " / ".join(f"{_num(ratios[c], 2)}x" for c in ratios),
                _settings(memory.get("threads"), memory.get("runs")),
            ]
        )
    calibration = load_json(bench / "calibration.json")
    for case in (calibration or {}).get("cases", []):
        rows.append(_calibration_row(case))
    return rows


def bench_blocks(bench: Path) -> list[Block]:
    """Speeds against a floor or peak measured in the same run (medians).

    Raises:
        ResultsError: the files come from different runs (:func:`benchmark_run`).

    """
    run = benchmark_run(bench)
    rows = _bench_rows(bench, run)
    if not rows:
        return _missing("the benchmarks", "python -m benchmarks --out bench_out")
    model = load_json(bench / "model.json") or {}
    machine = run or {}
    cap = _cap(model, run)
    where = ", ".join(
        part
        for part in (
            str(machine.get("cpu") or model.get("cpu_model") or ""),
            f"{machine['cores']} CPUs" if machine.get("cores") else "",
            f"torch {model['torch']}" if "torch" in model else "",
            f"oneDNN capped at ONEDNN_MAX_CPU_ISA={cap}" if cap else "",
        )
        if part
    )
    which = f" (run {machine['id']})" if machine.get("id") else ""
    return [
        Paragraph(
            f"`python -m benchmarks --out bench_out`{which} on {where or 'this machine'}; "
            "medians, each speed next to a floor or peak measured in the same run; the last "
            "column gives each row's threads and timed runs."
        ),
        Table(["what", "median", "measured against", "ratio", "threads, runs"], rows),
    ]


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


def detector_section(figures_path: Path) -> str:
    """The bundled detector's held-out scores, hard cases and latency, from its JSON."""
    figures = load_json(figures_path)
    if not figures:
        missing = _missing("this section", "python -m benchmarks.train_bundled_detector")
        return to_markdown(missing).rstrip("\n") + "\n"
    training = figures["training"]
    rows = [
        [
            name,
            str(s["frames"]),
            str(s["positives"]),
            _num(s["accuracy"], 3),
            _num(s["f1"], 3),
            _num(s["precision"], 3),
            _num(s["recall"], 3),
            _num(s["tile_iou"], 3),
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
    latency = figures.get("latency")
    if latency:
        medians = latency["median_ms"]
        blocks.append(
            Paragraph(
                f"Its time per 540x360 frame (batch 1, fp32, {latency['threads']} thread, median "
                f"of {latency['runs']} interleaved runs): {medians['judge']:.2f} ms with its "
                f"input preparation, {latency['ratio_judge_to_gea']:.3f}x GEA's "
                f"{medians['GEA']:.0f} ms measured in the same run "
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
            body = detector_section(args.detector)
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
    sources = f"{args.detector}" if args.detector_only else f"{args.demo}, {args.bench}"
    print(f"{args.readme}: results written from {sources}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
