"""Every subcommand on a few frames, chained as a user runs them (``lenspair demo --quick``)."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.cli import main
from lenspair.core.imageio import read_image
from lenspair.demo import QUICK, plan
from lenspair.model.precision import choose_precision
from lenspair.model.training.config_loading import load_run_config

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--out", str(out), "--quick"]) == 0
    return out


def test_demo_runs_every_stage_and_writes_the_report(demo_out: Path) -> None:
    timings = json.loads((demo_out / "timings.json").read_text())
    assert sorted(timings) == sorted(stage.name for stage in plan(demo_out, QUICK))
    report = (demo_out / "report.md").read_text()
    sections = (
        "Calibration",
        "Ingest",
        "Dataset",
        "Evaluation",
        "Accuracy against time",
        "Restore",
    )
    for section in sections:
        assert f"## {section}" in report
    assert "<table>" in (demo_out / "report.html").read_text()
    # what made it, --quick included: the full demo would not reproduce these figures
    assert report.count(f"lenspair demo --out {demo_out} --quick") == 2  # --out as given
    runtime = load_run_config(demo_out / "runs" / "finetune" / "config.yaml").runtime
    assert runtime is not None  # the report says where training ran and why at that precision
    assert f"at {runtime.precision} (natively: " in report and runtime.precision_reason in report
    for picture in ("eval/contact_sheet.png", "tradeoff/tradeoff.png", "restore_before_after.png"):
        assert picture in report and (demo_out / picture).is_file()


def test_ingested_pairs_are_540x360_and_accounted_for(demo_out: Path) -> None:
    for name, obstructed in (("rain", "cam1"), ("heavy_rain", "cam1"), ("dust_swapped", "cam0")):
        folder = demo_out / "ingested" / name
        report = json.loads((folder / "report.json").read_text())
        assert report["obstructed"] == obstructed
        lines = (folder / "pairs.jsonl").read_text().splitlines()
        frames = len(
            list((demo_out / "recordings" / name / "mav0" / obstructed / "data").glob("*.png"))
        )
        assert len(lines) == frames  # one line per obstructed input frame
        kept = [json.loads(line) for line in lines if '"kept"' in line]
        assert kept, f"{name}: no pair kept"
        image = read_image(folder / kept[0]["files"]["input"])
        assert image.shape[:2] == (360, 540)


def test_dataset_tracks_the_clean_side_and_spans_the_difficulties(demo_out: Path) -> None:
    rows = [
        json.loads(line)
        for line in (demo_out / "dataset" / "manifest.jsonl").read_text().splitlines()
    ]
    sides = {(row["recording"], row["clean"]) for row in rows}
    assert sides == {("rain", "cam0"), ("heavy_rain", "cam0"), ("dust_swapped", "cam1")}
    # light rain and dust give easy pairs, the heavy rain the harder ones
    by_recording = {row["recording"]: set() for row in rows}
    for row in rows:
        by_recording[row["recording"]].add(row["difficulty"])
    assert by_recording["rain"] == by_recording["dust_swapped"] == {"easy"}
    assert by_recording["heavy_rain"] & {"medium", "hard"}


def test_rerun_reuses_finished_stages(demo_out: Path) -> None:
    before = (demo_out / "report.md").stat().st_mtime_ns
    assert main(["demo", "--out", str(demo_out), "--quick"]) == 0
    timings = json.loads((demo_out / "timings.json").read_text())
    assert all(entry["reused"] for entry in timings.values())
    assert (demo_out / "report.md").stat().st_mtime_ns >= before


def test_eval_and_export_of_the_fine_tuned_checkpoint(demo_out: Path, tmp_path: Path) -> None:
    checkpoint = demo_out / "runs" / "finetune" / "checkpoints" / "best.pt"
    metrics = json.loads((demo_out / "eval" / "metrics.json").read_text())
    assert "convention" in json.dumps(metrics)
    assert main(["export", str(checkpoint), "--torchscript", str(tmp_path / "m.pt")]) == 0
    assert (tmp_path / "m.pt").stat().st_size > 0
    rows = json.loads((demo_out / "tradeoff" / "tradeoff.json").read_text())["rows"]
    assert {row["name"] for row in rows} >= {"G", "GE", "GEA", "GEA-w0.5", "GEA-w2", "GEA-b3"}
    # GEA again at each native reduced precision (bf16 only where native; no int8 in --quick).
    native = choose_precision("auto", torch.device("cpu"), "infer").native
    expected = {"fp32"} | ({"bf16"} & set(native))
    assert {row["precision"] for row in rows if row["name"] == "GEA"} == expected
    assert all(np.isfinite(row["psnr_db"]) and row["cpu_ms"] > 0 for row in rows)
