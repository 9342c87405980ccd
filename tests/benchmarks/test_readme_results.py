"""The README's results section is written from the commands' own output files."""

import re
from pathlib import Path
from typing import Any

import pytest

from benchmarks import RUN_KEY
from benchmarks.readme_demo import seeded_blocks, seeded_runs, stage_blocks
from benchmarks.readme_results import (
    BEGIN,
    DETECTOR_BEGIN,
    DETECTOR_END,
    END,
    main,
    replace_section,
)
from benchmarks.readme_speed import bench_blocks
from lenspair.core.config import dump_yaml
from lenspair.core.fsutil import atomic_write_json
from lenspair.core.report import to_markdown
from lenspair.model.evaluation.evaluate import EvalResult
from lenspair.model.evaluation.latency import Latency
from lenspair.model.evaluation.report import write_report
from lenspair.model.evaluation.seed_statistics import summarise_seeds
from lenspair.model.evaluation.summary import ImageScore, breakdown, summarize
from lenspair.model.evaluation.tradeoff_report import write_tradeoff
from lenspair.model.evaluation.tradeoff_rows import TradeoffRow, mark_pareto
from lenspair.model.evaluation.tradeoff_seeds_report import SeededRow, seeded_markdown
from lenspair.model.training.config import RunConfig, RuntimeInfo

README = Path(__file__).resolve().parents[2] / "README.md"


def _row(name: str, precision: str, cpu_ms: float, psnr: float) -> TradeoffRow:
    return TradeoffRow(
        name=name, variant=name.split("-")[0], width=1.0, num_blocks=9, precision=precision,
        params=700_001, gflops=19.71, cpu_ms=cpu_ms, gpu_ms=None, psnr_db=psnr, ssim=0.8765,
        convention="skimage-gaussian", steps=40,
    )  # fmt: skip


def _demo(root: Path) -> Path:
    """A demo output folder written by the stages' own writers."""
    meta = {
        "dataset": "demo_out/dataset", "evaluated_on": "demo_out/dataset split test",
        "budget": "40 steps", "device": "cpu", "threads": 2, "size": "540x360",
        "convention": "skimage-gaussian",
        "input_baseline": {"psnr_db": 21.234, "ssim": 0.7001},
    }  # fmt: skip
    rows = mark_pareto([_row("G", "fp32", 50.0, 24.5), _row("GEA", "bf16", 43.21, 25.678)])
    write_tradeoff(rows, root / "tradeoff", meta)
    scores = [
        ImageScore("a", "easy", 360, 540, 30.0, 0.95, 27.0, 0.9),
        ImageScore("b", "hard", 360, 540, 22.0, 0.75, 17.5, 0.6),
    ]
    result = EvalResult(
        checkpoint="best.pt", data="ds (split test)", convention="skimage-gaussian",
        precision="fp32", scores=scores, overall=summarize(scores),
        by_difficulty=breakdown(scores), input_overall=summarize(scores, "input"),
        input_by_difficulty=breakdown(scores, "input"),
        latency=[Latency("cpu", "fp32", "540x360", 2, "channels-last", 30, 5, 61.25, 63.0)],
    )  # fmt: skip
    write_report(result, root / "eval")
    (root / "eval" / "contact_sheet.png").write_bytes(b"\x89PNG sheet")
    atomic_write_json(
        root / "timings.json",
        {"simulate-rain": {"seconds": 7.25, "reused": False},
         "pretrain": {"seconds": 60.0, "reused": True}},
    )  # fmt: skip
    return root


RUN = {"id": "20250101T000000Z-abc123", "cpu": "Test CPU", "cores": 2, "threads": 2,
       "onednn_max_cpu_isa": None, "started": "2025-01-01T00:00:00+00:00"}  # fmt: skip
"""The ``benchmark_run`` entry ``python -m benchmarks`` writes into every JSON file."""


def _write(path: Path, record: dict[str, Any], run: dict[str, Any] | None = RUN) -> None:
    """A benchmark's JSON file, stamped as ``python -m benchmarks`` stamps it (None: alone)."""
    atomic_write_json(path, record if run is None else {**record, RUN_KEY: run})


def _bench(root: Path) -> Path:
    root.mkdir(parents=True)
    _write(
        root / "ingest.json",
        {"pairs": 38, "ingest_w1_ms_per_pair": 65.05, "io_floor_ms_per_pair": 33.93,
         "ratio_w1_to_floor": 1.917, "runs": 3},
    )  # fmt: skip
    rows = [
        {"command": command, "frames": frames, "peak_mib": mib, "s": 1.0}
        for frames, mibs in ((500, (150.4, 110.0, 470.0)), (2000, (156.2, 125.0, 474.0)))
        for command, mib in zip(("capture-ingest", "dataset-build", "restore"), mibs, strict=True)
    ]
    ratios = {"capture-ingest": 1.0386, "dataset-build": 1.1364, "restore": 1.0085}
    _write(
        root / "memory.json",
        {"rows": rows, "ratios": ratios, "worst_ratio": 1.1364, "target_ratio": 1.15},
    )
    return root


def _readme(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    readme = folder / "README.md"
    readme.write_text(f"# Title\n\nintro\n\n{BEGIN}\nold text\n{END}\n\n## After\n")
    return readme


def test_section_carries_the_figures_of_the_files(tmp_path: Path) -> None:
    demo, bench = _demo(tmp_path / "demo"), _bench(tmp_path / "bench")
    readme = _readme(tmp_path / "repo")
    args = ["--demo", str(demo), "--bench", str(bench), "--readme", str(readme)]
    assert main(args) == 0
    text = readme.read_text()
    assert text.startswith("# Title\n\nintro\n\n") and text.endswith(f"{END}\n\n## After\n")
    assert "old text" not in text
    # tradeoff rows, the input baseline first, times and accuracy as measured
    assert "| input, no restoration | - | 0 | 0 | 0 | 21.23 | 0.7001 |  |" in text
    assert "| GEA | bf16 | 700,001 | 19.7 | 43.2 | 25.68 | 0.8765 | PSNR SSIM |" in text
    assert "40 steps" in text and "540x360" in text
    # eval: input and output per difficulty, and the latency it was measured with
    assert "| hard | 1 | 17.50 | 22.00 | 0.6000 | 0.7500 |" in text
    assert "| all | 2 | 22.25 | 26.00 |" in text
    assert "| cpu | fp32 | 540x360 | 2 | 61.2 | 63.0 |" in text
    # stage times with their total, reuse said
    assert "| simulate-rain | 7.2 |" in text and "| total | 67.2 |" in text
    assert text.index("| simulate-rain |") < text.index("| pretrain |")  # pipeline order
    assert "earlier run, with that run's time: pretrain" in text
    # benchmark ratio against its floor, with its runs; absent benchmarks name their command
    assert "| 65.0 ms/pair |" in text and "| 1.92x | 3 runs |" in text
    assert "(run 20250101T000000Z-abc123) on Test CPU, 2 CPUs" in text
    # peak memory at the longer recording, as ratios to the shorter one (bench_memory)
    assert (
        "| peak memory at 2000 frames: ingest / dataset-build / restore | 156 MiB / 125 MiB / "
        "474 MiB | the same at 500 frames (target <= 1.15x) | 1.04x / 1.14x / 1.01x |"
    ) in text
    assert "Not measured yet: the calibration comes from `lenspair demo --out demo_out`" in text
    # pictures are copied beside the README and linked relative to it
    assert (tmp_path / "repo" / "docs" / "results" / "contact_sheet.png").read_bytes() == (
        b"\x89PNG sheet"
    )
    assert "](docs/results/tradeoff.png)" in text
    assert (tmp_path / "repo" / "docs" / "results" / "tradeoff.png").is_file()
    # a second run changes nothing, and --check agrees
    assert main(args) == 0 and readme.read_text() == text
    assert main([*args, "--check"]) == 0


def test_check_flags_a_stale_section_and_writes_nothing(tmp_path: Path) -> None:
    demo, bench = _demo(tmp_path / "demo"), _bench(tmp_path / "bench")
    readme = _readme(tmp_path / "repo")
    before = readme.read_text()
    args = ["--demo", str(demo), "--bench", str(bench), "--readme", str(readme), "--check"]
    assert main(args) == 1
    assert readme.read_text() == before
    assert not (tmp_path / "repo" / "docs").exists()


def test_missing_markers_are_a_clear_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(f"# Title\n{END}\n{BEGIN}\n")  # out of order
    assert main(["--readme", str(readme), "--demo", str(tmp_path), "--bench", str(tmp_path)]) == 2
    assert "README.md" in capsys.readouterr().err
    with pytest.raises(Exception, match="markers"):
        replace_section("no markers", "body")


# Units of measured figures. A number with one of these outside the generated
# section was typed by hand and would go stale.
UNITS = r"ms\b|dB\b|s\b|sec|seconds|minutes?|min\b|px\b|%|GFLOP|pairs/s|steps/s|fps|x faster"
MEASURED = re.compile(rf"(?<!\w)\d[\d.,]*\s*(?:{UNITS})", re.IGNORECASE)


def test_readme_figures_outside_the_generated_section_are_not_measurements() -> None:
    text = README.read_text(encoding="utf-8")
    outside = text
    for begin, end in ((BEGIN, END), (DETECTOR_BEGIN, DETECTOR_END)):
        assert outside.count(begin) == 1 and outside.count(end) == 1
        outside = outside[: outside.index(begin)] + outside[outside.index(end) :]
    assert MEASURED.findall(outside) == []


def _detector_figures(path: Path) -> Path:
    scores = {"frames": 128, "positives": 48, "accuracy": 0.671875, "precision": 0.5384,
              "recall": 0.875, "f1": 0.66667, "tile_iou": 0.0969, "confusion": [[0]]}  # fmt: skip
    latency = {"threads": 1, "runs": 20, "median_ms": {"GEA": 318.03, "judge": 4.17},
               "ratio_judge_to_gea": 0.0131, "parameters": {"detector": 81845}}  # fmt: skip
    figures = {
        "command": "python -m benchmarks.train_bundled_detector --minutes 30",
        "training": {"steps": 35132, "seconds": 1800.05},
        "device": "cpu",
        "scores": {"test recordings": scores},
        "hard_cases": [{"name": "defocused frames: clean", "passed": True, "detail": "p 0.01"}],
        "latency": latency,
    }
    atomic_write_json(path, figures)
    return path


def test_detector_only_writes_the_detector_section_from_its_json(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    results = f"{BEGIN}\nkept as it was\n{END}\n"
    readme.write_text(f"# T\n{results}## D\n{DETECTOR_BEGIN}\nold\n{DETECTOR_END}\n")
    figures = _detector_figures(tmp_path / "detector.json")
    bench = tmp_path / "bench"
    argv = ["--readme", str(readme), "--detector", str(figures), "--bench", str(bench)]
    assert main([*argv, "--detector-only", "--check"]) == 1
    assert main([*argv, "--detector-only"]) == 0
    text = readme.read_text()
    assert results in text and "\nold\n" not in text
    assert "| test recordings | 128 | 48 | 0.672 | 0.667 | 0.538 | 0.875 | 0.097 |" in text
    assert "35132 steps in 30 min on `cpu`" in text
    assert "| defocused frames: clean | yes | p 0.01 |" in text
    # the training run timed GEA in NCHW, and the line says so
    assert "4.17 ms with its input preparation, 0.013x GEA's 318 ms (NCHW)" in text
    assert main([*argv, "--detector-only", "--check"]) == 0
    # a benchmark run's bench_detector timed GEA as deployed: its figures are the ones shown
    timed = {
        "threads": 1, "runs": 40, "gea_layout": "channels-last",
        "median_ms": {"GEA": 109.07, "detector": 2.04, "judge": 2.15},
        "ratio_detector_to_gea": 0.0187, "ratio_judge_to_gea": 0.0197,
        "parameters": {"GEA": 708426, "detector": 81845},
        "benchmark_run": {"id": "20261129T102205Z-bf7043", "cpu": "AMD EPYC"},
    }  # fmt: skip
    atomic_write_json(bench / "detector.json", timed)
    assert main([*argv, "--detector-only", "--check"]) == 1
    assert main([*argv, "--detector-only"]) == 0
    assert (
        "median of 40 interleaved runs, benchmark run 20261129T102205Z-bf7043 on AMD EPYC): "
        "2.15 ms with its input preparation, 0.020x GEA's 109 ms (channels-last)"
    ) in readme.read_text()
    figures.unlink()
    assert main([*argv, "--detector-only"]) == 0
    assert "Not measured yet: this section comes from" in readme.read_text()


def _finetune_config(demo: Path, precision: str, reason: str) -> None:
    """The fine-tuning run's config.yaml as the trainer writes it (runtime section included)."""
    runtime = RuntimeInfo(precision=precision, precision_reason=reason, device="cpu")
    config = demo / "runs" / "finetune" / "config.yaml"
    config.parent.mkdir(parents=True)
    config.write_text(dump_yaml(RunConfig(runtime=runtime)))


def _timings(demo: Path, **seconds: float) -> None:
    timings = {
        name.replace("_", "-"): {"seconds": s, "reused": False} for name, s in seconds.items()
    }
    atomic_write_json(demo / "timings.json", timings)


def test_stage_times_stand_beside_the_run_without_native_bf16(tmp_path: Path) -> None:
    native, capped = tmp_path / "demo_out", tmp_path / "demo_out_fp32"
    _timings(native, simulate_rain=8.0, finetune=180.0, tradeoff=200.0)
    _timings(capped, simulate_rain=9.0, finetune=250.0, tradeoff=240.0)
    _finetune_config(native, "bf16 autocast", "auto: fastest native precision")
    _finetune_config(capped, "fp32", "auto: bf16 is not native; ONEDNN_MAX_CPU_ISA caps it")
    text = to_markdown(stage_blocks(native, capped))
    assert "| stage | seconds (demo_out) | seconds (demo_out_fp32, bf16 off) |" in text
    assert "| finetune | 180.0 | 250.0 |" in text
    assert "| total | 388.0 | 499.0 |" in text
    assert "`demo_out`: 6.5 min, trained at bf16 autocast (auto: fastest native precision)" in text
    assert "`demo_out_fp32`: the same demo under `ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI`" in text
    assert "8.3 min, trained at fp32 (auto: bf16 is not native; ONEDNN_MAX_CPU_ISA" in text
    assert "Target: within 15 min on a 2-core CPU; on this machine met." in text
    # one run over the target fails the target for both
    _timings(capped, simulate_rain=9.0, finetune=700.0, tradeoff=240.0)
    assert "Target: within 15 min on a 2-core CPU; on this machine NOT met." in to_markdown(
        stage_blocks(native, capped)
    )
    # no second run (a CPU without bf16 runs the demo once): one column, the same target
    alone = to_markdown(stage_blocks(native, tmp_path / "absent"))
    assert "| stage | seconds (demo_out) |\n" in alone and "bf16 off" not in alone
    assert "| total | 388.0 |" in alone and "met." in alone


def test_speed_table_shows_bf16_against_fp32_with_and_without_the_isa_cap(tmp_path: Path) -> None:
    bench = _bench(tmp_path / "bench")
    rows = [
        {"cap": None, "bf16_over_fp32": 0.553, "median_ms": {"fp32": 9.17, "bf16": 5.07},
         "auto": "bf16", "reason": "native"},
        {"cap": "AVX512_CORE_VNNI", "bf16_over_fp32": 2.718,
         "median_ms": {"fp32": 8.98, "bf16": 24.41}, "auto": "fp32", "reason": "capped"},
    ]  # fmt: skip
    kernel = "3x3 conv 32->32 270x180, 1 thread"
    _write(bench / "isa_cap.json", {"kernel": kernel, "runs": 15, "rows": rows})
    text = to_markdown(bench_blocks(bench))
    assert (
        "| 3x3 conv 32->32 270x180, 1 thread, oneDNN as the CPU is | bf16 5.07 ms / fp32 9.17 ms "
        "| fp32 in the same run; auto trains at bf16 | 0.55x (bf16 / fp32) |"
    ) in text
    assert "oneDNN AVX512_CORE_VNNI | bf16 24.41 ms / fp32 8.98 ms" in text
    assert "auto trains at fp32 | 2.72x (bf16 / fp32) |" in text


def test_seeded_tradeoff_comes_in_as_the_command_wrote_it_with_its_device(tmp_path: Path) -> None:
    row = SeededRow(
        name="GEA", precision="fp32", params=708_426, gflops=19.71, cpu_ms=133.5,
        psnr=summarise_seeds([28.2, 28.5, 28.6]), ssim=summarise_seeds([0.907, 0.9071, 0.9072]),
        converged=False, tail_change_db=1.82, pareto_psnr=True,
    )  # fmt: skip
    meta = {
        "dataset": "ds", "evaluated_on": "ds split test", "budget": "800 steps",
        "seeds": [0, 1, 2], "convention": "skimage-gaussian", "size": "540x360",
        "input_baseline": {"psnr_db": 25.64, "ssim": 0.8953}, "device": "cuda",
    }  # fmt: skip
    markdown = tmp_path / "tradeoff_seeds.md"
    markdown.write_text(seeded_markdown([row], meta))
    atomic_write_json(tmp_path / "tradeoff_seeds.json", {"meta": meta, "rows": []})
    text = to_markdown(seeded_blocks(markdown))
    assert "# Accuracy against inference time" not in text  # the section has its own heading
    assert "trained on cuda" in text and f"`{markdown.as_posix()}`" in text
    assert "| GEA | fp32 | 708,426 | 19.7 | 133.5 | 28.43 +/- 0.21 |" in text
    assert "| no (+1.82 dB) | * |" in text
    assert "800 steps" in text and "does NOT hold for every network" in text
    assert "| state of the art, Raindrop test set | DeRaindrop | 0.921 | 31.50 |" in text
    # several runs: the paper's rows once, after the last
    both = to_markdown(seeded_runs([markdown, markdown]))
    assert both.count("| GEA | fp32 | 708,426 |") == 2 and both.count("| DeRaindrop |") == 1
    assert both.index("| DeRaindrop |") > both.rindex("| GEA | fp32 | 708,426 |")
    missing = to_markdown(seeded_blocks(tmp_path / "absent.md"))
    assert "Not measured yet: the tradeoff over seeds comes from `lenspair tradeoff" in missing


def test_a_speed_ratio_below_one_reads_as_slower() -> None:
    from benchmarks.readme_speed import _speed

    assert _speed(1.43, "fp32") == "1.43x faster than fp32"
    assert _speed(0.85, "fp32 torch") == "1.18x slower than fp32 torch"


def test_int8_rows_show_the_fp32_time_their_ratio_is_against() -> None:
    """The ratio was against bench_int8's own fp32 run, which the table never showed."""
    from benchmarks.readme_speed import _precision_rows

    int8 = {
        "threads": 2,
        "medians_ms": {"fp32 torch": 120.0, "onnxruntime int8": 150.0},
        "speed_vs_fp32": {"onnxruntime int8": 0.8},
        "psnr_vs_fp32_db": {"onnxruntime int8": 39.4},
        "setup_seconds": {"onnxruntime int8": 7.4},
    }
    (row,) = _precision_rows(None, int8)
    assert row[1] == "150.0 ms"
    assert row[3] == "1.25x slower than fp32 torch timed beside it (120.0 ms)"


def _model(**changes: Any) -> dict[str, Any]:
    """bench_model's record under ``ONEDNN_MAX_CPU_ISA=AVX2`` on a bf16 CPU (the review's run)."""
    reason = (
        "auto: bf16 is not native on AMD EPYC (cpu) (emulated bf16 is slower than fp32); "
        "ONEDNN_MAX_CPU_ISA=AVX2 turns off avx512_bf16"
    )
    record = {
        "cpu_model": "AMD EPYC", "torch": "2.13.0+cpu", "threads": 2, "runs": 40, "bf16_runs": 3,
        "size": [360, 540], "fp32_best": "fp32 channels-last", "fp32_ms": 95.0,
        "roofline_ms": 76.1, "peak_gflops": 258.9, "peak_kernel": "conv3x3",
        "fp32_roofline_ratio": 1.248, "bf16_best": "bf16 weights channels-last",
        "bf16_ms": 2656.9, "bf16_psnr_vs_fp32_db": {"bf16 weights channels-last": 51.3},
        "precision": {"precision": "fp32", "requested": "auto", "reason": reason,
                      "native": ["int8", "fp32"], "device": "cpu", "hardware": "AMD EPYC"},
        "onednn_max_cpu_isa": "AVX2", "isa_cap": "ONEDNN_MAX_CPU_ISA=AVX2 turns off avx512_bf16",
        "emulated": ["bf16 weights channels-last"],
    }  # fmt: skip
    return record | changes


def test_rows_under_an_isa_cap_say_so_and_emulated_precisions_are_marked(tmp_path: Path) -> None:
    # rendered "precisions native on this CPU | int8, fp32" and bf16 "27.97x slower than
    # fp32" without a word about the cap or about bf16 being emulated
    bench = tmp_path / "bench"
    bench.mkdir()
    _write(bench / "model.json", _model(), RUN | {"onednn_max_cpu_isa": "AVX2"})
    text = to_markdown(bench_blocks(bench))
    assert (
        "| precisions native on this CPU, oneDNN capped: ONEDNN_MAX_CPU_ISA=AVX2 | int8, fp32 "
        "| lenspair.model.precision (auto: native and measured faster than fp32): auto: bf16 "
        "is not native on AMD EPYC (cpu) (emulated bf16 is slower than fp32); "
        "ONEDNN_MAX_CPU_ISA=AVX2 turns off avx512_bf16 | auto: fp32 |"
    ) in text
    assert (
        "| GEA 540x360 batch 1, bf16 weights channels-last, emulated (bf16 not native under "
        "ONEDNN_MAX_CPU_ISA=AVX2) | 2656.9 ms | PSNR against fp32 output 51.3 dB "
        "| 27.97x slower than fp32 | 2 threads, 3 runs |"
    ) in text
    assert "| GEA 540x360 batch 1, fp32 channels-last | 95.0 ms |" in text
    assert "| 1.25x | 2 threads, 40 runs |" in text
    assert "oneDNN capped at ONEDNN_MAX_CPU_ISA=AVX2" in text.split("|")[0]  # said up front
    # a model.json written before the fields: its native precisions tell
    old = {k: v for k, v in _model().items() if k not in ("onednn_max_cpu_isa", "emulated")}
    _write(bench / "model.json", old)
    text = to_markdown(bench_blocks(bench))
    assert "bf16 weights channels-last, emulated (bf16 not native) |" in text
    # where bf16 is native, nothing is marked
    native = _model(emulated=[], onednn_max_cpu_isa=None)
    native["precision"] = native["precision"] | {"native": ["int8", "bf16", "fp32"]}
    _write(bench / "model.json", native)
    text = to_markdown(bench_blocks(bench))
    assert "emulated (" not in text and "capped" not in text


def test_files_of_different_runs_are_refused_naming_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # model.json from a run under an ISA cap beside int8.json from a run alone were
    # combined, and the section said "measured in the same run"
    demo, bench = _demo(tmp_path / "demo"), _bench(tmp_path / "bench")
    readme = _readme(tmp_path / "repo")
    before = readme.read_text()
    args = ["--demo", str(demo), "--bench", str(bench), "--readme", str(readme)]
    _write(bench / "model.json", _model(), RUN | {"id": "20250102T000000Z-def456"})
    assert main(args) == 2
    error = capsys.readouterr().err
    assert len(error.strip().splitlines()) == 1
    assert "model.json (20250102T000000Z-def456)" in error
    assert "ingest.json (20250101T000000Z-abc123)" in error and "different runs" in error
    assert readme.read_text() == before
    # a benchmark run on its own writes no run id: not the same run either
    _write(bench / "model.json", _model(), None)
    assert main(args) == 2
    assert "model.json (no run id)" in capsys.readouterr().err
    # one run, but a benchmark of it started on a busy CPU: its ratios are not the machine's
    _write(bench / "model.json", _model(), RUN | {"busy_at_start": {"bench_model": 45.0}})
    assert main(args) == 2
    error = capsys.readouterr().err
    assert "started on a busy CPU (pressure at start: bench_model (45 %))" in error
    assert readme.read_text() == before
    # all of one run: written
    _write(bench / "model.json", _model())
    assert main(args) == 0


def test_calibration_rows_take_the_median_of_the_per_run_sums(tmp_path: Path) -> None:
    # the "median" column was the sum of two medians, which is not a median
    bench = tmp_path / "bench"
    bench.mkdir()
    case = {"board": "chessboard:9x6:0.06", "model": "pinhole-equi", "views": 30,
            "detect_ms": 400.0, "calibrate_ms": 350.0, "focal_error_pct": 0.019,
            "baseline_error_pct": 0.009, "row_disagreement_px": 0.049, "stereo_rms_px": 0.06,
            "repeats": 3, "opencv_threads": 2}  # fmt: skip
    _write(bench / "calibration.json", {"cases": [case | {"detect_calibrate_ms": 741.0}]})
    text = to_markdown(bench_blocks(bench))
    assert (
        "| calibrate chessboard pinhole-equi, 30 views: detection + calibration | 741 ms |"
    ) in text
    assert "| stereo RMS 0.060 px | 2 threads, 3 runs |" in text
    _write(bench / "calibration.json", {"cases": [case]})  # written before the per-run sum
    text = to_markdown(bench_blocks(bench))
    assert "| 750 ms (sum of the detection and calibration medians) |" in text


def test_every_relative_link_of_the_readme_and_its_docs_resolves() -> None:
    # a run's page embedded from docs/results/ kept its link [gpu_h100.md](gpu_h100.md),
    # which pointed beside the README, where there is no such file
    link = re.compile(r"\]\((?![a-z][a-z0-9+.-]*:|#)([^)\s#]+)[^)]*\)")
    pages = [README, *sorted((README.parent / "docs").rglob("*.md"))]
    broken = [
        f"{page.relative_to(README.parent)}: {target}"
        for page in pages
        for target in link.findall(page.read_text(encoding="utf-8"))
        if not (page.parent / target).exists()
    ]
    assert broken == []


def test_an_embedded_pages_relative_links_are_made_the_readmes(tmp_path: Path) -> None:
    page = tmp_path / "docs" / "results" / "tradeoff_seeds_gpu.md"
    page.parent.mkdir(parents=True)
    page.write_text("# Tradeoff\n\n- data: x ([gpu.md](gpu.md)), [web](https://a.b) [here](#x)\n")
    text = to_markdown(seeded_blocks(page))
    assert f"([gpu.md]({page.parent.as_posix()}/gpu.md))" in text
    assert "[web](https://a.b)" in text and "[here](#x)" in text


def test_the_training_row_sets_the_fp32_step_against_its_roofline() -> None:
    # bench_training measured the step's roofline, and the README's row left it out
    from benchmarks.readme_speed import _training_rows

    training = {
        "batch": 8, "crop": 256, "threads": 2, "steps": 5,
        "steps_per_second": {"fp32": 0.2}, "speed_vs_fp32": {"fp32": 1.0},
        "fp32_roofline_seconds": 3.4, "fp32_step_gflop": 561.2, "fp32_roofline_ratio": 1.45,
    }  # fmt: skip
    (row,) = _training_rows(training, None)
    assert row[2] == "fp32 step; its roofline 3.40 s (561 GFLOP at the run's peak)"
    assert row[3].endswith("(speed vs fp32); fp32 1.45x its roofline")
    older = {k: v for k, v in training.items() if "roofline" not in k and "gflop" not in k}
    (row,) = _training_rows(older, None)  # a run before the roofline was measured
    assert row[2] == "fp32 step" and row[3].endswith("(speed vs fp32)")
