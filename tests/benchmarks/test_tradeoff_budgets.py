"""benchmarks.tradeoff_budgets: what a larger budget changed, claimed only beyond the spread."""

import json
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import pytest

from benchmarks.tradeoff_budgets import _compared, curves, figure, main


def _run(path: Path, budget: str, rows: dict[str, list[float]], crop: int = 128) -> Path:
    meta = {
        "dataset": "ds", "evaluated_on": "ds split test", "convention": "skimage-gaussian",
        "size": "540x360", "budget": budget, "seeds": [0, 1, 2],
        "training": {"crop_size": crop, "batch_size": 4, "lr": 2e-4, "lr_decay": 0.5},
        "input_baseline": {"psnr_db": 24.49, "ssim": 0.8936},
    }  # fmt: skip
    table: list[dict[str, Any]] = [
        {"name": name, "precision": precision, "psnr_db": psnr, "ssim": [0.9, 0.91, 0.92]}
        for name, psnr in rows.items()
        for precision in ("fp32", "bf16")
    ]
    path.write_text(json.dumps({"meta": meta, "rows": table}))
    return path


def test_a_change_is_claimed_only_beyond_either_spread(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # G rises by 1 dB against spreads of 0.1 and 0.2; GEA by 0.1 dB against 0.2; b3 is
    # only in the larger run and so not compared
    small = _run(
        tmp_path / "a.json", "800 steps", {"G": [24.9, 25.0, 25.1], "GEA": [25.0, 25.2, 25.4]}
    )
    large = _run(
        tmp_path / "b.json",
        "2000 steps",
        {"G": [25.8, 26.0, 26.2], "GEA": [25.1, 25.3, 25.5], "GEA-b3": [25.0, 25.0, 25.0]},
    )
    out = tmp_path / "budgets.md"
    assert main([str(small), str(large), "--out", str(out)]) == 0
    text = out.read_text()
    assert text == capsys.readouterr().out
    assert "| G | 25.00 +/- 0.10 | 26.00 +/- 0.20 | +1.00 dB, yes |" in text
    assert "| GEA | 25.20 +/- 0.20 | 25.30 +/- 0.20 | +0.10 dB, no |" in text
    assert "| GEA-b3 |" not in text  # named below the table, not compared
    # the input's scores at each budget: the same pairs score the same
    assert "| input, no restoration | 24.49 | 24.49 | - | 0.8936 | 0.8936 |" in text
    assert "changed G beyond the spread: at 800 steps those had not converged" in text
    assert text.rstrip().endswith("Only at 2000 steps: GEA-b3 (not compared).")


def test_runs_that_do_not_compare_are_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    small = _run(tmp_path / "a.json", "800 steps", {"G": [25.0, 25.1, 25.2]})
    other_crop = _run(tmp_path / "b.json", "2000 steps", {"G": [25.0, 25.1, 25.2]}, crop=256)
    assert main([str(small), str(other_crop)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "b.json: crop_size is 256, but 128" in error
    constant = _run(tmp_path / "e.json", "2000 steps", {"G": [25.0, 25.1, 25.2]})
    meta = json.loads(constant.read_text())
    meta["meta"]["training"]["lr_decay"] = 0.0  # another schedule: not the same training
    constant.write_text(json.dumps(meta))
    assert main([str(small), str(constant)]) == 2
    assert "e.json: lr_decay is 0.0, but 0.5" in capsys.readouterr().err
    same_budget = _run(tmp_path / "c.json", "800 steps", {"G": [25.0, 25.1, 25.2]})
    assert main([str(small), str(same_budget)]) == 2
    assert "the same budget" in capsys.readouterr().err
    assert main([str(small)]) == 2
    assert "at least two runs" in capsys.readouterr().err
    # the larger first: read as 8000 -> 800 steps, "at 8000 steps those had not converged"
    larger = _run(tmp_path / "f.json", "8000 steps", {"G": [27.0, 27.1, 27.2]})
    assert main([str(larger), str(small)]) == 2
    said = capsys.readouterr().err
    assert "a.json: 800 steps, less than" in said and "smallest budget first" in said
    # another draw of the dataset under the same name: other pairs scored
    for path, pairs in ((small, 26), (larger, 10)):
        data = json.loads(path.read_text())
        data["meta"]["pairs_scored"] = pairs
        path.write_text(json.dumps(data))
    assert main([str(small), str(larger)]) == 2
    assert "f.json: pairs_scored is 10, but 26 in" in capsys.readouterr().err
    (tmp_path / "d.json").write_text("{not json")
    assert main([str(small), str(tmp_path / "d.json")]) == 2
    assert "d.json: cannot read it as JSON" in capsys.readouterr().err


def test_no_change_beyond_the_spread_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    small = _run(tmp_path / "a.json", "800 steps", {"G": [24.9, 25.0, 25.1]})
    large = _run(tmp_path / "b.json", "2000 steps", {"G": [24.95, 25.05, 25.15]})
    assert main([str(small), str(large)]) == 0
    assert "No network changed beyond the spread between 800 steps and 2000 steps" in (
        capsys.readouterr().out
    )


def test_three_budgets_compare_each_with_the_next(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # G rises from 800 to 2000 steps beyond the spread, then stays; GEA-w0.5 is absent at
    # 4000 steps, so only its first step is compared; GEA-b3 is in one run only
    small = _run(
        tmp_path / "a.json", "800 steps",
        {"G": [24.9, 25.0, 25.1], "GEA-w0.5": [24.0, 24.2, 24.4], "GEA-b3": [24.0, 24.1, 24.2]},
    )  # fmt: skip
    middle = _run(
        tmp_path / "b.json", "2000 steps", {"G": [25.8, 26.0, 26.2], "GEA-w0.5": [24.1, 24.3, 24.5]}
    )
    large = _run(tmp_path / "c.json", "4000 steps", {"G": [25.9, 26.1, 26.3]})
    assert main([str(small), str(middle), str(large)]) == 0
    text = capsys.readouterr().out
    header = next(line for line in text.splitlines() if line.startswith("| network |"))
    assert "| 800 steps -> 2000 steps | 2000 steps -> 4000 steps |" in header
    assert (
        "| G | 25.00 +/- 0.10 | 26.00 +/- 0.20 | 26.10 +/- 0.20 | +1.00 dB, yes | +0.10 dB, no |"
        in text
    )
    assert "| GEA-w0.5 | 24.20 +/- 0.20 | 24.30 +/- 0.20 | - | +0.10 dB, no | - |" in text
    assert "From 800 steps to 2000 steps the budget changed G beyond the spread" in text
    assert "No network changed beyond the spread between 2000 steps and 4000 steps (G)" in text
    assert text.rstrip().endswith("Only at 800 steps: GEA-b3 (not compared).")
    # the same budget twice is refused, whichever run repeats it
    again = _run(tmp_path / "d.json", "800 steps", {"G": [25.0, 25.1, 25.2]})
    assert main([str(small), str(middle), str(again)]) == 2
    assert "d.json: the same budget as" in capsys.readouterr().err


def test_the_plot_draws_each_network_at_the_budgets_it_was_trained_at(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    small = _run(
        tmp_path / "a.json", "800 steps", {"G": [24.9, 25.0, 25.1], "GEA": [24.0, 24.2, 24.4]}
    )
    large = _run(tmp_path / "b.json", "4000 steps", {"G": [25.8, 26.0, 26.2]})
    series = curves(_compared([small, large]))
    assert list(series) == ["G"]  # GEA is in one run only: nothing to compare
    assert [(i, round(s.mean, 6), round(s.spread, 6)) for i, s in series["G"]] == [
        (0, 25.0, 0.1),
        (1, 26.0, 0.2),
    ]
    png = tmp_path / "curve.png"
    assert main([str(small), str(large), "--plot", str(png)]) == 0
    image = plt.imread(png)
    assert image.shape[:2] == (round(4.5 * 110), round(7.5 * 110))  # the figure, whole
    # written atomically: nothing left beside it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.json", "curve.png"]


def test_budgets_in_steps_sit_on_a_log_axis_and_seconds_side_by_side(tmp_path: Path) -> None:
    # a budget of time trains another number of steps on each machine: no axis of steps
    runs = {
        unit: [
            _run(tmp_path / f"{unit}{k}.json", f"{size} {unit}", {"G": [24.9 + k, 25.0 + k]})
            for k, size in enumerate((600, 1200, 4800))
        ]
        for unit in ("steps", "s")
    }
    for unit, scale, ticks in (("steps", "log", [600, 1200, 4800]), ("s", "linear", [0, 1, 2])):
        axes = figure(_compared(runs[unit])).axes[0]
        assert axes.get_xscale() == scale
        assert list(axes.get_xticks()) == ticks
        assert [t.get_text() for t in axes.get_xticklabels()] == [
            f"{size} {unit}" for size in (600, 1200, 4800)
        ]
