import argparse
import csv
import json
import logging
import shutil
from dataclasses import replace
from functools import partial
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import remove_path
from lenspair.core.imagewrite import write_image
from lenspair.model.checkpoint import load_model
from lenspair.model.errors import ModelError
from lenspair.model.evaluation import tradeoff as tradeoff_module
from lenspair.model.evaluation import tradeoff_pairs
from lenspair.model.evaluation.scoring import score_tensors
from lenspair.model.evaluation.tradeoff import TradeoffResult, run_tradeoff
from lenspair.model.evaluation.tradeoff_report import (
    MARKERS,
    TABLE_FILES,
    tradeoff_markdown,
    trained_on_line,
    write_tradeoff,
)
from lenspair.model.evaluation.tradeoff_rows import TradeoffRow, mark_pareto, pareto_front
from lenspair.model.evaluation.tradeoff_seeds_report import seeded_markdown
from lenspair.model.evaluation.tradeoff_variants import (
    DEFAULT_VARIANTS,
    Budget,
    parse_budget,
    precisions_for,
    variant_config,
)
from lenspair.model.precision import PRECISIONS
from lenspair.model.training.config import RunConfig
from lenspair.model.training.pairs import open_eval_pairs, to_tensor
from tests.model.train_fixtures import clean_image, tiny_config, write_split_dataset

pytestmark = pytest.mark.usefixtures("one_thread")


def test_pareto_front_on_fixed_points() -> None:
    times = [1.0, 2.0, 3.0, 2.0, 4.0, 1.5, None]
    psnr = [20.0, 25.0, 24.0, 22.0, 30.0, 20.0, 99.0]
    # 2 is dominated by 1 (faster and better), 3 by 1, 5 by 0 (slower, equal score);
    # the point without a time is never on the front.
    assert pareto_front(times, psnr) == [0, 1, 4]
    assert pareto_front([1.0, 1.0], [5.0, 5.0]) == [0, 1]  # exact ties both stay
    assert pareto_front([], []) == []
    assert pareto_front([1.0, 2.0], [float("nan"), 3.0]) == [1]


def test_mark_pareto_uses_psnr_and_ssim_separately() -> None:
    def row(name: str, ms: float, psnr: float, ssim: float) -> TradeoffRow:
        return TradeoffRow(name, "GEA", 1.0, 9, "fp32", 1, 0.1, ms, None, psnr, ssim, "c", 1)

    rows = mark_pareto([row("a", 1, 20, 0.9), row("b", 2, 25, 0.8), row("c", 3, 24, 0.95)])
    assert [r.pareto_psnr for r in rows] == [True, True, False]
    assert [r.pareto_ssim for r in rows] == [True, False, True]
    # doing nothing takes no time: a row the input beats is on no front, the rest stay
    marked = mark_pareto([row("a", 1, 20, 0.9), row("b", 2, 25, 0.8)], baseline=(21.0, 0.85))
    assert [(r.pareto_psnr, r.pareto_ssim) for r in marked] == [(False, True), (True, False)]


def test_parse_budget() -> None:
    assert parse_budget("60") == Budget(steps=60)
    assert parse_budget("90s") == Budget(seconds=90.0)
    assert parse_budget("2m") == Budget(seconds=120.0)
    assert parse_budget("1h").seconds == 3600.0
    for bad in ("", "0", "abc", "1.5", "-3"):
        with pytest.raises(ModelError, match="budget"):
            parse_budget(bad)


@pytest.mark.parametrize(
    "budget", [Budget(steps=4000), Budget(steps=1), Budget(seconds=90.0), Budget(seconds=0.5)]
)
def test_a_described_budget_reads_back_as_itself(budget: Budget) -> None:
    assert Budget.from_description(budget.describe()) == budget


@pytest.mark.parametrize("text", ["many steps", "800", "4000.5 steps", "90 min", ""])
def test_text_describe_did_not_write_is_no_budget(text: str) -> None:
    assert Budget.from_description(text) is None


def test_variant_set_and_precisions() -> None:
    names = [v.name for v in DEFAULT_VARIANTS]
    assert {"G", "GE", "GEA"} <= set(names)
    assert any(v.width == 0.5 for v in DEFAULT_VARIANTS)
    assert any(v.width == 2.0 for v in DEFAULT_VARIANTS)
    assert any(v.num_blocks == 3 for v in DEFAULT_VARIANTS)
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    assert precisions_for("G", cpu, ("int8", "bf16", "fp32")) == ["fp32"]
    assert precisions_for("GEA", cpu, ("int8", "bf16", "fp32")) == ["fp32", "bf16", "int8"]
    assert precisions_for("GEA", cpu, ("int8", "fp32")) == ["fp32", "int8"]  # no emulated bf16
    assert precisions_for("GEA", cpu, ("fp32",)) == ["fp32"]
    assert precisions_for("GEA", cuda, ("bf16", "fp16", "fp32")) == ["fp32", "bf16", "fp16"]
    assert precisions_for("GEA", cuda, ("fp16", "fp32")) == ["fp32", "fp16"]


def _fixed_precisions(monkeypatch: pytest.MonkeyPatch, reduced: list[str]) -> None:
    def fixed(variant: str, device: torch.device, native: object = None) -> list[str]:
        return ["fp32", *reduced] if variant == "GEA" else ["fp32"]

    monkeypatch.setattr("lenspair.model.evaluation.tradeoff.precisions_for", fixed)
    _cpu_native(monkeypatch, ("int8", *reduced, "fp32"))  # timed on any CI machine's CPU


def _cpu_native(monkeypatch: pytest.MonkeyPatch, native: tuple[str, ...]) -> None:
    """Make ``run_tradeoff`` see ``native`` as the CPU's native precisions."""

    def decision(*_: object) -> SimpleNamespace:
        return SimpleNamespace(native=native)

    monkeypatch.setattr(tradeoff_module, "choose_precision", decision)


def test_tradeoff_int8_row_scores_against_fp32_and_target(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("onnxruntime")
    _fixed_precisions(monkeypatch, ["int8"])
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    base = tiny_config()
    base = replace(base, model=replace(base.model, channels=None))
    gea = tuple(v for v in DEFAULT_VARIANTS if v.name in ("GEA", "GEA-w0.5"))
    result = run_tradeoff(dataset, tmp_path / "t", torch.device("cpu"), Budget(steps=1), base,
                          gea, latency_runs=2)  # fmt: skip
    assert {(r.name, r.precision) for r in result.rows} == {
        ("GEA", "fp32"),
        ("GEA", "int8"),
        ("GEA-w0.5", "fp32"),
    }  # int8 for the paper's GEA only
    rows = {r.precision: r for r in result.rows if r.name == "GEA"}
    assert rows["fp32"].psnr_vs_fp32_db is None
    assert 25.0 < (rows["int8"].psnr_vs_fp32_db or 0.0) <= 100.0
    assert abs(rows["int8"].psnr_db - rows["fp32"].psnr_db) < 3.0
    assert rows["int8"].cpu_ms is not None and rows["int8"].cpu_ms > 0
    assert "| GEA | int8 (" in (tmp_path / "t" / "tradeoff.md").read_text()


def payload_cpu(out: Path) -> str:
    """The CPU a tradeoff recorded, checked against this machine's."""
    from lenspair.model.precision import read_cpu_flags

    cpu = json.loads((out / "tradeoff.json").read_text())["cpu"]
    assert cpu == read_cpu_flags()[0]
    return str(cpu)


def test_tradeoff_writes_one_table_with_every_variant_and_a_plot(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="lenspair.model.evaluation")
    _fixed_precisions(monkeypatch, ["bf16"])
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    base = tiny_config()
    base = replace(base, model=replace(base.model, channels=None))
    out = tmp_path / "tradeoff"
    result = run_tradeoff(dataset, out, torch.device("cpu"), Budget(steps=1), base,
                          latency_runs=2)  # fmt: skip
    names = [(r.name, r.precision) for r in result.rows]
    gea_family = [v.name for v in DEFAULT_VARIANTS if v.variant == "GEA"]
    expected = [(v.name, "fp32") for v in DEFAULT_VARIANTS] + [(n, "bf16") for n in gea_family]
    assert sorted(names) == sorted(expected)
    assert all(r.steps == 1 for r in result.rows)
    assert all(r.cpu_ms is not None and r.cpu_ms > 0 for r in result.rows)
    assert all(r.gpu_ms is None for r in result.rows)
    assert any(r.pareto_psnr for r in result.rows)
    by_name = {(r.name, r.precision): r for r in result.rows}
    assert by_name[("GEA-w2", "fp32")].params > by_name[("GEA", "fp32")].params
    assert by_name[("GEA", "fp32")].params > by_name[("GEA-w0.5", "fp32")].params
    assert by_name[("GEA-b3", "fp32")].gflops < by_name[("GEA", "fp32")].gflops
    # each row is logged as a readable line, not as a dataclass repr
    logged = [r.getMessage() for r in caplog.records if r.name.endswith(".tradeoff")]
    for row in result.rows:
        assert f"tradeoff: {row.describe()}" in logged
    assert not any("TradeoffRow(" in line for line in logged)

    markdown = (out / "tradeoff.md").read_text()
    for name, precision in expected:
        assert f"| {name} | {precision}" in markdown
    assert "skimage-gaussian" in markdown
    assert f"threads of {payload_cpu(out)} (n/a" in markdown  # the CPU that timed the rows
    with (out / "tradeoff.csv").open() as handle:
        assert len(list(csv.DictReader(handle))) == len(expected)
    payload = json.loads((out / "tradeoff.json").read_text())
    assert len(payload["rows"]) == len(expected) and payload["budget"] == "1 steps"
    baseline = payload["input_baseline"]  # the test pair's input scored against its target
    pair = open_eval_pairs(dataset, "test")[0]
    psnr, ssim = score_tensors(to_tensor(pair.input, 1)[None], to_tensor(pair.target, 1)[None],
                               "skimage-gaussian")  # fmt: skip
    assert (baseline["psnr_db"], baseline["ssim"]) == pytest.approx((psnr, ssim))
    assert f"PSNR {baseline['psnr_db']:.2f} dB" in markdown
    assert (out / "tradeoff.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "tradeoff_config.yaml").is_file()
    assert (out / "runs" / "GEA-w2" / "checkpoints" / "best.pt").is_file()
    # scored: the checkpoint the validation pairs chose (test pairs score it), with its step
    assert payload["scored"] == tradeoff_module.SCORED["best.pt"] and "- scored: " in markdown
    for row in result.rows:
        best = load_model(out / "runs" / row.name / "checkpoints" / "best.pt")
        assert (
            row.scored_step == best.step == payload["rows"][result.rows.index(row)]["scored_step"]
        )

    # A rerun reuses the finished runs (and may select a subset from the CLI).
    config = tmp_path / "base.yaml"
    config.write_text(dump_yaml(base))
    before = (out / "runs" / "G" / "checkpoints" / "last.pt").stat().st_mtime_ns
    args = ["tradeoff", str(dataset), "--out", str(out), "--budget", "1", "--variants", "G"]
    args += ["--seeds", "0"]  # one seed: the single table
    assert main([*args, "--config", str(config), "--latency-runs", "1"]) == 0
    assert [r["name"] for r in json.loads((out / "tradeoff.json").read_text())["rows"]] == ["G"]
    assert (out / "runs" / "G" / "checkpoints" / "last.pt").stat().st_mtime_ns == before
    assert main(["tradeoff", str(dataset), "--out", str(out), "--variants", "X"]) == 2


def test_a_rerun_of_other_settings_takes_the_old_table_away_before_it_trains(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # stopped while retraining, it left tradeoff.md of the old budget beside a config of
    # the new one, its rows naming checkpoints the rerun had cleared
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    out = tmp_path / "tradeoff"
    g = [v for v in DEFAULT_VARIANTS if v.name == "G"]
    run = partial(run_tradeoff, dataset, out, torch.device("cpu"), base=tiny_config(),
                  variants=g, latency_runs=1, int8=False)  # fmt: skip
    run(Budget(steps=1))
    table = {name: (out / name).read_bytes() for name in TABLE_FILES}

    def stopped(*args: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(tradeoff_module, "_train_variant", stopped)
    with pytest.raises(KeyboardInterrupt):
        run(Budget(steps=1))  # the same settings: the table still says what is there
    assert {name: (out / name).read_bytes() for name in TABLE_FILES} == table
    with pytest.raises(KeyboardInterrupt):
        run(Budget(steps=2))
    assert not any((out / name).exists() for name in TABLE_FILES)
    assert "budget: 2 steps" in (out / "tradeoff_config.yaml").read_text()


def test_a_budget_under_one_step_is_named_not_a_missing_checkpoint(tmp_path: Path) -> None:
    # it ended in "G/checkpoints/best.pt: checkpoint not found"
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    g = tuple(v for v in DEFAULT_VARIANTS if v.name == "G")
    with pytest.raises(ModelError, match=r"^G: time budget .* before the first step.*--budget$"):
        run_tradeoff(dataset, tmp_path / "out", torch.device("cpu"), Budget(seconds=1e-300),
                     tiny_config(), g, latency_runs=0)  # fmt: skip


def test_a_precision_the_cpu_only_emulates_gets_no_cpu_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # as on a GPU whose host CPU lacks bf16: the GPU runs bf16, the CPU would emulate it
    _fixed_precisions(monkeypatch, ["bf16"])
    _cpu_native(monkeypatch, ("int8", "fp32"))
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    gea = tuple(v for v in DEFAULT_VARIANTS if v.name == "GEA")
    result = run_tradeoff(dataset, tmp_path / "out", torch.device("cpu"), Budget(steps=1),
                          tiny_config(), gea, latency_runs=1)  # fmt: skip
    times = {r.precision: r.cpu_ms for r in result.rows}
    assert times["bf16"] is None and times["fp32"] is not None and times["fp32"] > 0
    assert "| GEA | bf16" in (tmp_path / "out" / "tradeoff.md").read_text()


def _record_loads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the checkpoints the tradeoff scores, in the order it loads them."""
    loaded: list[str] = []
    real_load = tradeoff_module.load_model

    def load(path: Path, device: torch.device) -> object:
        loaded.append(Path(path).name)
        return real_load(path, device)

    monkeypatch.setattr(tradeoff_module, "load_model", load)
    return loaded


def test_a_single_paired_folder_is_scored_on_pairs_it_did_not_train_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from lenspair.model.training.datasets import paired_training_data
    from tests.model.train_fixtures import write_paired_folder

    folder = write_paired_folder(tmp_path / "pairs", count=20)  # input/ + target/, no splits
    base = tiny_config()
    data = paired_training_data(folder, base.data, 1, base.train.seed)
    trained = {pair.name for pair in data.train.source}  # type: ignore[attr-defined]
    variant = next(v for v in DEFAULT_VARIANTS if v.name == "G")
    loaded = _record_loads(monkeypatch)
    result = run_tradeoff(folder, tmp_path / "out", torch.device("cpu"), Budget(steps=1), base,
                          (variant,), latency_runs=1)  # fmt: skip
    # the validation pairs are the scored ones: they choose no checkpoint, the end is scored
    assert loaded == ["last.pt"] and result.meta["scored"] == tradeoff_module.SCORED["last.pt"]
    evaluated = result.meta["evaluated_on"]
    assert "held-out" in evaluated and "split test" not in evaluated
    scored = {pair.name for pair in data.val.source}  # type: ignore[attr-defined]
    assert scored and not scored & trained
    assert f"({len(scored)}, not trained on)" in evaluated
    assert result.meta["trained_on_scored_pairs"] == 0  # held out by name hash: none


def test_seeded_tradeoff_reports_mean_spread_convergence_and_published_rows(
    tmp_path: Path,
) -> None:
    from lenspair.model.evaluation.tradeoff_seeds import run_seeded_tradeoff

    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    base = tiny_config()
    base = replace(base, model=replace(base.model, channels=None))
    out = tmp_path / "seeded"
    variants = [v for v in DEFAULT_VARIANTS if v.name in ("G", "GEA-b3")]
    rows, meta = run_seeded_tradeoff(
        dataset, out, torch.device("cpu"), Budget(steps=3), base, [0, 1], variants,
        latency_runs=1,
    )  # fmt: skip
    assert meta["seeds"] == [0, 1]
    for row in rows:
        per_seed = []
        for seed in (0, 1):
            table = json.loads((out / f"seed{seed}" / "tradeoff.json").read_text())
            match = [
                r for r in table["rows"] if (r["name"], r["precision"]) == (row.name, row.precision)
            ]
            per_seed.append(float(match[0]["psnr_db"]))
        assert row.psnr.values == pytest.approx(tuple(per_seed))
        assert row.psnr.mean == pytest.approx(sum(per_seed) / 2)
        assert row.converged in (True, False, None)
    markdown = (out / "tradeoff_seeds.md").read_text()
    assert "+/-" in markdown and "converged" in markdown
    assert "published" in markdown and "| G+E+A | 0.909 | 29.84 |" in markdown
    assert json.loads((out / "tradeoff_seeds.json").read_text())["meta"]["seeds"] == [0, 1]
    # the CPU ms column names the CPU that timed it: runs on two machines are told apart
    from lenspair.model.precision import read_cpu_flags

    cpu = read_cpu_flags()[0]
    # ... and the threads that timed it
    timed = f"(batch 1, {meta['size']}, {meta['threads']} threads), on {cpu}"
    assert meta["cpu"] == cpu and timed in markdown
    # what the budget bought depends on crops, batch and schedule: the table says them
    crop, batch = base.data.crop_size, base.train.batch_size
    said = f"- training: {crop} px crops, batch {batch}, learning rate {base.train.lr:g} constant"
    assert said in markdown


def test_a_row_describes_itself_in_one_line() -> None:
    row = TradeoffRow(name="GEA", variant="GEA", width=1.0, num_blocks=9, precision="int8",
                      params=708426, gflops=19.7, cpu_ms=118.436, gpu_ms=None, psnr_db=25.0812,
                      ssim=0.89431, convention="skimage-gaussian", steps=10,
                      psnr_vs_fp32_db=69.06)  # fmt: skip
    assert row.describe() == (
        "GEA int8 (69.06 dB vs fp32): PSNR 25.08 dB, SSIM 0.8943 (skimage-gaussian, 10 steps); "
        "CPU 118.4 ms per frame"
    )
    on_gpu = replace(row, precision="fp16", cpu_ms=None, gpu_ms=2.5, psnr_vs_fp32_db=None)
    assert on_gpu.describe().endswith(
        ": PSNR 25.08 dB, SSIM 0.8943 (skimage-gaussian, 10 steps); GPU 2.5 ms per frame"
    )
    assert replace(row, cpu_ms=None).describe().endswith("not timed per frame")


def test_a_run_trained_with_other_settings_is_not_reused(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from lenspair.model.evaluation.tradeoff_reuse import RUN_MARKER, reusable
    from lenspair.model.training.config import RuntimeInfo
    from tests.model.train_fixtures import make_checkpoint

    caplog.set_level(logging.WARNING, logger="lenspair.model.evaluation")
    data = "/data/ds (train 2 pairs, validation 1 pairs)"
    stored = replace(tiny_config(max_steps=60), runtime=RuntimeInfo(data=data))
    run = tmp_path / "runs" / "GEA"

    def reused(
        wanted: RunConfig, dataset: str | None = None, best: bool = True, best_epoch: int = 1
    ) -> bool:
        make_checkpoint(run / "checkpoints" / "last.pt", stored, best_epoch=best_epoch)
        (run / RUN_MARKER).write_text("")  # a run tradeoff started
        if best:
            make_checkpoint(run / "checkpoints" / "best.pt", stored)
        else:
            (run / "checkpoints" / "best.pt").unlink(missing_ok=True)
        return reusable(run, wanted, torch.device("cpu"), dataset)

    # The same settings, a larger budget (extends the run) or other logging: reused.
    assert reused(tiny_config(max_steps=60))
    assert reused(tiny_config(max_steps=120, log_every=3, tensorboard=True))
    assert not caplog.records
    # Anything that changes what the run learns: cleared and trained again, said once.
    changes = {
        "train.seed": tiny_config(max_steps=60, seed=5),
        "train.batch_size": tiny_config(max_steps=60, batch_size=4),
        "train.lr": tiny_config(max_steps=60, lr=1e-3),
        "train.max_steps": tiny_config(max_steps=30),  # the run trained past this budget
        "train.max_seconds": tiny_config(max_seconds=90.0),  # another kind of budget
    }
    cropped = tiny_config(max_steps=60)
    changes["data.crop_size"] = replace(cropped, data=replace(cropped.data, crop_size=24))
    weighted = replace(cropped, loss=replace(cropped.loss, fidelity=1.0))
    changes["loss.fidelity"] = weighted
    for setting, wanted in changes.items():
        caplog.clear()
        assert not reused(wanted), setting
        assert not (run / "checkpoints").exists(), setting
        [record] = caplog.records
        assert str(run) in record.getMessage() and setting in record.getMessage()
    # cleared of what training wrote alone: an eval of its checkpoint (eval's default output
    # is in the run folder) and a note of the user's went with the whole folder
    (run / "eval_best_ds_test").mkdir()
    (run / "eval_best_ds_test" / "metrics.json").write_text("{}")
    (run / "NOTES.txt").write_text("rainy day")
    (run / "metrics.csv").write_text("step\n")
    caplog.clear()
    assert not reused(changes["train.seed"])
    assert sorted(p.name for p in run.iterdir()) == ["NOTES.txt", "eval_best_ds_test", RUN_MARKER]
    assert "kept NOTES.txt, eval_best_ds_test, not written by its training" in caplog.text
    remove_path(run / "NOTES.txt")
    remove_path(run / "eval_best_ds_test")
    # With a decaying learning rate a longer budget is another schedule, not an extension.
    stored = replace(tiny_config(max_steps=60, lr_decay=0.5), runtime=RuntimeInfo(data=data))
    assert reused(tiny_config(max_steps=60, lr_decay=0.5))
    caplog.clear()
    assert not reused(tiny_config(max_steps=120, lr_decay=0.5))
    assert "another schedule" in caplog.records[0].getMessage()
    assert not reused(tiny_config(max_steps=60))  # lr_decay 0.5 -> 0
    stored = replace(tiny_config(max_steps=60), runtime=RuntimeInfo(data=data))
    caplog.clear()
    assert reused(tiny_config(max_steps=60), data)  # the same dataset
    assert not reused(tiny_config(max_steps=60), "/data/other (train 2 pairs, validation 1 pairs)")
    assert "dataset" in caplog.records[0].getMessage()
    # trained at bf16 where bf16 was native; the rerun trains at fp32 (tiny_config: amp off,
    # as auto resolves where bf16 is emulated): trained again, not relabelled fp32
    bf16 = RuntimeInfo(data=data, precision="bf16 autocast")
    stored = replace(tiny_config(max_steps=60), runtime=bf16)
    caplog.clear()
    assert not reused(tiny_config(max_steps=60), data)
    assert "precision: 'bf16 autocast' -> 'fp32'" in caplog.records[0].getMessage()
    stored = replace(tiny_config(max_steps=60), runtime=replace(bf16, precision="fp32"))
    assert reused(tiny_config(max_steps=60), data)
    # best.pt gone (the row is scored from it, and a resume of a finished run never
    # writes it): every rerun failed on "checkpoint not found"; now trained again
    caplog.clear()
    assert not reused(tiny_config(max_steps=60), data, best=False)
    assert "cannot be resumed (its best.pt is missing)" in caplog.records[0].getMessage()
    # but a run killed before its first best (a long epoch, validated at the budget's
    # end) resumes and takes one then: it was thrown away and trained from step 0
    caplog.clear()
    assert reused(tiny_config(max_steps=60), data, best=False, best_epoch=0)
    assert not caplog.records
    # stopped before its first checkpoint: nothing to resume, cleared and trained again,
    # said (the time it had spent is lost)
    (run / "checkpoints" / "last.pt").unlink()
    assert not reusable(run, tiny_config(max_steps=60), torch.device("cpu"), data)
    assert [p.name for p in run.iterdir()] == [RUN_MARKER]
    [record] = caplog.records
    assert str(run) in record.getMessage() and "no checkpoints/last.pt" in record.getMessage()


def test_a_rerun_with_another_seed_retrains_and_records_the_seed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="lenspair.model.evaluation")
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    base = tiny_config()
    variant = tuple(v for v in DEFAULT_VARIANTS if v.name == "G")
    out = tmp_path / "t"
    last = out / "runs" / "G" / "checkpoints" / "last.pt"

    def rerun(config: RunConfig, steps: int) -> TradeoffResult:
        return run_tradeoff(dataset, out, torch.device("cpu"), Budget(steps=steps), config,
                            variant, latency_runs=1, int8=False)  # fmt: skip

    first = rerun(base, 1)
    assert first.meta["seed"] == 0
    assert json.loads((out / "tradeoff.json").read_text())["seed"] == 0
    stamp = last.stat().st_mtime_ns
    assert rerun(base, 1).rows[0].steps == 1 and last.stat().st_mtime_ns == stamp  # reused
    assert rerun(base, 2).rows[0].steps == 2  # a larger budget extends the run
    assert not any("cannot be resumed" in r.getMessage() for r in caplog.records)
    reseeded = rerun(replace(base, train=replace(base.train, seed=5)), 2)
    assert reseeded.meta["seed"] == 5
    assert reseeded.rows[0].steps == 2
    [line] = [r.getMessage() for r in caplog.records if "cannot be resumed" in r.getMessage()]
    assert str(out / "runs" / "G") in line and "train.seed: 0 -> 5" in line
    assert "seed: 5" in (out / "runs" / "G" / "config.yaml").read_text()


def _tiny_tradeoff_here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """In ``tmp_path``: dataset ``ds``, a tiny ``cfg.yaml``; the options of a 1-step G run."""
    monkeypatch.chdir(tmp_path)
    write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    (tmp_path / "cfg.yaml").write_text(dump_yaml(tiny_config()))
    common = ["--budget", "1", "--variants", "G", "--config", "cfg.yaml", "--crop-size", "32"]
    return [*common, "--batch-size", "2", "--latency-runs", "1", "--no-int8", "--device", "cpu"]


def test_per_seed_runs_are_reused_by_the_seeded_tradeoff(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # docs/results/gpu_h100.md: one process per seed into T/seed<k>, then
    # `--seeds 0,1` into T reuses those runs (a relative DS, as there).
    caplog.set_level(logging.INFO, logger="lenspair.model.evaluation")
    common = _tiny_tradeoff_here(tmp_path, monkeypatch)
    for seed in (0, 1):
        assert (
            main(["tradeoff", "ds", "--out", f"T/seed{seed}", "--seeds", str(seed), *common]) == 0
        )
        assert json.loads((tmp_path / f"T/seed{seed}/tradeoff.json").read_text())["seed"] == seed
    lasts = [tmp_path / f"T/seed{seed}/runs/G/checkpoints/last.pt" for seed in (0, 1)]
    stamps = [last.stat().st_mtime_ns for last in lasts]
    assert main(["tradeoff", "ds", "--out", "T", "--seeds", "0,1", *common]) == 0
    assert [last.stat().st_mtime_ns for last in lasts] == stamps
    assert not any("training it again" in r.getMessage() for r in caplog.records)
    meta = json.loads((tmp_path / "T" / "tradeoff_seeds.json").read_text())["meta"]
    assert meta["seeds"] == [0, 1] and "seed" not in meta


def test_one_output_holds_one_kind_of_tradeoff_table(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # A single-seed table a seeded rerun includes moves into seed<k>/ and is reused; a
    # single-seed rerun into the seeded output, or a seeded one leaving its seed out, is
    # refused before training, so no table sits beside one it is not part of.
    caplog.set_level(logging.INFO, logger="lenspair.model.evaluation")
    common = _tiny_tradeoff_here(tmp_path, monkeypatch)
    assert main(["tradeoff", "ds", "--out", "T", "--seeds", "0", *common]) == 0
    stamp = (tmp_path / "T/runs/G/checkpoints/last.pt").stat().st_mtime_ns
    before = sorted(p.name for p in (tmp_path / "T").iterdir())
    assert main(["tradeoff", "ds", "--out", "T", "--seeds", "1,2", *common]) == 2
    assert "single-seed tradeoff (seed 0" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "T").iterdir()) == before  # nothing touched
    (tmp_path / "T/seed0").mkdir()  # as a move killed after its first file leaves it
    (tmp_path / "T/runs").rename(tmp_path / "T/seed0/runs")
    assert main(["tradeoff", "ds", "--out", "T", "--seeds", "0,1", *common]) == 0
    last = tmp_path / "T/seed0/runs/G/checkpoints/last.pt"
    assert last.stat().st_mtime_ns == stamp  # moved and reused, not trained again
    assert not any("training it again" in r.getMessage() for r in caplog.records)
    assert json.loads((tmp_path / "T/seed0/tradeoff.json").read_text())["seed"] == 0
    names = {p.name for p in (tmp_path / "T").iterdir()}
    assert names == {"seed0", "seed1", "tradeoff_seeds.md", "tradeoff_seeds.json"}
    assert main(["tradeoff", "ds", "--out", "T", "--seeds", "0", *common]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert "holds a tradeoff over several seeds (seed0, seed1)" in line
    assert {p.name for p in (tmp_path / "T").iterdir()} == names
    assert last.stat().st_mtime_ns == stamp


def test_an_empty_split_to_score_is_a_one_line_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    monkeypatch.setattr(tradeoff_pairs, "open_eval_pairs", lambda data, split: [])  # all empty
    gea = tuple(v for v in DEFAULT_VARIANTS if v.name == "GEA")
    # asked for by name (the default falls back to held-out pairs: see the test above)
    with pytest.raises(ModelError, match=r"split test: no pairs to score; no other split holds"):
        run_tradeoff(
            dataset, tmp_path / "t", torch.device("cpu"), Budget(steps=1), tiny_config(), gea,
            split="test",
        )  # fmt: skip
    assert not (tmp_path / "t").exists()  # refused before anything was trained or written


@pytest.mark.parametrize(
    ("empty", "said"),
    [
        (("val",), "splits with pairs: test (2), train (4, trained on); leave --split out to "
         "score the test split"),
        (("val", "test"), "splits with pairs: train (4, trained on); leave --split out to "
         "score the held-out validation pairs"),
    ],
)  # fmt: skip
def test_an_empty_split_names_the_splits_that_hold_pairs(
    tmp_path: Path, empty: tuple[str, ...], said: str
) -> None:
    """It said "choose another --split (e.g. val)" when val itself was the empty split."""
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1, "test": 2})
    (dataset / "dataset.json").write_text('{"format": "lenspair-dataset/1"}\n')  # empty ones open
    for split in empty:  # as dataset-build leaves the splits of one recording
        for side in ("input", "target"):
            shutil.rmtree(dataset / split / side)
            (dataset / split / side).mkdir()
    g = tuple(v for v in DEFAULT_VARIANTS if v.name == "G")
    with pytest.raises(ModelError) as raised:
        run_tradeoff(dataset, tmp_path / "t", torch.device("cpu"), Budget(steps=1),
                     tiny_config(), g, split="val")  # fmt: skip
    message = str(raised.value)
    assert message.startswith(f"{dataset} split val: no pairs to score; {said}"), message
    assert "e.g. val" not in message and "\n" not in message
    assert not (tmp_path / "t").exists()


def test_scoring_the_split_trained_on_is_said_in_the_log_and_under_the_table(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """As lenspair eval says it of the same checkpoint and split."""
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1, "test": 2})
    g = tuple(v for v in DEFAULT_VARIANTS if v.name == "G")
    with caplog.at_level(logging.WARNING):
        result = run_tradeoff(dataset, tmp_path / "t", torch.device("cpu"), Budget(steps=1),
                              tiny_config(), g, split="train", latency_runs=1)  # fmt: skip
    said = [r.getMessage() for r in caplog.records if "flatter" in r.getMessage()]
    assert len(said) == 1 and "trained on 4 of the 4 scored pairs" in said[0], said
    assert (result.meta["trained_on_scored_pairs"], result.meta["scored_pairs"]) == (4, 4)
    line = "Warning: the networks trained on 4 of the 4 scored pairs, which flatter their scores"
    table = (tmp_path / "t" / "tradeoff.md").read_text()
    assert line in table.split("| G |")[-1]  # under the table
    saved = json.loads((tmp_path / "t" / "tradeoff.json").read_text())
    assert saved["trained_on_scored_pairs"] == 4 and saved["warning"].startswith(line)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        other = run_tradeoff(dataset, tmp_path / "t2", torch.device("cpu"), Budget(steps=1),
                             tiny_config(), g, split="test", latency_runs=1)  # fmt: skip
    assert other.meta["trained_on_scored_pairs"] == 0
    assert not any("flatter" in r.getMessage() for r in caplog.records)
    assert "Warning" not in (tmp_path / "t2" / "tradeoff.md").read_text()


def test_the_warning_under_the_tables_names_the_int8_calibration() -> None:
    meta = {
        "dataset": "ds", "evaluated_on": "ds split train", "budget": "3 steps", "seeds": [0],
        "convention": "skimage-gaussian", "size": "48x32", "threads": 1,
        "trained_on_scored_pairs": 6, "scored_pairs": 6, "int8_calibrated_on_scored": True,
    }  # fmt: skip
    line = trained_on_line(meta)
    assert line is not None and "the int8 row was calibrated on the training pairs" in line
    assert tradeoff_markdown([], meta).rstrip().endswith(line)
    assert line in seeded_markdown([], meta)
    assert trained_on_line({**meta, "trained_on_scored_pairs": 0}) is None


def test_an_unreadable_test_pair_is_skipped_and_recorded_before_training(tmp_path: Path) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 1, "test": 4})
    bad = dataset / "test" / "target" / "001.png"
    bad.write_bytes(bad.read_bytes()[:50])
    small = clean_image(np.random.default_rng(5), 10, 10)  # readable, but under SSIM's window
    write_image(dataset / "test" / "input" / "003.png", small)
    write_image(dataset / "test" / "target" / "003.png", small)
    g = tuple(v for v in DEFAULT_VARIANTS if v.name == "G")
    result = run_tradeoff(dataset, tmp_path / "t", torch.device("cpu"), Budget(steps=1),
                          tiny_config(), g, latency_runs=1)  # fmt: skip
    unread, small_one = result.meta["unread"]
    assert unread["index"] == 1 and "001.png" in unread["reason"]
    assert small_one["index"] == 3 and "window" in small_one["reason"]  # the split's index
    # the row's mean is over the two readable pairs: recompute it from them
    network = load_model(tmp_path / "t" / "runs" / "G" / "checkpoints" / "best.pt").network
    pairs = open_eval_pairs(dataset, "test")
    psnrs = []
    for index in (0, 2):
        x = to_tensor(pairs[index].input, 1)[None]
        with torch.no_grad():
            output = torch.round(network(x)[1].clamp(0, 1) * 255) / 255
        psnrs.append(
            score_tensors(output, to_tensor(pairs[index].target, 1)[None], "skimage-gaussian")[0]
        )
    assert result.rows[0].psnr_db == pytest.approx(sum(psnrs) / 2, abs=1e-6)
    saved = json.loads((tmp_path / "t" / "tradeoff.json").read_text())
    assert saved["unread"] == result.meta["unread"]
    assert "2 pair(s) could not be read or scored" in (tmp_path / "t" / "tradeoff.md").read_text()


def test_a_test_split_with_no_readable_pair_is_refused_before_training(tmp_path: Path) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    (dataset / "test" / "input" / "000.png").write_bytes(b"")
    g = tuple(v for v in DEFAULT_VARIANTS if v.name == "G")
    with pytest.raises(ModelError, match=r"none can be read and scored; the first: .*000\.png"):
        run_tradeoff(
            dataset, tmp_path / "t", torch.device("cpu"), Budget(steps=1), tiny_config(), g
        )
    assert not (tmp_path / "t").exists()
    small = clean_image(np.random.default_rng(5), 10, 10)  # readable, under SSIM's window
    write_image(dataset / "test" / "input" / "000.png", small)
    write_image(dataset / "test" / "target" / "000.png", small)
    with pytest.raises(ModelError, match=r"none can be read and scored; the first: 000: .*window"):
        run_tradeoff(
            dataset, tmp_path / "t", torch.device("cpu"), Budget(steps=1), tiny_config(), g
        )
    assert not (tmp_path / "t").exists()  # found before any training


def test_the_cli_anneals_step_budgets_by_default(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from lenspair.model.evaluation import tradeoff

    decays: list[float] = []

    def record(dataset: Path, out: Path, device: object, budget: Budget, base: RunConfig,
               *args: object, **kwargs: object) -> TradeoffResult:  # fmt: skip
        decays.append(base.train.lr_decay)
        variant = variant_config(base, DEFAULT_VARIANTS[0], budget)
        decays.append(variant.train.lr_decay)
        return TradeoffResult([], {"dataset": str(dataset), "evaluated_on": "x", "budget": "b",
                                   "convention": "c", "size": "1x1", "threads": 1})  # fmt: skip

    monkeypatch.setattr(tradeoff, "run_tradeoff", record)
    config = tmp_path / "base.yaml"
    config.write_text(dump_yaml(tiny_config(lr_decay=0.25)))
    argv = ["tradeoff", str(tmp_path), "--out", str(tmp_path / "t"), "--seeds", "0"]
    assert main([*argv, "--budget", "10"]) == 0  # the default: pix2pix's second half
    assert main([*argv, "--budget", "10", "--config", str(config)]) == 0  # the config's
    assert main([*argv, "--budget", "10", "--config", str(config), "--lr-decay", "0"]) == 0
    assert main([*argv, "--budget", "90s"]) == 0  # a time budget: steps unknown, constant
    # ... and recorded as constant (the config and report said "falling" for it)
    assert decays == [0.5, 0.5, 0.25, 0.25, 0.0, 0.0, 0.0, 0.0]
    # asked for: refused, not dropped unsaid
    assert main([*argv, "--budget", "90s", "--lr-decay", "0.5"]) == 2
    assert "--lr-decay 0.5: a time budget (90s)" in capsys.readouterr().err


def test_a_config_sets_only_what_it_names(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # A config written to set val_every once switched crop, batch and the decay to
    # train's defaults (256, 8, constant): a tradeoff of other networks than asked for.
    from lenspair.model.evaluation import tradeoff

    settings: list[tuple[int, int, float]] = []

    def record(dataset: Path, out: Path, device: object, budget: Budget, base: RunConfig,
               *args: object, **kwargs: object) -> TradeoffResult:  # fmt: skip
        settings.append((base.data.crop_size, base.train.batch_size, base.train.lr_decay))
        return TradeoffResult([], {"dataset": str(dataset), "evaluated_on": "x", "budget": "b",
                                   "convention": "c", "size": "1x1", "threads": 1})  # fmt: skip

    monkeypatch.setattr(tradeoff, "run_tradeoff", record)
    partial = tmp_path / "partial.yaml"
    partial.write_text("train:\n  val_every: 3\n  patience: 0\n")
    cropped = tmp_path / "cropped.yaml"
    cropped.write_text("data:\n  crop_size: 64\ntrain:\n  batch_size: 2\n")
    argv = ["tradeoff", str(tmp_path), "--out", str(tmp_path / "t"), "--seeds", "0"]
    assert main([*argv, "--budget", "10", "--config", str(partial)]) == 0
    assert main([*argv, "--budget", "10", "--config", str(cropped)]) == 0
    assert main([*argv, "--budget", "10", "--config", str(cropped), "--crop-size", "32"]) == 0
    emptied = tmp_path / "emptied.yaml"  # every key commented out: the section is null
    emptied.write_text("train:\n  # batch_size: 2\n")
    assert main([*argv, "--budget", "10", "--config", str(emptied)]) == 0
    assert settings == [(128, 4, 0.5), (64, 2, 0.5), (32, 2, 0.5), (128, 4, 0.5)]


def test_a_split_asked_for_is_scored_or_refused_never_replaced(tmp_path: Path) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    g = tuple(v for v in DEFAULT_VARIANTS if v.name == "G")

    def tradeoff(split: str | None, out: str) -> TradeoffResult:
        return run_tradeoff(dataset, tmp_path / out, torch.device("cpu"), Budget(steps=1),
                            tiny_config(), g, split=split, latency_runs=1)  # fmt: skip

    with pytest.raises(LenspairError, match="nope"):
        tradeoff("nope", "t1")
    assert not (tmp_path / "t1").exists()
    assert "split val" in tradeoff("val", "t2").meta["evaluated_on"]
    shutil.rmtree(dataset / "test")  # no test split: the default falls back, said so
    assert "held-out validation pairs" in tradeoff(None, "t3").meta["evaluated_on"]
    for side in ("input", "target"):  # an empty one, as dataset-build may leave it: the same
        (dataset / "test" / side).mkdir(parents=True)
    # a lenspair dataset (its card says so): empty splits open
    (dataset / "dataset.json").write_text('{"format": "lenspair-dataset/1"}\n')
    assert "held-out validation pairs" in tradeoff(None, "t4").meta["evaluated_on"]
    with pytest.raises(LenspairError, match="no pairs to score"):
        tradeoff("test", "t5")  # asked for by name: refused, not replaced


def test_the_schedule_in_words_says_the_decay() -> None:
    from lenspair.model.evaluation.tradeoff_seeds_report import _schedule

    training = {"crop_size": 128, "batch_size": 4, "lr": 2e-4, "lr_decay": 0.5}
    assert _schedule(training) == (
        "128 px crops, batch 4, learning rate 0.0002 falling linearly towards zero over the "
        "last 50% of the budget"
    )


def test_a_run_folder_tradeoff_did_not_start_is_refused_never_deleted(tmp_path: Path) -> None:
    """``--out .`` in a project with runs/G: tradeoff deleted the user's folder, notes and
    checkpoints, with no word or with "cannot be resumed; training it again"."""
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    g = tuple(v for v in DEFAULT_VARIANTS if v.name == "G")
    mine = tmp_path / "t" / "runs" / "G"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("important")

    def tradeoff() -> TradeoffResult:
        return run_tradeoff(dataset, tmp_path / "t", torch.device("cpu"), Budget(steps=1),
                            tiny_config(), g, latency_runs=1)  # fmt: skip

    with pytest.raises(ModelError, match=r"runs/G: exists and holds more than a run tradeoff"):
        tradeoff()
    assert (mine / "notes.txt").read_text() == "important"
    shutil.rmtree(mine)
    first = tradeoff().rows[0].psnr_db
    assert (mine / "tradeoff_run.txt").is_file()  # its own: a rerun resumes it
    assert tradeoff().rows[0].psnr_db == first
    # a run of the version before the marker, in its own output: adopted, not refused
    (mine / "tradeoff_run.txt").unlink()
    assert tradeoff().rows[0].psnr_db == first and (mine / "tradeoff_run.txt").is_file()
    # ... unless the user put a file of theirs in it
    (mine / "tradeoff_run.txt").unlink()
    (mine / "notes.txt").write_text("important")
    with pytest.raises(ModelError, match="holds more than a run tradeoff started"):
        tradeoff()


def test_int8_in_a_paired_folder_calibrates_on_the_pairs_it_trained_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It calibrated on every pair of the folder, the scored held-out ones included."""
    pytest.importorskip("onnxruntime")
    from lenspair.model.evaluation import quantize
    from tests.model.train_fixtures import write_paired_folder

    _fixed_precisions(monkeypatch, ["int8"])
    calibrated: list[str] = []
    real = quantize.calibration_images

    def record(source: object, *args: object) -> object:
        calibrated.extend(source[i].name for i in range(len(source)))  # type: ignore[index]
        return real(source, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(quantize, "calibration_images", record)
    folder = write_paired_folder(tmp_path / "pairs", count=12)
    gea = tuple(v for v in DEFAULT_VARIANTS if v.name == "GEA")
    base = tiny_config()
    base = replace(base, model=replace(base.model, channels=None))
    result = run_tradeoff(folder, tmp_path / "t", torch.device("cpu"), Budget(steps=1), base,
                          gea, latency_runs=1)  # fmt: skip
    assert {r.precision for r in result.rows} == {"fp32", "int8"}
    from lenspair.model.training.datasets import paired_training_data

    data = paired_training_data(folder, base.data, 1, base.train.seed)
    scored = {pair.name for pair in data.val.source}  # type: ignore[attr-defined]
    assert calibrated and scored and not scored & set(calibrated)


def test_places_a_tradeoff_cannot_use_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tests.model.train_fixtures import write_paired_folder

    folder = write_paired_folder(tmp_path / "pairs", count=4)
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    cases = {  # argv after tradeoff: what the one line says
        (str(folder), "--out", str(folder / "input")): "inside the image folder",
        (str(dataset), "--out", str(dataset / "test" / "target" / "t")): "inside the image folder",
        (str(folder), "--out", str(tmp_path / "o"), "--split", "bogus"): "is a paired folder",
        (str(folder), "--out", str(tmp_path / "o"), "--variants", ""): "no variant named",
    }
    for argv, said in cases.items():
        assert main(["tradeoff", *argv, "--budget", "1"]) == 2
        [line] = capsys.readouterr().err.strip().splitlines()
        assert said in line, line
    assert not (tmp_path / "o").exists() and not (folder / "input" / "tradeoff.png").exists()
    # beside the image folders (as dataset-build keeps train/restored/): never read as pairs
    from lenspair.commands.tradeoff import _check_places
    from lenspair.commands.tradeoff import add_arguments as tradeoff_arguments

    parser = argparse.ArgumentParser()
    tradeoff_arguments(parser)
    _check_places(parser.parse_args([str(dataset), "--out", str(dataset / "test" / "t")]))


def test_a_test_split_with_an_unpaired_file_is_refused_not_swapped_for_another(
    tmp_path: Path,
) -> None:
    """It scored the validation pairs instead, with nothing said: the test split's problem
    is the answer, as in eval."""
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 2})
    next((dataset / "test" / "target").glob("*.png")).unlink()
    variant = next(v for v in DEFAULT_VARIANTS if v.name == "G")
    with pytest.raises(LenspairError, match=r"test: 1 unpaired file\(s\)"):
        run_tradeoff(dataset, tmp_path / "out", torch.device("cpu"), Budget(steps=1),
                     tiny_config(), (variant,), latency_runs=1)  # fmt: skip


def test_the_validation_split_scored_scores_the_end_of_the_budget(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """best.pt is the best of noisy validations on those very pairs: not their score."""
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2, "val": 1, "test": 1})
    variant = next(v for v in DEFAULT_VARIANTS if v.name == "G")
    loaded = _record_loads(monkeypatch)
    result = run_tradeoff(dataset, tmp_path / "out", torch.device("cpu"), Budget(steps=1),
                          tiny_config(), (variant,), latency_runs=1, split="val")  # fmt: skip
    assert loaded == ["last.pt"] and result.meta["scored"] == tradeoff_module.SCORED["last.pt"]
    assert result.meta["evaluated_on"].endswith("split val")
    assert result.meta["pairs_scored"] == 1  # the count tells two draws of one dataset apart


def test_only_seed_numbered_folders_make_an_output_seeded(tmp_path: Path) -> None:
    from lenspair.model.evaluation.tradeoff_seeds import seeded_output_refusal

    (tmp_path / "seedling").mkdir()  # a folder of the user's, named alike
    (tmp_path / "seedling" / "tradeoff_config.yaml").write_text("seed: 0\n")
    assert seeded_output_refusal(tmp_path) is None
    (tmp_path / "seed3").mkdir()
    (tmp_path / "seed3" / "tradeoff_config.yaml").write_text("seed: 3\n")
    refusal = seeded_output_refusal(tmp_path)
    assert refusal is not None and "several seeds (seed3)" in refusal


def test_tradeoff_json_keeps_text_and_writes_non_finite_numbers_as_strings(
    tmp_path: Path,
) -> None:
    # a folder named Infinity and an infinite PSNR (identical pairs): strict JSON, text untouched
    row = TradeoffRow("GEA", "GEA", 1.0, 9, "fp32", 1, 0.1, 2.0, None, float("inf"), 1.0, "c", 1)
    nan_row = replace(row, name="GE", psnr_db=float("nan"), psnr_vs_fp32_db=float("-inf"))
    meta = {
        "dataset": "/data/Infinity_rig/DS", "evaluated_on": "Infinity split test",
        "budget": "2 steps", "convention": "c", "size": "540x360", "threads": 1,
        "cpu": "NaN-Infinity CPU",
    }  # fmt: skip
    write_tradeoff([row, nan_row], tmp_path, meta)
    text = (tmp_path / "tradeoff.json").read_text()
    data = json.loads(text, parse_constant=lambda token: pytest.fail(f"bare {token} in JSON"))
    assert {k: data[k] for k in meta} == meta
    assert [r["psnr_db"] for r in data["rows"]] == ["inf", "nan"]
    assert data["rows"][1]["psnr_vs_fp32_db"] == "-inf"


def test_every_precision_has_its_own_marker_in_the_plot() -> None:
    # int8 rows were drawn as bf16 squares, under a title naming only fp32 and bf16
    assert set(MARKERS) == set(PRECISIONS)
    assert len(set(MARKERS.values())) == len(MARKERS)


def test_a_cuda_runs_seeded_table_gives_fp16_rows_their_gpu_time(tmp_path: Path) -> None:
    from lenspair.model.evaluation.tradeoff_seeds import aggregate
    from lenspair.model.evaluation.tradeoff_seeds_report import seeded_markdown

    def row(precision: str, cpu: float | None, gpu: float, psnr: float) -> TradeoffRow:
        return TradeoffRow(name="GEA", variant="GEA", width=1.0, num_blocks=9,
                           precision=precision, params=708426, gflops=19.7, cpu_ms=cpu,
                           gpu_ms=gpu, psnr_db=psnr, ssim=0.9, convention="skimage-gaussian",
                           steps=3)  # fmt: skip

    meta = {"input_baseline": {"psnr_db": 24.0, "ssim": 0.89}}
    results = [
        TradeoffResult([row("fp32", 60.0, 2.0, 27.0), row("fp16", None, 1.0, 27.0)], meta),
        TradeoffResult([row("fp32", 62.0, 4.0, 27.2), row("fp16", None, 3.0, 27.2)], meta),
        TradeoffResult([row("fp32", 61.0, 9.0, 27.1), row("fp16", None, 2.0, 27.1)], meta),
    ]
    rows = aggregate(results, tmp_path, [0, 1, 2], Budget(steps=3))
    by_precision = {r.precision: r for r in rows}
    assert by_precision["fp32"].gpu_ms == 4.0 and by_precision["fp16"].gpu_ms == 2.0  # medians
    assert by_precision["fp16"].cpu_ms is None
    table_meta = {
        "dataset": "ds", "evaluated_on": "ds split test", "budget": "3 steps", "seeds": [0, 1, 2],
        "convention": "skimage-gaussian", "size": "540x360", "gpu": "NVIDIA H200", **meta,
    }  # fmt: skip
    text = seeded_markdown(rows, table_meta)
    assert "| CPU ms | GPU ms | PSNR (dB) |" in text and "the same on NVIDIA H200" in text
    assert "| input, no restoration | - | 0 | 0 | 0 | 0 | 24.00 |" in text
    assert "| 19.7 | 61.0 | 4.00 | 27.10 +/- 0.10 |" in text
    assert "| 19.7 | n/a | 2.00 | 27.10 +/- 0.10 |" in text
    # a CPU-only run's table keeps the columns it always had
    cpu_only = [replace(r, gpu_ms=None) for r in rows]
    plain = seeded_markdown(cpu_only, {k: v for k, v in table_meta.items() if k != "gpu"})
    assert "GPU ms" not in plain and "| CPU ms | PSNR (dB) |" in plain
    # the single-seed table names the GPU of its GPU column too
    from lenspair.model.evaluation.tradeoff_report import tradeoff_markdown

    single = tradeoff_markdown(results[0].rows, {**table_meta, "threads": 2})
    assert "GPU column only when trained on CUDA, on NVIDIA H200" in single
