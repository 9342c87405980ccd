import csv
import json
import math
import os
import platform
import shutil
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
import torch

from lenspair.cli import main
from lenspair.core.imagewrite import write_image
from lenspair.dataset.manifest import ManifestRow, write_manifest
from lenspair.dataset.readers import open_paired
from lenspair.model.checkpoint import load_model
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.evaluate import PSNR_CAP_DB, evaluate_checkpoint
from lenspair.model.evaluation.latency import measure_latency, tune_allocator
from lenspair.model.evaluation.report import _agreement_pairs, write_report
from lenspair.model.evaluation.scoring import agreement_with_fp32, score_pairs
from lenspair.model.evaluation.summary import ImageScore, summarize
from lenspair.model.metrics import MetricConvention, image_metrics
from lenspair.model.networks.variants import build_model
from lenspair.model.training.pairs import to_tensor
from tests.file_limits import REFUSALS, refuse_writes
from tests.model.train_fixtures import (
    clean_image,
    make_checkpoint,
    obstruct,
    write_paired_folder,
    write_split_dataset,
)

CPU = torch.device("cpu")


pytestmark = pytest.mark.usefixtures("one_thread")


def _expected(checkpoint: Path, folder: Path, convention: str) -> list[tuple[float, float]]:
    """Recompute the scores independently: model output rounded to 8 bits, model.metrics."""
    network = load_model(checkpoint).network
    scores = []
    for item in open_paired(folder):
        x = to_tensor(item.input, 1)[None]
        target = to_tensor(item.target, 1)[None]
        with torch.no_grad():
            output = network(x)[1]
        output = torch.round(output.clamp(0, 1) * 255) / 255
        result = image_metrics(output, target, MetricConvention(convention))
        scores.append((float(result.psnr[0]), float(result.ssim[0])))
    return scores


@pytest.mark.parametrize("convention", ["skimage-gaussian", "deraindrop-y"])
def test_eval_cli_writes_reports_that_match_model_metrics(tmp_path: Path, convention: str) -> None:
    folder = write_paired_folder(tmp_path / "pairs", count=3)
    checkpoint = make_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")
    out = tmp_path / "eval"
    args = ["eval", str(checkpoint), "--data", str(folder), "--out", str(out)]
    assert main([*args, "--convention", convention, "--latency-runs", "2", "--device", "cpu"]) == 0

    with (out / "per_image.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    expected = _expected(checkpoint, folder, convention)
    assert [r["name"] for r in rows] == ["000", "001", "002"]
    for row, (psnr, ssim) in zip(rows, expected, strict=True):
        assert row["convention"] == convention
        assert float(row["psnr_db"]) == pytest.approx(psnr, abs=1e-6)
        assert float(row["ssim"]) == pytest.approx(ssim, abs=1e-8)
    means = json.loads((out / "metrics.json").read_text())
    assert means["convention"] == convention
    assert means["model"]["variant"] == "GEA"
    assert means["overall"]["pairs"] == 3
    assert means["overall"]["psnr_db"] == pytest.approx(np.mean([p for p, _ in expected]))
    assert means["overall"]["ssim"] == pytest.approx(np.mean([s for _, s in expected]))
    assert means["latency"][0]["device"] == "cpu"
    assert means["latency"][0]["threads"] == 1
    assert means["latency"][0]["size"] == "48x32"
    markdown = (out / "metrics.md").read_text()
    assert convention in markdown and "Latency" in markdown
    assert (out / "contact_sheet.png").stat().st_size > 0


def test_eval_cli_reads_the_checkpoint_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # it was read twice: once to check it before the precision line, once to evaluate
    import lenspair.model.checkpoint as checkpoints

    folder = write_paired_folder(tmp_path / "pairs", count=1)
    checkpoint = make_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")
    reads: list[Path] = []
    original = checkpoints.load_checkpoint

    def counted(path: Path) -> dict[str, object]:
        reads.append(Path(path))
        return original(path)

    monkeypatch.setattr(checkpoints, "load_checkpoint", counted)
    assert main(["eval", str(checkpoint), "--data", str(folder), "--latency-runs", "0"]) == 0
    assert reads == [checkpoint]


def test_int8_eval_scores_against_target_and_fp32(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    folder = write_paired_folder(tmp_path / "pairs", count=3)
    calibration = write_paired_folder(tmp_path / "calibration", count=4, seed=7)
    checkpoint = make_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")
    out = tmp_path / "eval"
    args = ["eval", str(checkpoint), "--data", str(folder), "--out", str(out), "--device", "cpu"]
    calibrate = ["--calibration", str(calibration)]
    assert main([*args, "--precision", "int8", *calibrate, "--latency-runs", "2"]) == 0
    means = json.loads((out / "metrics.json").read_text())
    assert means["precision"] == "int8"
    assert "requested" in means["precision_reason"]
    versus = means["versus_fp32"]
    assert versus["pairs"] == 3 and 25.0 < versus["psnr_db"] < 100.0
    fp32 = np.mean([p for p, _ in _expected(checkpoint, folder, "skimage-gaussian")])
    # The int8 output is scored against the target too, close to the fp32 score.
    assert abs(means["overall"]["psnr_db"] - fp32) < 3.0
    assert means["latency"][0]["precision"] == "int8"
    assert means["latency"][0]["layout"] == "NCHW (onnxruntime)"
    assert "agreement with the fp32 output" in (out / "metrics.md").read_text()
    # why this precision (emulated or not) is in the report a reader opens, not only the JSON
    said = f"- inference precision: int8 ({means['precision_reason']})"
    assert said in (out / "metrics.md").read_text()


def test_default_eval_folder_sits_in_the_run(tmp_path: Path) -> None:
    folder = write_paired_folder(tmp_path / "pairs", count=1)
    checkpoint = make_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")
    assert main(["eval", str(checkpoint), "--data", str(folder), "--latency-runs", "0"]) == 0
    assert (tmp_path / "run" / "eval_best_pairs" / "metrics.json").is_file()  # no split
    # another checkpoint of the run, or other data, does not replace that evaluation
    last = make_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")
    assert main(["eval", str(last), "--data", str(folder), "--latency-runs", "0"]) == 0
    other = write_paired_folder(tmp_path / "more", count=1)
    assert main(["eval", str(checkpoint), "--data", str(other), "--latency-runs", "0"]) == 0
    written = sorted(p.name for p in (tmp_path / "run").glob("eval_*"))
    assert written == ["eval_best_more", "eval_best_pairs", "eval_last_pairs"]
    # a dataset's split is named too
    dataset = tmp_path / "ds"
    write_paired_folder(dataset / "val", count=1)
    args = ["--data", str(dataset), "--split", "val", "--latency-runs", "0"]
    assert main(["eval", str(checkpoint), *args]) == 0
    assert (tmp_path / "run" / "eval_best_ds_val" / "metrics.json").is_file()
    # and another precision: an int8 evaluation replaced the fp32 one
    assert main(["eval", str(checkpoint), *args, "--precision", "bf16"]) == 0
    assert (tmp_path / "run" / "eval_best_ds_val_bf16" / "metrics.json").is_file()
    # and the other metric convention: deraindrop-y replaced the default's results
    assert main(["eval", str(checkpoint), *args, "--convention", "deraindrop-y"]) == 0
    y = json.loads(
        (tmp_path / "run" / "eval_best_ds_val_deraindrop-y" / "metrics.json").read_text()
    )
    default = json.loads((tmp_path / "run" / "eval_best_ds_val" / "metrics.json").read_text())
    assert (y["convention"], default["convention"]) == ("deraindrop-y", "skimage-gaussian")
    # a dataset of the same name elsewhere: its own folder, reused by its own reruns
    namesake = tmp_path / "elsewhere" / "ds"
    write_paired_folder(namesake / "val", count=2)
    elsewhere = ["--data", str(namesake), "--split", "val", "--latency-runs", "0"]
    for _ in range(2):
        assert main(["eval", str(checkpoint), *elsewhere]) == 0
        assert main(["eval", str(checkpoint), *args]) == 0
    first, second = (tmp_path / "run" / name for name in ("eval_best_ds_val", "eval_best_ds_val_2"))
    assert json.loads((first / "metrics.json").read_text())["overall"]["pairs"] == 1
    assert json.loads((second / "metrics.json").read_text())["overall"]["pairs"] == 2
    assert not (tmp_path / "run" / "eval_best_ds_val_3").exists()


def test_a_reduced_precision_is_timed_beside_fp32(tmp_path: Path) -> None:
    # eval --precision int8 or bf16 showed its cost against fp32, not what it saves in time:
    # the fp32 row needed a second eval
    folder = write_paired_folder(tmp_path / "pairs", count=2)
    checkpoint = make_checkpoint(tmp_path / "gea.pt")
    cpu = {"bf16": [], "fp32": []}
    for precision in cpu:
        result = evaluate_checkpoint(checkpoint, folder, "test", CPU, precision=precision,
                                     latency_runs=2)  # fmt: skip
        cpu[precision] = [lat.precision for lat in result.latency if lat.device == "cpu"]
    assert cpu == {"bf16": ["bf16", "fp32"], "fp32": ["fp32"]}
    table = write_report(result, tmp_path / "out")["markdown"].read_text()
    assert table.count("| cpu | fp32 |") == 1


def test_odd_sizes_and_identical_images(tmp_path: Path) -> None:
    folder = tmp_path / "odd"
    rng = np.random.default_rng(0)
    image = clean_image(rng, 33, 47)
    write_image(folder / "input" / "same.png", image)
    write_image(folder / "target" / "same.png", image)
    write_image(folder / "input" / "drops.png", obstruct(image, rng))
    write_image(folder / "target" / "drops.png", image)
    # An untrained network is the identity (zero-initialised residual heads).
    checkpoint = make_checkpoint(tmp_path / "id.pt", perturb=False)
    result = evaluate_checkpoint(checkpoint, folder, "test", CPU, latency_runs=2)
    by_name = {s.name: s for s in result.scores}
    assert (by_name["same"].height, by_name["same"].width) == (33, 47)
    assert math.isinf(by_name["same"].psnr_db)
    assert math.isfinite(by_name["drops"].psnr_db)
    assert result.overall.capped == 1
    expected = (PSNR_CAP_DB + by_name["drops"].psnr_db) / 2
    assert result.overall.psnr_db == pytest.approx(expected)
    assert result.latency[0].size == "47x33"
    # the identity restores nothing: its output scores are the input's own
    drops = by_name["drops"]
    assert (drops.psnr_db, drops.ssim) == pytest.approx((drops.input_psnr_db, drops.input_ssim))
    assert result.input_overall == result.overall
    files = write_report(result, tmp_path / "out")
    assert "inf" in files["csv"].read_text()
    assert json.loads(files["json"].read_text())["overall"]["capped"] == 1
    assert f"as {PSNR_CAP_DB:g} dB" in files["markdown"].read_text()
    # the input column's capped image is counted too (only the output's was)
    assert "1 output(s) and 1 input(s) were capped" in files["markdown"].read_text()


def test_a_finite_psnr_above_the_cap_is_counted_as_capped() -> None:
    # a few codes apart in a 16-bit image: 101 dB, counted as 100 in the mean, and the
    # table said "0 output(s) were capped"
    scores = [
        ImageScore("near", None, 8, 8, PSNR_CAP_DB + 1.0, 1.0, PSNR_CAP_DB + 1.0, 1.0),
        ImageScore("same", None, 8, 8, math.inf, 1.0, 30.0, 0.9),
        ImageScore("drops", None, 8, 8, 30.0, 0.9, 20.0, 0.8),
    ]
    overall = summarize(scores)
    assert overall.capped == 2 and overall.psnr_db == pytest.approx((2 * PSNR_CAP_DB + 30) / 3)
    assert summarize(scores, "input").capped == 1


def _spoil(folder: Path) -> None:
    """Truncate pair 000's input, give 002 a target of another size, make 005 too small.

    005 (10x10) is large enough for the network (8 px) but not for SSIM's 11x11 window.
    """
    first = folder / "input" / "000.png"
    first.write_bytes(first.read_bytes()[:60])
    rng = np.random.default_rng(3)
    write_image(folder / "target" / "002.png", clean_image(rng, 20, 24))
    small = clean_image(rng, 10, 10)
    write_image(folder / "input" / "005.png", obstruct(small, rng))
    write_image(folder / "target" / "005.png", small)


@pytest.mark.parametrize("precision", ["fp32", "int8"])
def test_a_bad_pair_costs_only_itself_and_is_reported(tmp_path: Path, precision: str) -> None:
    if precision == "int8":
        pytest.importorskip("onnxruntime")
    folder = write_paired_folder(tmp_path / "pairs", count=5)
    expected = dict(
        zip(
            ["000", "001", "002", "003", "004"],
            _expected(make_checkpoint(tmp_path / "ckpt.pt"), folder, "skimage-gaussian"),
            strict=True,
        )
    )
    _spoil(folder)
    checkpoint = tmp_path / "ckpt.pt"
    out = tmp_path / "eval"
    args = ["eval", str(checkpoint), "--data", str(folder), "--out", str(out), "--device", "cpu"]
    assert main([*args, "--precision", precision, "--latency-runs", "1"]) == 0

    with (out / "per_image.csv").open() as handle:
        rows = {r["name"]: float(r["psnr_db"]) for r in csv.DictReader(handle)}
    assert sorted(rows) == ["001", "003", "004"]
    if precision == "fp32":
        for name, psnr in rows.items():
            assert psnr == pytest.approx(expected[name][0], abs=1e-6)
    means = json.loads((out / "metrics.json").read_text())
    assert means["overall"]["pairs"] == 3
    unread = means["unread"]
    assert [u["index"] for u in unread] == [0, 2, 5]
    assert "000.png" in unread[0]["reason"] and "002.png" in unread[1]["reason"]
    assert unread[2]["reason"].startswith("005: ") and "window" in unread[2]["reason"]
    if precision == "int8":
        assert means["versus_fp32"]["pairs"] == 3
    markdown = (out / "metrics.md").read_text()
    assert "3 pair(s) could not be read or scored" in markdown and "000.png" in markdown
    assert means["latency"][0]["size"] == "48x32"  # from the first scored pair


def test_latency_is_timed_at_a_scored_pair_when_the_first_is_too_small(tmp_path: Path) -> None:
    folder = write_paired_folder(tmp_path / "pairs", count=3)
    tiny = clean_image(np.random.default_rng(1), 4, 4)  # under the network's 8 px: left out
    write_image(folder / "input" / "000.png", tiny)
    write_image(folder / "target" / "000.png", tiny)
    checkpoint = make_checkpoint(tmp_path / "ckpt.pt")
    out = tmp_path / "eval"
    args = ["eval", str(checkpoint), "--data", str(folder), "--out", str(out), "--device", "cpu"]
    assert main([*args, "--latency-runs", "1"]) == 0  # it scored the rest, then failed timing
    means = json.loads((out / "metrics.json").read_text())
    assert means["overall"]["pairs"] == 2 and means["latency"][0]["size"] == "48x32"


def test_eval_with_no_readable_pair_is_one_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = write_paired_folder(tmp_path / "pairs", count=1)
    (folder / "target" / "000.png").write_bytes(b"not a png")
    checkpoint = make_checkpoint(tmp_path / "ckpt.pt")
    assert main(["eval", str(checkpoint), "--data", str(folder), "--latency-runs", "0"]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "none of the 1 pairs can be read" in error and "000.png" in error
    small = clean_image(np.random.default_rng(1), 10, 10)  # the network's 8 px, not SSIM's 11
    write_image(folder / "input" / "000.png", small)
    write_image(folder / "target" / "000.png", small)
    assert main(["eval", str(checkpoint), "--data", str(folder), "--latency-runs", "0"]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "none of the 1 pairs can be scored" in error and "window" in error


def _row(name: str, difficulty: str) -> ManifestRow:
    return ManifestRow(
        split="test", name=name, recording="rec", group="rec", t_ns=0, obstructed="cam0",
        clean="cam1", difficulty=difficulty, psnr_db=20.0, anomaly_fraction=0.1,  # type: ignore[arg-type]
        sharpness=100.0, saturated=0.0, black=0.0, mask_fraction=0.0,
    )  # fmt: skip


def test_breakdown_by_difficulty_from_the_manifest(tmp_path: Path) -> None:
    dataset = tmp_path / "ds"
    difficulties = {"a": "easy", "b": "hard", "c": "medium", "d": "hard"}
    rng = np.random.default_rng(1)
    for name in difficulties:
        image = clean_image(rng)
        write_image(dataset / "test" / "input" / f"{name}.png", obstruct(image, rng))
        write_image(dataset / "test" / "target" / f"{name}.png", image)
    write_manifest(dataset / "manifest.jsonl", [_row(n, d) for n, d in difficulties.items()])
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    result = evaluate_checkpoint(checkpoint, dataset, "test", CPU, latency_runs=0)
    assert list(result.by_difficulty) == ["easy", "medium", "hard"]
    assert result.by_difficulty["hard"].pairs == 2
    hard = [s for s in result.scores if s.difficulty == "hard"]
    assert result.by_difficulty["hard"] == summarize(hard)
    assert result.input_by_difficulty["hard"] == summarize(hard, "input")
    assert result.input_by_difficulty["hard"].psnr_db == pytest.approx(
        float(np.mean([s.input_psnr_db for s in hard]))
    )
    assert result.input_by_difficulty["hard"].psnr_db != result.by_difficulty["hard"].psnr_db
    assert [row.difficulty for row in result.samples] == ["easy", "medium", "hard", "hard"]
    # each sheet row names its difficulty and shows input and output PSNR side by side
    by_name = {s.name: s for s in result.scores}
    for row in result.samples:
        score = by_name[row.labels[2].removeprefix("target ")]
        assert row.labels[0] == f"{score.difficulty} input {score.input_psnr_db:.2f} dB"
        assert row.labels[1] == f"output {score.psnr_db:.2f} dB"
    markdown = write_report(result, tmp_path / "out")["markdown"].read_text()
    assert "| hard | 2 |" in markdown
    assert "skimage-gaussian" in markdown


def test_describe_prints_parameters_and_flops(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    assert main(["eval", str(checkpoint), "--describe"]) == 0
    text = capsys.readouterr().out
    assert "parameters" in text and "GFLOPs at 540x360" in text


def test_latency_is_a_median_of_timed_runs() -> None:
    latency = measure_latency(build_model("G", 1, 0.25, 1), 1, CPU, (24, 40), runs=5, warmup=1)
    assert latency.runs == 5 and latency.warmup == 1 and latency.threads == 1
    assert 0 < latency.median_ms <= latency.p90_ms
    assert latency.size == "40x24" and latency.precision == "fp32"
    assert "threads" in latency.summary() and "batch" not in latency.summary()
    assert latency.batch == 1
    bf16 = measure_latency(build_model("GEA", 1, 0.25, 1), 1, CPU, (24, 40), "bf16", 1, 2)
    assert bf16.precision == "bf16"


@pytest.mark.parametrize(("device", "timed"), [("cpu", ["cpu"]), ("cuda:1", ["cpu", "cuda:1"])])
def test_latency_is_timed_on_cuda_only_when_the_device_is(
    monkeypatch: pytest.MonkeyPatch, device: str, timed: list[str]
) -> None:
    # --device cpu on a machine with a GPU timed the GPU too, moving the network onto it
    from lenspair.model.evaluation import evaluate

    seen: list[str] = []

    def measure(network: object, channels: int, where: torch.device, *rest: object, **kw: object):
        seen.append(str(where))
        return where

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(evaluate, "measure_latency", measure)
    network = build_model("G", 1, 0.25, 1)
    evaluate._deployed_latency(network, network, 1, torch.device(device), (24, 40), "fp32", 2)
    assert seen == timed


class _Shapes(torch.nn.Module):
    """Records the shape of every input (in the class: the CPU times a copy); returns it."""

    seen: ClassVar[list[tuple[int, ...]]] = []

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        _Shapes.seen.append(tuple(x.shape))
        return x


def test_a_batch_is_timed_as_one_forward_pass_and_gives_images_per_second() -> None:
    network = _Shapes()
    _Shapes.seen.clear()
    latency = measure_latency(network, 3, CPU, (24, 40), runs=4, warmup=1, batch=5)
    assert _Shapes.seen == [(5, 3, 24, 40)] * 5  # one warm-up and four timed passes
    assert latency.batch == 5 and "batch 5" in latency.summary()
    assert latency.images_per_second == pytest.approx(5 * 1000.0 / latency.median_ms)
    with pytest.raises(ModelError, match="batch >= 1"):
        measure_latency(network, 3, CPU, (24, 40), runs=1, batch=0)


def test_cpu_latency_times_a_channels_last_copy_and_leaves_the_network_alone() -> None:
    network = build_model("GEA", 1, 0.25, 1)
    first = next(p for p in network.parameters() if p.ndim == 4)
    latency = measure_latency(network, 1, CPU, (24, 40), runs=2, warmup=1)
    assert latency.layout == "channels-last"
    assert "channels-last" in latency.summary()
    assert first.is_contiguous()  # the caller's weights keep their NCHW layout
    assert tune_allocator() is (platform.libc_ver()[0] == "glibc")


def test_a_mono_network_on_colour_pairs_says_so(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from lenspair.model.evaluation.evaluate import evaluate_checkpoint
    from tests.model.train_fixtures import make_checkpoint, write_paired_folder

    checkpoint = make_checkpoint(tmp_path / "mono.pt")  # a 1-channel network
    colour = write_paired_folder(tmp_path / "rgb", count=2, rgb=True)
    with caplog.at_level("WARNING"):
        evaluate_checkpoint(checkpoint, colour, "test", torch.device("cpu"), latency_runs=0)
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert any("1 channel(s)" in m and "have 3" in m and "luma" in m for m in warned), warned
    # the written report says it too: read later, its scores are of luma, not of colour
    out = tmp_path / "eval"
    assert main(["eval", str(checkpoint), "--data", str(colour), "--out", str(out),
                 "--latency-runs", "0"]) == 0  # fmt: skip
    conversion = json.loads((out / "metrics.json").read_text())["conversion"]
    assert conversion.startswith("2 of 2 pair(s)") and "converted (to luma)" in conversion
    assert f"- channels: {conversion}" in (out / "metrics.md").read_text()


@pytest.mark.parametrize("layout", ["dataset", "folder"])
def test_int8_eval_calibrates_off_the_scored_images_where_it_can(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], layout: str
) -> None:
    pytest.importorskip("onnxruntime")
    from lenspair.model.evaluation import quantize

    counts = {"train": 5, "val": 1, "test": 2}
    if layout == "dataset":
        data = write_split_dataset(tmp_path / "ds", counts)
    else:
        data = write_paired_folder(tmp_path / "pairs", count=2)
    sizes: list[int] = []
    real = quantize.calibration_images

    def record(pairs: Any, *args: Any, **kwargs: Any) -> list[np.ndarray]:
        sizes.append(len(pairs))
        return real(pairs, *args, **kwargs)

    monkeypatch.setattr(quantize, "calibration_images", record)
    checkpoint = make_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")
    args = ["eval", str(checkpoint), "--data", str(data), "--out", str(tmp_path / "eval")]
    assert main([*args, "--device", "cpu", "--precision", "int8", "--latency-runs", "1"]) == 0
    printed = capsys.readouterr().out
    # the written report says what int8 was calibrated on, not only the console
    said = json.loads((tmp_path / "eval" / "metrics.json").read_text())["calibration"]
    assert f"- int8 calibrated on: {said}" in (tmp_path / "eval" / "metrics.md").read_text()
    if layout == "dataset":  # the train split's 5 pairs, not the 2 scored test pairs
        assert sizes == [counts["train"]] and "split train" in printed
        assert said.startswith(str(data / "train")) and "its 5 pairs" in said
    else:  # nothing else to calibrate on: the scored pairs, and the output says so
        assert sizes == [2] and "optimistic" in printed
        assert said.startswith("the evaluated pairs themselves") and "optimistic" in said
    if layout == "dataset":  # no train split: another unscored one, said after it opened
        shutil.rmtree(data / "train")
        sizes.clear()
        assert main([*args, "--precision", "int8", "--latency-runs", "1", "--split", "test"]) == 0
        assert sizes == [counts["val"]] and "split val" in capsys.readouterr().out


def test_an_untimed_evaluation_says_so(tmp_path: Path) -> None:
    """--latency-runs 0 left the report without a time and without a word about it."""
    folder = write_paired_folder(tmp_path / "pairs", count=1)
    checkpoint = make_checkpoint(tmp_path / "ck.pt")
    out = tmp_path / "eval"
    argv = ["eval", str(checkpoint), "--data", str(folder), "--out", str(out)]
    assert main([*argv, "--latency-runs", "0"]) == 0
    assert "Not timed (`--latency-runs 0`)" in (out / "metrics.md").read_text()
    assert main([*argv, "--latency-runs", "1"]) == 0
    assert "Not timed" not in (out / "metrics.md").read_text()


def test_an_eval_folder_inside_the_pairs_scored_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # its contact sheet became an unpaired input: the next evaluation refused the data
    folder = write_paired_folder(tmp_path / "pairs", count=1)
    checkpoint = make_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")
    argv = ["eval", str(checkpoint), "--data", str(folder), "--latency-runs", "0", "--out"]
    assert main([*argv, str(folder / "input")]) == 2
    assert "inside the pairs scored" in capsys.readouterr().err
    assert not (folder / "input" / "metrics.json").exists()
    dataset = tmp_path / "ds"
    write_paired_folder(dataset / "test", count=1)
    write_paired_folder(dataset / "train", count=1)
    ds_argv = ["eval", str(checkpoint), "--data", str(dataset), "--latency-runs", "0", "--out"]
    assert main([*ds_argv, str(dataset / "eval_best")]) == 0  # beside the splits: fine
    # another split's images took the report: the next train refused the dataset
    capsys.readouterr()
    assert main([*ds_argv, str(dataset / "train" / "input")]) == 2
    assert "inside the image folder" in capsys.readouterr().err
    assert not (dataset / "train" / "input" / "metrics.json").exists()


def test_colour_pairs_among_grey_ones_are_said_converted(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # the conversion was said only when the first pair needed it
    folder = write_paired_folder(tmp_path / "pairs", count=2)
    colour = write_paired_folder(tmp_path / "colour", count=1, seed=5, rgb=True)
    for side in ("input", "target"):
        shutil.copyfile(colour / side / "000.png", folder / side / "zzz.png")
    checkpoint = make_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")  # mono
    with caplog.at_level("WARNING"):
        assert main(["eval", str(checkpoint), "--data", str(folder), "--latency-runs", "0"]) == 0
    said = [r.getMessage() for r in caplog.records if "were converted" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("1 of 3 pair(s)") and "zzz" in said[0]
    # and the reports say it: they read as if nothing had been converted
    out = tmp_path / "eval"
    argv = ["eval", str(checkpoint), "--data", str(folder), "--latency-runs", "0"]
    assert main([*argv, "--out", str(out)]) == 0
    conversion = json.loads((out / "metrics.json").read_text())["conversion"]
    assert conversion == said[0]
    assert f"- channels: {conversion}" in (out / "metrics.md").read_text()


def test_a_split_eval_cannot_use_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--split on a paired folder was ignored (its pairs scored whole); a path as the split
    read pairs outside the dataset's splits and nested the default report folder."""
    folder = write_paired_folder(tmp_path / "pairs", count=1)
    checkpoint = make_checkpoint(tmp_path / "run" / "checkpoints" / "best.pt")
    argv = ["eval", str(checkpoint), "--latency-runs", "0", "--data"]
    assert main([*argv, str(folder), "--split", "val"]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert "--split val" in line and "paired folder" in line and "leave --split out" in line
    dataset = tmp_path / "ds"
    write_paired_folder(dataset / "test" / "more", count=1)
    split = write_paired_folder(tmp_path / "ds2" / "test", count=1)  # a split named as itself
    assert main([*argv, str(split), "--split", "test", "--out", str(tmp_path / "e")]) == 0
    for split in ("test/more", "..", ""):
        with pytest.raises(SystemExit) as stop:
            main([*argv, str(dataset), "--split", split])
        assert stop.value.code == 2 and "not a path" in capsys.readouterr().err
    assert not any((tmp_path / "run").glob("eval_*"))


@pytest.mark.parametrize("code", REFUSALS)
def test_a_read_only_out_is_said_before_the_scoring(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    code: int,
) -> None:
    """It was said after every image was scored and timed: a large split's work lost."""
    from lenspair.model.evaluation import evaluate

    checkpoint = make_checkpoint(tmp_path / "c.pt")
    folder = write_paired_folder(tmp_path / "pairs", count=2)
    (tmp_path / "ro").mkdir()
    refuse_writes(monkeypatch, tmp_path / "ro", code)
    scored: list[object] = []
    monkeypatch.setattr(evaluate, "evaluate_checkpoint", lambda *a, **k: scored.append(a))
    out = tmp_path / "ro" / "ev"
    assert main(["eval", str(checkpoint), "--data", str(folder), "--out", str(out)]) == 1
    assert not scored
    assert capsys.readouterr().err.strip().endswith(f"{out / 'eval.json'}: {os.strerror(code)}")


def test_pixels_a_mask_marks_untrustworthy_are_not_scored(tmp_path: Path) -> None:
    # training leaves them out of its loss and dataset-build out of psnr_db; eval scored them:
    # two datasets differing only there scored 19.72 against 18.48 dB
    scores = []
    for name, spoil in (("plain", False), ("spoiled", True)):
        folder = tmp_path / name
        rng = np.random.default_rng(5)
        for index in range(3):
            target = clean_image(rng)
            source = obstruct(target, rng)
            mask = np.zeros(target.shape, np.uint8)
            mask[:, :6] = 255  # a misregistered strip at the left border
            if spoil:
                target = target.copy()
                target[:, :6] = 255 - target[:, :6]
            write_image(folder / "input" / f"{index:03d}.png", source)
            write_image(folder / "target" / f"{index:03d}.png", target)
            write_image(folder / "mask" / f"{index:03d}.png", mask)
        checkpoint = make_checkpoint(tmp_path / "net.pt")
        result = evaluate_checkpoint(checkpoint, folder, "test", CPU, latency_runs=0)
        scores.append([v for s in result.scores for v in (s.psnr_db, s.ssim, s.input_psnr_db)])
        scores[-1] += [s.input_ssim for s in result.scores]
    assert len(scores[0]) == 12 and scores[0] == pytest.approx(scores[1], abs=1e-9)
    # a pair whose mask covers it has nothing to score: left out and named, not a crash
    write_image(tmp_path / "spoiled" / "mask" / "001.png", np.full((32, 48), 255, np.uint8))
    result = evaluate_checkpoint(checkpoint, tmp_path / "spoiled", "test", CPU, latency_runs=0)
    assert [s.name for s in result.scores] == ["000", "002"]
    assert "001: psnr: an image has no trustworthy pixel" in result.unread[0].reason


def test_a_report_without_samples_leaves_no_earlier_contact_sheet(tmp_path: Path) -> None:
    # an earlier run's sheet stayed beside this run's tables and passed for this run's
    from dataclasses import replace

    folder = write_paired_folder(tmp_path / "pairs", count=2)
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    result = evaluate_checkpoint(checkpoint, folder, "test", CPU, latency_runs=0)
    files = write_report(result, tmp_path / "out")
    assert files["contact_sheet"].is_file()
    again = write_report(replace(result, samples=[]), tmp_path / "out")
    assert "contact_sheet" not in again and not (tmp_path / "out" / "contact_sheet.png").exists()
    assert {p.name for p in (tmp_path / "out").iterdir()} == {
        "per_image.csv",
        "metrics.json",
        "metrics.md",
    }


def test_a_network_that_outputs_nan_is_refused_not_averaged_over_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A NaN output on a finite input is the network's fault: eval recorded those pairs as
    unreadable and wrote the mean of the others, exit 0, as if the data were to blame."""
    folder = write_paired_folder(tmp_path / "pairs", count=4)
    checkpoint = make_checkpoint(tmp_path / "ckpt.pt")
    state = torch.load(checkpoint, weights_only=False)
    weights = state["model"]
    name = next(k for k in weights if k.endswith("weight") and weights[k].ndim == 4)
    weights[name] = weights[name] * 1e38  # finite weights, an output that overflows
    torch.save(state, checkpoint)
    out = tmp_path / "eval"
    args = ["eval", str(checkpoint), "--data", str(folder), "--out", str(out)]
    assert main([*args, "--latency-runs", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "holds NaN or Inf on a finite input" in err
    assert not (out / "metrics.json").exists()


class _Hungry(torch.nn.Module):
    """The network, running out of memory (as the CPU allocator says it) on wide frames."""

    def __init__(self, inner: torch.nn.Module, message: str) -> None:
        super().__init__()
        self.inner, self.message = inner, message

    def forward(self, x: torch.Tensor) -> Any:
        if x.shape[-1] > 60:
            raise RuntimeError(self.message)
        return self.inner(x)


OOM = "DefaultCPUAllocator: can't allocate memory: you tried to allocate 3200000000 bytes"


def _with_a_wide_pair(tmp_path: Path) -> tuple[Path, torch.nn.Module]:
    """Four pairs, the third 96x40 (the one _Hungry runs out of memory on), and a network."""
    folder = write_paired_folder(tmp_path / "pairs", count=4)
    rng = np.random.default_rng(9)
    wide = clean_image(rng, 40, 96)
    write_image(folder / "input" / "002.png", obstruct(wide, rng))
    write_image(folder / "target" / "002.png", wide)
    return folder, load_model(make_checkpoint(tmp_path / "ckpt.pt")).network


def test_a_pair_too_large_for_memory_costs_only_itself(tmp_path: Path) -> None:
    # torch's allocator error went up as a traceback: nothing was written, not even the
    # other pairs' scores (restore fails such a frame alone and names a --tile)
    folder, network = _with_a_wide_pair(tmp_path)
    scored = score_pairs(_Hungry(network, OOM), open_paired(folder), 1, CPU)
    assert sorted(s.name for s in scored.scores) == ["000", "001", "003"]
    (unread,) = scored.unread
    assert unread.index == 2
    assert unread.reason.startswith("002: out of memory scoring one 96x40 frame on cpu (fp32)")
    with pytest.raises(RuntimeError, match="a bug, not memory"):
        score_pairs(_Hungry(network, "a bug, not memory"), open_paired(folder), 1, CPU)


def test_out_of_memory_in_the_fp32_agreement_is_said_and_counted(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # fp32 needs more memory than bf16: a pair scored at bf16 was left out of the agreement
    # without a word, and metrics.md said "all pairs"
    folder, network = _with_a_wide_pair(tmp_path)
    hungry = _Hungry(network, OOM)
    with caplog.at_level("WARNING"):
        versus = agreement_with_fp32(
            network, hungry, open_paired(folder), 1, CPU, "skimage-gaussian", "bf16"
        )
    assert versus.pairs == 3
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and said[0].startswith("pair 2: 002 left out of the fp32 agreement: out")
    assert _agreement_pairs(3, 4) == (
        "3 of the 4 scored pairs: fp32 ran out of memory on the others"
    )
    assert _agreement_pairs(4, 4) == "all pairs"
    # the tradeoff compares rows over the same pairs: there it is an error naming the pair
    with pytest.raises(ModelError, match=r"^002: out of memory .* every row scores the same"):
        agreement_with_fp32(
            network, hungry, open_paired(folder), 1, CPU, "skimage-gaussian", "bf16",
            skip_out_of_memory=False,
        )  # fmt: skip
    with pytest.raises(ModelError, match=r"^002: out of memory .* every row scores the same"):
        score_pairs(hungry, open_paired(folder), 1, CPU, skip_out_of_memory=False)
