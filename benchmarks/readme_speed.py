"""The speed table of the README's results section, read from the benchmarks' JSON files.

Each row is a median beside a floor or peak measured in the same run, with
the threads and timed runs the file records. Every file the table reads
must come from one ``python -m benchmarks`` run (:func:`benchmark_run`).
Rows at a precision the CPU does not run natively (bf16 under an ISA cap of
oneDNN, say) are marked emulated, and the cap is named.
"""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks import RUN_KEY
from benchmarks.errors import ResultsError
from benchmarks.readme_format import not_measured, number
from lenspair.core.report import Block, Paragraph, Table
from lenspair.demo_report import load_json


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


def _speed(ratio: float, than: str) -> str:
    """``1.43x faster than fp32``, or ``1.18x slower than fp32`` for a ratio below 1."""
    if ratio >= 1.0:
        return f"{number(ratio, 2)}x faster than {than}"
    return f"{number(1.0 / ratio, 2)}x slower than {than}"


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
                f"bf16 {number(medians['bf16'], 2)} ms / fp32 {number(medians['fp32'], 2)} ms",
                f"fp32 in the same run; auto trains at {row['auto']}",
                f"{number(row['bf16_over_fp32'], 2)}x (bf16 / fp32)",
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
        beside = "fp32 torch timed beside it" + (f" ({number(fp32, 1)} ms)" if fp32 else "")
        native = (int8.get("precision") or {}).get("native")
        for name, ms in int8["medians_ms"].items():
            if name == "fp32 torch":
                continue
            rows.append(
                [
                    f"GEA 540x360 batch 1, {name}" + _emulated("int8", native, _cap(int8, run)),
                    f"{number(ms, 1)} ms",
                    f"PSNR against fp32 output {number(int8['psnr_vs_fp32_db'][name], 1)} dB; "
                    f"quantise/compile {number(int8['setup_seconds'].get(name, 0.0), 0)} s",
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
                f"{number(deraindrop['gea_ms'], 0)} ms / "
                f"{number(deraindrop['deraindrop_ms'], 0)} ms",
                "DeRaindrop re-implemented layer for layer (the paper: 8x)",
                f"{number(deraindrop['speedup'], 1)}x faster",
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
                "lenspair.model.precision (auto: native and measured faster than fp32): "
                + str(decision.get("reason", "reason not recorded")),
                f"auto: {decision['precision']}",
                "",
            ]
        )
    return rows


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
    busy: dict[str, float] = {}
    for run in runs.values():  # each file's record holds the benchmarks up to its own
        busy.update(run.get("busy_at_start", {}))
    if busy:
        listing = ", ".join(f"{name} ({pressure:.0f} %)" for name, pressure in sorted(busy.items()))
        raise ResultsError(
            f"{bench}: benchmarks that started on a busy CPU (pressure at start: {listing}) "
            "inflate their ratios, refused; rerun `python -m benchmarks "
            f"--out {bench}` with nothing else running"
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
            f"{number(model['fp32_ms'], 1)} ms",
            f"fp32 roofline {number(model['roofline_ms'], 1)} ms (peak "
            f"{number(model['peak_gflops'], 0)} GFLOP/s, {model['peak_kernel']})",
            f"{number(model['fp32_roofline_ratio'], 2)}x",
            _settings(threads, model.get("runs")),
        ],
        [
            f"{frame}, {bf16}{mark}",
            f"{number(model['bf16_ms'], 1)} ms",
            f"PSNR against fp32 output {number(model['bf16_psnr_vs_fp32_db'][bf16], 1)} dB",
            _speed(model["fp32_ms"] / model["bf16_ms"], "fp32"),
            _settings(threads, model.get("bf16_runs", model.get("runs"))),
        ],
    ]


def _calibration_row(case: dict[str, Any]) -> list[str]:
    """One board/model case of bench_calibration: detection + calibration time, accuracy."""
    if "detect_calibrate_ms" in case:  # the median of each run's detection + calibration
        median = f"{number(case['detect_calibrate_ms'], 0)} ms"
    else:  # an older calibration.json: two medians added, which is not a median
        median = (
            f"{number(case['detect_ms'] + case['calibrate_ms'], 0)} ms (sum of the detection "
            "and calibration medians)"
        )
    return [
        f"calibrate {case['board'].split(':')[0]} {case['model']}, {case['views']} views: "
        "detection + calibration",
        median,
        f"focal error {number(case['focal_error_pct'], 3)} %, baseline "
        f"{number(case['baseline_error_pct'], 3)} %, "
        f"rows {number(case['row_disagreement_px'], 3)} px",
        f"stereo RMS {number(case['stereo_rms_px'], 3)} px",
        _settings(case.get("opencv_threads"), case.get("repeats")),
    ]


def _training_rows(training: dict[str, Any] | None, run: dict[str, Any] | None) -> list[list[str]]:
    """bench_training's steps per second at each precision, against the fp32 step."""
    if not training:
        return []
    steps = training["steps_per_second"]
    native = (training.get("precision_auto") or {}).get("native")
    cap = _cap(training, run)
    return [
        [
            f"GEA training step, batch {training['batch']}, crop {training['crop']}",
            " / ".join(
                f"{k}{_emulated(k.split()[0], native, cap)} {number(v, 2)} steps/s"
                for k, v in steps.items()
            ),
            _step_roofline(training),
            " / ".join(
                f"{name} {number(speed, 2)}x"
                for name, speed in training.get(
                    "speed_vs_fp32", {"mixed": training.get("mixed_over_fp32_speed")}
                ).items()
            )
            + " (speed vs fp32)"
            + _roofline_ratio(training),
            _settings(training.get("threads"), training.get("steps"), "step"),
        ]
    ]


def _step_roofline(training: dict[str, Any]) -> str:
    """The fp32 step's roofline (its counted FLOPs at the run's peak), where the run measured it."""
    if "fp32_roofline_seconds" not in training:
        return "fp32 step"
    return (
        f"fp32 step; its roofline {number(training['fp32_roofline_seconds'], 2)} s "
        f"({number(training['fp32_step_gflop'], 0)} GFLOP at the run's peak)"
    )


def _roofline_ratio(training: dict[str, Any]) -> str:
    """``; fp32 1.45x its roofline``, where the run measured it."""
    if "fp32_roofline_ratio" not in training:
        return ""
    return f"; fp32 {number(training['fp32_roofline_ratio'], 2)}x its roofline"


def _effects_rows(effects: dict[str, Any] | None) -> list[list[str]]:
    """bench_effects: each simulated effect's worst render time against its target."""
    if not effects:
        return []
    return [
        [
            f"simulate {name}, {effects['frame']} frame",
            f"{number(target['worst_render_ms'], 2)} ms",
            f"target < {number(target['target_ms'], 0)} ms",
            "met" if target["met"] else "missed",
            _settings(effects.get("opencv_threads"), effects.get("runs")),
        ]
        for name, target in effects["targets"].items()
    ]


def _ingest_rows(ingest: dict[str, Any] | None) -> list[list[str]]:
    """bench_ingest: capture-ingest with one worker against its decode + remap + encode floor."""
    if not ingest:
        return []
    return [
        [
            f"capture-ingest, {ingest['pairs']} pairs, 1 worker",
            f"{number(ingest['ingest_w1_ms_per_pair'], 1)} ms/pair",
            f"decode + remap + encode floor {number(ingest['io_floor_ms_per_pair'], 1)} ms/pair",
            f"{number(ingest['ratio_w1_to_floor'], 2)}x",
            _settings(None, ingest.get("runs")),
        ]
    ]


def _dataset_rows(dataset: dict[str, Any] | None) -> list[list[str]]:
    """bench_dataset: dataset-build's pairs per second against its decode and I/O floors.

    A rerun (figures read back from the measurement cache) is its own row,
    against the I/O floor: it decodes nothing.
    """
    if not dataset:
        return []
    rows = [
        [
            f"dataset-build, {dataset['pairs']} pairs",
            f"{number(dataset['build_pairs_per_s'], 0)} pairs/s",
            f"PNG decode floor {number(dataset['decode_floor_pairs_per_s'], 0)} pairs/s; "
            f"read + hash + link floor {number(dataset['io_floor_pairs_per_s'], 0)} pairs/s",
            f"{number(dataset['build_over_decode_floor'], 2)}x / "
            f"{number(dataset['build_over_io_floor'], 1)}x",
            _settings(dataset.get("workers"), dataset.get("runs")),
        ]
    ]
    if "rebuild_pairs_per_s" in dataset:  # runs before the measurement cache have none
        rows.append(
            [
                f"dataset-build rerun, {dataset['pairs']} pairs, figures cached",
                f"{number(dataset['rebuild_pairs_per_s'], 0)} pairs/s",
                f"read + hash + link floor {number(dataset['io_floor_pairs_per_s'], 0)} pairs/s",
                f"{number(dataset['rebuild_over_io_floor'], 1)}x",
                _settings(dataset.get("workers"), dataset.get("runs")),
            ]
        )
    return rows


def _memory_rows(memory: dict[str, Any] | None) -> list[list[str]]:
    """bench_memory: peak memory at the longer recording, as ratios to the shorter one."""
    if not memory:
        return []
    counts = sorted({row["frames"] for row in memory["rows"]})
    most = {
        row["command"]: row["peak_mib"] for row in memory["rows"] if row["frames"] == counts[-1]
    }
    ratios = memory["ratios"]
    return [
        [
            f"peak memory at {counts[-1]} frames: ingest / dataset-build / restore",
            " / ".join(f"{number(most[c], 0)} MiB" for c in ratios),
            f"the same at {counts[0]} frames (target <= {memory['target_ratio']}x)",
            " / ".join(f"{number(ratios[c], 2)}x" for c in ratios),
            _settings(memory.get("threads"), memory.get("runs")),
        ]
    ]


def _bench_rows(bench: Path, run: dict[str, Any] | None = None) -> list[list[str]]:
    """Every row of the speed table, from the files in ``bench`` there are."""
    model = load_json(bench / "model.json")
    rows = _model_rows(model, run) if model else []
    rows += _training_rows(load_json(bench / "training.json"), run)
    rows += _precision_rows(model, load_json(bench / "int8.json"), run)
    rows += _isa_cap_rows(load_json(bench / "isa_cap.json"))
    rows += _effects_rows(load_json(bench / "effects.json"))
    rows += _ingest_rows(load_json(bench / "ingest.json"))
    rows += _dataset_rows(load_json(bench / "dataset.json"))
    rows += _memory_rows(load_json(bench / "memory.json"))
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
        return not_measured("the benchmarks", "python -m benchmarks --out bench_out")
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
            "column gives each row's threads and timed runs. Where runs alternate with their "
            "floor (ingest, dataset-build), the ratio is the median of the per-round ratios, "
            "which other load disturbs less than the quotient of the two medians."
        ),
        Table(["what", "median", "measured against", "ratio", "threads, runs"], rows),
    ]
