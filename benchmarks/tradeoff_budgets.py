"""Does the tradeoff's accuracy still change with the budget? Seeded runs at several budgets.

    python -m benchmarks.tradeoff_budgets SMALL/tradeoff_seeds.json LARGER/tradeoff_seeds.json \\
        [LARGEST/tradeoff_seeds.json ...] --out docs/results/tradeoff_budgets.md \\
        [--plot docs/results/tradeoff_budgets.png]

``lenspair tradeoff --seeds`` checks convergence inside one run: the trend of
validation PSNR over the budget's last fifth against the seed spread. Under
the decaying learning rate that window is where the rate falls towards zero
and the GAN settles, so the curve rises there at any budget: the check cannot
tell a network still learning from one settling. Training again with a larger
budget can. For each network present in at least two runs (the network as
trained, fp32), this prints the test PSNR and SSIM at each budget as mean +/-
spread over seeds and, for each budget and the next, whether the larger one
changed PSNR by more than either spread (the rule that claims a difference
anywhere else in lenspair): where it did not, more training did not buy
accuracy this table can see. A network missing from a run is shown as ``-``.

The runs must be scored on the same pairs with the same convention, crops,
batch, learning rate and schedule (their ``meta``); no two may have the same budget.
The input's own scores head the table for each run: a dataset rebuilt by
another version can differ slightly under the same path, and that row shows it.
"""

import argparse
import json
import sys
from collections.abc import Sequence
from itertools import pairwise
from pathlib import Path
from typing import Any, NamedTuple

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from lenspair.core.fsutil import atomic_write, atomic_write_text
from lenspair.model.evaluation.seed_statistics import SeedSummary, clearly_better, summarise_seeds
from lenspair.model.evaluation.tradeoff_variants import Budget

SAME = ("dataset", "evaluated_on", "convention", "size", "pairs_scored")
"""Meta fields two runs must share to be compared (plus crops, batch, rate and its decay):
two draws of one dataset's name differ in the pairs they scored."""


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
    shared |= {key: training.get(key) for key in ("crop_size", "batch_size", "lr", "lr_decay")}
    return shared


def _fp32(data: dict[str, Any]) -> dict[str, tuple[SeedSummary, SeedSummary]]:
    return {
        row["name"]: (summarise_seeds(row["psnr_db"]), summarise_seeds(row["ssim"]))
        for row in data["rows"]
        if row["precision"] == "fp32"
    }


def _row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _score(value: float | None, digits: int) -> str:
    return "not recorded" if value is None else f"{value:.{digits}f}"


class Compared(NamedTuple):
    """Runs that passed the checks: their JSON, budgets, fp32 scores and the networks compared."""

    paths: list[Path]
    runs: list[dict[str, Any]]
    budgets: list[str]
    tables: list[dict[str, tuple[SeedSummary, SeedSummary]]]
    names: list[str]


def _compared(paths: Sequence[Path]) -> Compared:
    """Load the runs and check that they compare (:class:`BudgetsError` where not)."""
    if len(paths) < 2:
        raise BudgetsError("give at least two runs to compare")
    runs = [_load(path) for path in paths]
    first = _settings(runs[0]["meta"])
    for path, run in zip(paths[1:], runs[1:], strict=True):
        theirs = _settings(run["meta"])
        for key in first:
            if key == "pairs_scored" and None in (first[key], theirs[key]):
                continue  # runs written before tradeoff recorded it: unknown, not different
            if first[key] != theirs[key]:
                raise BudgetsError(
                    f"{path}: {key} is {theirs[key]!r}, but {first[key]!r} in {paths[0]}: "
                    "only runs on the same pairs and settings compare"
                )
    budgets = [run["meta"]["budget"] for run in runs]
    for index, (path, budget) in enumerate(zip(paths, budgets, strict=True)):
        if budget in budgets[:index]:
            earlier = paths[budgets.index(budget)]
            raise BudgetsError(f"{path}: the same budget as {earlier} ({budget})")
    _check_order(paths, budgets)
    tables = [_fp32(run) for run in runs]
    names: list[str] = []  # in order of first appearance, each in at least two runs
    for table in tables:
        names += [n for n in table if n not in names and sum(n in t for t in tables) > 1]
    if not names:
        raise BudgetsError(f"{paths[-1]}: no network in common with another run")
    return Compared(list(paths), runs, budgets, tables, names)


def _check_order(paths: Sequence[Path], budgets: Sequence[str]) -> None:
    """Refuse runs given out of budget order: each is read as the next one's smaller budget.

    8000 steps then 800 steps read "at 8000 steps those had not converged".
    """
    read = [Budget.from_description(budget) for budget in budgets]
    runs = zip(paths, budgets, read, strict=True)
    for (path, budget, ours), (later, theirs, next_) in pairwise(runs):
        if ours is None or next_ is None or (ours.steps is None) != (next_.steps is None):
            continue  # budgets that do not order (unknown text, steps beside seconds)
        if (ours.steps or ours.seconds or 0) > (next_.steps or next_.seconds or 0):
            raise BudgetsError(
                f"{later}: {theirs}, less than {path}'s {budget}: give the runs smallest "
                "budget first, each compared with the next"
            )


def compare(compared: Compared) -> str:
    """The comparison as Markdown: each budget compared with the next."""
    paths, runs, budgets, tables, names = compared
    steps = list(pairwise(budgets))
    described = [
        f"`{path.as_posix()}` ({budget}, seeds {run['meta']['seeds']}"
        + (f", {run['meta']['cpu']}" if run["meta"].get("cpu") else "")
        + ")"
        for path, budget, run in zip(paths, budgets, runs, strict=True)
    ]
    runs_line = ", ".join(described[:-1]) + " and " + described[-1]
    lines = [
        "# Accuracy against the training budget",
        "",
        f"- runs: {runs_line}",
        f"- data: `{runs[0]['meta']['dataset']}`, scored on {runs[0]['meta']['evaluated_on']}, "
        f"{runs[0]['meta']['convention']} convention; fp32, as trained",
        "- changed: the larger budget moved the mean by more than either run's spread "
        "(sample standard deviation over seeds)",
        "",
        _row(
            [
                "network",
                *(f"PSNR at {b}" for b in budgets),
                *(f"{a} -> {b}" for a, b in steps),
                *(f"SSIM at {b}" for b in budgets),
            ]
        ),
        "|---|" + "---|" * (2 * len(budgets) + len(steps)),
    ]
    baselines = [run["meta"].get("input_baseline") or {} for run in runs]
    lines.append(
        _row(
            [
                "input, no restoration",
                *(_score(b.get("psnr_db"), 2) for b in baselines),
                *("-" for _ in steps),
                *(_score(b.get("ssim"), 4) for b in baselines),
            ]
        )
    )
    changed: list[list[str]] = [[] for _ in steps]
    in_both: list[list[str]] = [[] for _ in steps]
    for name in names:
        psnr = [table[name][0].format(2) if name in table else "-" for table in tables]
        ssim = [table[name][1].format(4) if name in table else "-" for table in tables]
        moves = []
        for index, (before, after) in enumerate(pairwise(tables)):
            if name not in before or name not in after:
                moves.append("-")
                continue
            in_both[index].append(name)
            (psnr_a, _), (psnr_b, _) = before[name], after[name]
            beyond = clearly_better(psnr_b, psnr_a) or clearly_better(psnr_a, psnr_b)
            if beyond:
                changed[index].append(name)
            moves.append(f"{psnr_b.mean - psnr_a.mean:+.2f} dB, {'yes' if beyond else 'no'}")
        lines.append(_row([name, *psnr, *moves, *ssim]))
    verdicts = []
    for (small, large), moved, seen in zip(steps, changed, in_both, strict=True):
        if not seen:
            verdicts.append(f"No network was trained at both {small} and {large}.")
        elif moved:
            verdicts.append(
                f"From {small} to {large} the budget changed {', '.join(moved)} beyond the "
                f"spread: at {small} those had not converged."
            )
        else:
            verdicts.append(
                f"No network changed beyond the spread between {small} and {large} "
                f"({', '.join(seen)}): the accuracy columns at {small} compare networks "
                "that more training did not improve."
            )
    alone = [
        f"Only at {budget}: {', '.join(left)} (not compared)"
        for budget, table in zip(budgets, tables, strict=True)
        if (left := [n for n in table if n not in names])
    ]
    verdict = " ".join(verdicts)
    if alone:
        verdict += " " + "; ".join(alone) + "."
    return "\n".join([*lines, "", verdict]) + "\n"


def curves(compared: Compared) -> dict[str, list[tuple[int, SeedSummary]]]:
    """Each compared network's fp32 test PSNR at the budgets it was trained at.

    Returns:
        network name -> ``[(budget index, PSNR over seeds), ...]``, smallest budget first.
    """
    return {
        name: [(i, table[name][0]) for i, table in enumerate(compared.tables) if name in table]
        for name in compared.names
    }


def figure(compared: Compared) -> Figure:
    """Test PSNR against the budget, mean +/- spread per network, the input as a dashed line.

    Budgets counted in steps sit on a logarithmic axis (each doubling one step
    to the right, so a curve still rising by the same amount per doubling is a
    straight line); other budgets sit side by side in the order given.
    """
    read = [Budget.from_description(b) for b in compared.budgets]
    steps = [float(b.steps) for b in read if b is not None and b.steps is not None]
    in_steps = len(steps) == len(read)
    positions = steps if in_steps else [float(i) for i in range(len(read))]
    drawn = Figure(figsize=(7.5, 4.5), dpi=110)
    FigureCanvasAgg(drawn)
    axes = drawn.add_subplot()
    baselines = [(run["meta"].get("input_baseline") or {}).get("psnr_db") for run in compared.runs]
    known = [(x, b) for x, b in zip(positions, baselines, strict=True) if b is not None]
    if known:
        axes.plot(*zip(*known, strict=True), color="grey", linestyle="--", marker=".",
                  label="input, no restoration")  # fmt: skip
    series = curves(compared)
    for k, (name, points) in enumerate(series.items()):
        # side by side within a budget: nudged apart so error bars do not cover each other
        nudge = 1.0 + 0.025 * (k - (len(series) - 1) / 2)
        xs = [positions[i] * nudge if in_steps else positions[i] + (nudge - 1)
              for i, _ in points]  # fmt: skip
        axes.errorbar(xs, [s.mean for _, s in points], yerr=[s.spread for _, s in points],
                      marker="o", capsize=3, label=name)  # fmt: skip
    if in_steps:
        axes.set_xscale("log", base=2)
    axes.set_xticks(positions, compared.budgets)
    axes.minorticks_off()
    meta = compared.runs[0]["meta"]
    axes.set_xlabel("training budget per network and seed")
    axes.set_ylabel(f"test PSNR (dB), {meta['convention']}")
    axes.set_title("Accuracy against the training budget (fp32, mean +/- spread over seeds)",
                   fontsize=10)  # fmt: skip
    axes.grid(True, alpha=0.3)
    axes.legend(fontsize=8)
    drawn.tight_layout()
    return drawn


def plot(compared: Compared, path: Path) -> None:
    """Write :func:`figure` of the runs as a PNG, atomically."""
    drawn = figure(compared)

    def _write(tmp: Path) -> None:
        drawn.savefig(tmp, format="png")

    atomic_write(Path(path), _write, suffix=".png")


def main(argv: list[str] | None = None) -> int:
    """Entry point: compare seeded tradeoff runs, print and write the table."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "runs",
        type=Path,
        nargs="+",
        help="tradeoff_seeds.json of two or more budgets, smallest first",
    )
    parser.add_argument("--out", type=Path, default=None, help="also write the table here")
    parser.add_argument(
        "--plot", type=Path, default=None, help="also draw PSNR against the budget here (PNG)"
    )
    args = parser.parse_args(argv)
    try:
        compared = _compared(args.runs)
    except BudgetsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    text = compare(compared)
    if args.plot is not None:
        plot(compared, args.plot)
    print(text, end="")
    if args.out is not None:
        atomic_write_text(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
