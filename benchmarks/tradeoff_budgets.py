"""Does the tradeoff's accuracy still change with the budget? Seeded runs at two budgets.

    python -m benchmarks.tradeoff_budgets SMALL/tradeoff_seeds.json LARGE/tradeoff_seeds.json \\
        --out docs/results/tradeoff_budgets.md

``lenspair tradeoff --seeds`` checks convergence inside one run: the trend of
validation PSNR over the budget's last fifth against the seed spread. Under
the decaying learning rate that window is where the rate falls towards zero
and the GAN settles, so the curve rises there at any budget: the check cannot
tell a network still learning from one settling. Training again with a larger
budget can. For each network present in both runs (the network as trained,
fp32), this prints the test PSNR and SSIM at each budget as mean +/- spread
over seeds and whether the larger budget changed them by more than either
spread (the rule that claims a difference anywhere else in lenspair): where
it did not, more training did not buy accuracy this table can see.

The two runs must be scored on the same pairs with the same convention,
crops, batch and learning rate (their ``meta``); the budgets must differ.
"""

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from lenspair.core.fsutil import atomic_write_text
from lenspair.model.evaluation.seed_statistics import SeedSummary, clearly_better, summarise_seeds

SAME = ("dataset", "evaluated_on", "convention", "size")
"""Meta fields two runs must share to be compared (plus crops, batch and base rate)."""


class BudgetsError(ValueError):
    """Two runs that cannot be compared (one line naming the file and the difference)."""


def _load(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BudgetsError(f"{path}: cannot read it as JSON ({exc})") from None
    if not isinstance(data, dict) or "meta" not in data or "rows" not in data:
        raise BudgetsError(f"{path}: not a tradeoff_seeds.json (no meta and rows)")
    return data


def _settings(meta: dict[str, Any]) -> dict[str, Any]:
    training = meta.get("training", {})
    shared = {key: meta.get(key) for key in SAME}
    shared |= {key: training.get(key) for key in ("crop_size", "batch_size", "lr")}
    return shared


def _fp32(data: dict[str, Any]) -> dict[str, tuple[SeedSummary, SeedSummary]]:
    return {
        row["name"]: (summarise_seeds(row["psnr_db"]), summarise_seeds(row["ssim"]))
        for row in data["rows"]
        if row["precision"] == "fp32"
    }


def compare(small_path: Path, large_path: Path) -> str:
    """The comparison as Markdown (raises :class:`BudgetsError` when it cannot be made)."""
    small, large = _load(small_path), _load(large_path)
    mine, theirs = _settings(small["meta"]), _settings(large["meta"])
    for key in mine:
        if mine[key] != theirs[key]:
            raise BudgetsError(
                f"{large_path}: {key} is {theirs[key]!r}, but {mine[key]!r} in {small_path}: "
                "only runs on the same pairs and settings compare"
            )
    budgets = (small["meta"]["budget"], large["meta"]["budget"])
    if budgets[0] == budgets[1]:
        raise BudgetsError(f"{large_path}: the same budget as {small_path} ({budgets[0]})")
    before, after = _fp32(small), _fp32(large)
    lines = [
        "# Accuracy against the training budget",
        "",
        f"- runs: `{small_path.as_posix()}` ({budgets[0]}, seeds {small['meta']['seeds']}) "
        f"and `{large_path.as_posix()}` ({budgets[1]}, seeds {large['meta']['seeds']})",
        f"- data: `{small['meta']['dataset']}`, scored on {small['meta']['evaluated_on']}, "
        f"{small['meta']['convention']} convention; fp32, as trained",
        "- changed: the larger budget moved the mean by more than either run's spread "
        "(sample standard deviation over seeds)",
        "",
        f"| network | PSNR at {budgets[0]} | PSNR at {budgets[1]} | change | changed | "
        f"SSIM at {budgets[0]} | SSIM at {budgets[1]} |",
        "|---|---|---|---|---|---|---|",
    ]
    common = [name for name in before if name in after]
    if not common:
        raise BudgetsError(f"{large_path}: no network in common with {small_path}")
    changed = []
    for name in common:
        (psnr_a, ssim_a), (psnr_b, ssim_b) = before[name], after[name]
        change = psnr_b.mean - psnr_a.mean
        beyond = clearly_better(psnr_b, psnr_a) or clearly_better(psnr_a, psnr_b)
        if beyond:
            changed.append(name)
        lines.append(
            f"| {name} | {psnr_a.format(2)} | {psnr_b.format(2)} | {change:+.2f} dB | "
            f"{'yes' if beyond else 'no'} | {ssim_a.format(4)} | {ssim_b.format(4)} |"
        )
    if changed:
        verdict = (
            f"The larger budget changed {', '.join(changed)} beyond the spread: at "
            f"{budgets[0]} those had not converged."
        )
    else:
        verdict = (
            f"No network changed beyond the spread between {budgets[0]} and {budgets[1]}: "
            "the accuracy columns compare networks that more training did not improve."
        )
    alone = [
        f"Only at {budget}: {', '.join(names)} (not compared)"
        for budget, names in (
            (budgets[0], [n for n in before if n not in after]),
            (budgets[1], [n for n in after if n not in before]),
        )
        if names
    ]
    if alone:
        verdict += " " + "; ".join(alone) + "."
    return "\n".join([*lines, "", verdict]) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Entry point: compare two seeded tradeoff runs, print and write the table."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("small", type=Path, help="tradeoff_seeds.json of the smaller budget")
    parser.add_argument("large", type=Path, help="tradeoff_seeds.json of the larger budget")
    parser.add_argument("--out", type=Path, default=None, help="also write the table here")
    args = parser.parse_args(argv)
    try:
        text = compare(args.small, args.large)
    except BudgetsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(text, end="")
    if args.out is not None:
        atomic_write_text(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
