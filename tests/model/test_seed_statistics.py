"""Seed statistics: spread, claims beyond it, convergence, spread-aware Pareto; paper rows."""

import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.model.evaluation.published import PUBLISHED, published_markdown
from lenspair.model.evaluation.seed_statistics import (
    clearly_better,
    converged,
    robust_pareto,
    summarise_seeds,
)
from lenspair.model.evaluation.tradeoff import TradeoffResult
from lenspair.model.evaluation.tradeoff_rows import TradeoffRow
from lenspair.model.evaluation.tradeoff_seeds import aggregate
from lenspair.model.evaluation.tradeoff_seeds_report import seeded_markdown
from lenspair.model.evaluation.tradeoff_variants import Budget
from lenspair.model.training.run_files import write_metrics_rows


def test_mean_and_sample_spread() -> None:
    summary = summarise_seeds([1.0, 2.0, 3.0, math.nan])
    assert summary.values == (1.0, 2.0, 3.0) and summary.mean == 2.0
    assert summary.spread == pytest.approx(1.0)
    assert summary.format(1) == "2.0 +/- 1.0"
    single = summarise_seeds([5.0])
    assert single.spread == 0.0 and single.format(1) == "5.0"
    with pytest.raises(ValueError):
        summarise_seeds([math.nan])


@given(
    values=st.lists(st.floats(-50, 50), min_size=2, max_size=6),
    shift=st.floats(0, 20),
)
def test_a_shift_is_claimed_only_beyond_the_spread(values: list[float], shift: float) -> None:
    base = summarise_seeds(values)
    moved = summarise_seeds([v + shift for v in values])
    assert moved.spread == pytest.approx(base.spread, abs=1e-6)
    assert clearly_better(moved, base) == (moved.mean - base.mean > max(moved.spread, base.spread))
    assert not clearly_better(base, moved)
    assert not clearly_better(summarise_seeds([values[0] + 100]), summarise_seeds([values[0]]))


def test_convergence_compares_the_last_fifth_with_the_spread() -> None:
    flat = [(10, 20.0), (50, 24.0), (80, 24.9), (100, 25.0)]
    assert converged(flat, 100, spread=0.2) == (True, pytest.approx(0.1))
    rising = [(10, 20.0), (80, 23.0), (100, 25.0)]
    assert converged(rising, 100, spread=0.2) == (False, pytest.approx(2.0))
    assert converged([(90, 25.0), (100, 25.1)], 100, spread=1.0) is None  # no point at 80 %
    assert converged([(10, 20.0)], 100, spread=1.0) is None  # nothing after it
    # seeds that agree exactly (spread 0) on a curve that did not move: converged, not "no"
    assert converged([(50, 25.0), (80, 25.0), (100, 25.0)], 100, spread=0.0) == (True, 0.0)


def test_convergence_reads_the_trend_not_the_noise_of_the_last_fifth() -> None:
    # a flat tail whose validations jump +/-0.5 dB; its endpoints differ by 1 dB
    noisy_flat = [(float(s), 25.0 + 0.5 * (-1) ** s) for s in range(0, 100)] + [(100.0, 24.5)]
    assert noisy_flat[80][1] - noisy_flat[-1][1] == pytest.approx(1.0)
    holds, change = converged(noisy_flat, 100, spread=0.5) or (False, 99.0)
    assert holds and abs(change) < 0.3
    # the same noise on a tail rising 1 dB over the last 20 steps is not converged
    rising = [(s, v + 0.05 * s) for s, v in noisy_flat]
    holds, change = converged(rising, 100, spread=0.5) or (True, 0.0)
    assert not holds and 0.5 < change < 1.0


def test_pareto_ignores_differences_within_the_spread() -> None:
    fast = summarise_seeds([25.0, 25.4, 24.6])  # spread 0.4
    slow_slightly_better = summarise_seeds([25.2, 25.5, 24.9])  # within the spread
    slow_much_worse = summarise_seeds([22.0, 22.1, 21.9])
    times = [10.0, 20.0, 30.0, None]
    front = robust_pareto(times, [fast, slow_slightly_better, slow_much_worse, fast])
    assert front == [0, 1]
    faster_and_clearly_better = summarise_seeds([28.0, 28.1, 27.9])
    assert robust_pareto([5.0, 10.0], [faster_and_clearly_better, fast]) == [0]


def test_published_rows_are_the_papers() -> None:
    by_name = {row.name: row for row in PUBLISHED}
    assert (by_name["G+E+A"].ssim, by_name["G+E+A"].psnr_db) == (0.909, 29.84)
    assert (by_name["the paper's synthetic"].psnr_db, by_name["random init"].psnr_db) == (
        24.77,
        22.36,
    )
    assert by_name["the paper (GEA)"].cpu_s == 0.542
    table = published_markdown()
    assert table.count("\n| ") == len(PUBLISHED) + 1 and "published" in table


def _row(name: str, precision: str, psnr: float) -> TradeoffRow:
    return TradeoffRow(
        name=name, variant="GEA", width=1.0, num_blocks=9, precision=precision, params=1,
        gflops=1.0, cpu_ms=10.0, gpu_ms=None, psnr_db=psnr, ssim=0.9,
        convention="skimage-gaussian", steps=100,
    )  # fmt: skip


def _curve(path: Path, points: list[tuple[int, float]]) -> None:
    path.parent.mkdir(parents=True)
    rows = [{"step": str(step), "seconds": str(step), "val_psnr": str(v)} for step, v in points]
    write_metrics_rows(path, rows)


def test_one_verdict_per_network_from_its_fp32_spread_with_the_change_signed(
    tmp_path: Path,
) -> None:
    # fp32 scores 20.0 / 20.2 (spread 0.14); bf16 20.0 / 21.0 (spread 0.71). Both seeds'
    # validation PSNR falls 0.5 dB over the last fifth: beyond the fp32 spread, so the
    # network has not converged, at bf16 too, although 0.5 dB is within bf16's spread.
    results = [
        TradeoffResult(
            [_row("GEA", "fp32", 20.0 + seed * 0.2), _row("GEA", "bf16", 20.0 + seed)], {}
        )
        for seed in (0, 1)
    ]
    for seed in (0, 1):
        falling = [(0, 20.0), (80, 21.0), (90, 20.75), (100, 20.5)]
        _curve(tmp_path / f"seed{seed}" / "runs" / "GEA" / "metrics.csv", falling)
    rows = aggregate(results, tmp_path, [0, 1], Budget(steps=100))
    assert [(r.precision, r.converged) for r in rows] == [("fp32", False), ("bf16", False)]
    assert all(r.tail_change_db == pytest.approx(-0.5) for r in rows)
    text = seeded_markdown(rows, _META)
    assert "no (-0.50 dB)" in text and "does NOT hold" in text
    # one seed has no spread to compare with: not checked, and not called unconverged
    single = aggregate(results[:1], tmp_path, [0], Budget(steps=100))
    assert [r.converged for r in single] == [None, None]
    text = seeded_markdown(single, _META)
    assert "not checkable" in text and "does NOT hold" not in text and "could not be made" in text


def test_a_row_the_input_beats_beyond_its_spread_is_on_no_seeded_front(tmp_path: Path) -> None:
    # the input scores the same in every seed: exact, 0 ms; G (20.0/20.2) and GEA
    # (20.1/20.3) are within each other's spread, and 21.0 dB beats both beyond it
    def results(baseline: dict[str, float] | None) -> list[TradeoffResult]:
        meta = {} if baseline is None else {"input_baseline": baseline}
        return [
            TradeoffResult(
                [_row("G", "fp32", 20.0 + seed * 0.2), _row("GEA", "fp32", 20.1 + seed * 0.2)], meta
            )
            for seed in (0, 1)
        ]

    rows = aggregate(results({"psnr_db": 21.0, "ssim": 0.5}), tmp_path, [0, 1], Budget(steps=100))
    assert [(r.name, r.pareto_psnr, r.pareto_ssim) for r in rows] == [
        ("G", False, True),  # the SSIM of 0.5 beats neither
        ("GEA", False, True),
    ]
    unmarked = aggregate(results(None), tmp_path, [0, 1], Budget(steps=100))
    assert [r.pareto_psnr for r in unmarked] == [True, True]  # same time, within the spread


_META = {
    "dataset": "ds", "evaluated_on": "ds split test", "budget": "100 steps", "seeds": [0, 1],
    "convention": "skimage-gaussian", "size": "540x360",
}  # fmt: skip
